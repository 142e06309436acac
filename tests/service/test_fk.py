"""Forward kinematics of every chain kind (POST .../fk, the WebSocket ``fk``): the pose
used and each effector's world pose, in the session's conventions; bone data on
skeleton chains only.

The expected poses come from the solver's own FK of the same chain
(``solver.model.forward.effector_poses``), and the conventions' maps are written out
here (as in test_conventions.py), not computed from ``service.convert.conventions``.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from starlette.testclient import TestClient

import schemas as S
from schemas.chain import EXAMPLE_ARM, EXAMPLE_GLTF_LEG
from solver.model import EffectorMode, matrix_to_quaternion
from solver.model.forward import effector_poses
from solver.model.urdf import chain_from_urdf

from .helpers import Created, create

PANDA_URDF = (Path(__file__).resolve().parents[1] / "solver/data/panda_kinematic.urdf").read_text()
TIPS = ["panda_hand_tcp", "panda_leftfinger"]
PANDA = {
    "format": "urdf",
    "urdf": PANDA_URDF,
    "base_link": "panda_link0",
    "tip_links": TIPS,
    "mode": "pose",
}
# A pose inside the Panda's limits (the finger half open).
Q = [0.3, -0.4, 0.2, -1.9, 0.1, 1.6, 0.5, 0.02]
# Solves that compare poses must not stop at a deadline on busy cores.
NO_DEADLINE = {"time_budget_us": 50_000}


def _vec(d: dict[str, float]) -> np.ndarray:
    return np.array([d["x"], d["y"], d["z"]])


def _quat(d: dict[str, float]) -> np.ndarray:
    return np.array([d["w"], d["x"], d["y"], d["z"]])


def _same_rotation(a: np.ndarray, b: np.ndarray, atol: float = 1e-9) -> bool:
    """Two unit quaternions of one rotation (q and -q are the same rotation)."""
    return bool(np.allclose(a, b, atol=atol) or np.allclose(a, -b, atol=atol))


def _fk(client: TestClient, s: Created, body: dict[str, Any]) -> dict[str, Any]:
    r = client.post(f"/v1/sessions/{s.id}/fk", json=body, headers=s.headers)
    assert r.status_code == 200, r.text
    S.FkResult.model_validate(r.json())
    return dict(r.json())


def _solver_poses(q: list[float]) -> list[np.ndarray]:
    """The solver's own FK of the Panda URDF at q: each tip's 4x4 world pose."""
    chain = chain_from_urdf(
        PANDA_URDF, base_link="panda_link0", tip_links=TIPS, mode=EffectorMode.POSE
    )
    return effector_poses(chain, np.array(q))


def test_fk_of_a_urdf_chain_is_the_solvers_fk(client: TestClient) -> None:
    s = create(client, PANDA)
    before = s.body["pose"]["q"]
    answer = _fk(client, s, {"q": Q})
    assert answer["q"] == Q and "bones" not in answer
    assert [e["name"] for e in answer["effectors"]] == TIPS  # as targets name them
    for effector, pose in zip(answer["effectors"], _solver_poses(Q), strict=True):
        assert np.allclose(_vec(effector["position"]), pose[:3, 3], atol=1e-12)
        assert _same_rotation(_quat(effector["orientation"]), matrix_to_quaternion(pose[:3, :3]))
        assert effector["direction"] is None  # pose effectors: no aim axis
    # joints by name over the current pose, and neither: the current pose.
    by_name = _fk(client, s, {"joints": {"panda_joint4": -1.2}})
    expected = [*before[:3], -1.2, *before[4:]]
    assert by_name["q"] == pytest.approx(expected, abs=1e-15)
    tcp = _solver_poses(expected)[0]
    assert np.allclose(_vec(by_name["effectors"][0]["position"]), tcp[:3, 3], atol=1e-12)
    assert _fk(client, s, {})["q"] == before
    # A chain without bones that asks for none is answered too (bones: {} asks nothing).
    assert "bones" not in _fk(client, s, {"bones": {"local_rotations": False, "world": []}})
    # FK does not move the session.
    pose = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["pose"]
    assert pose["q"] == before


def test_fk_after_solving_is_the_target(client: TestClient) -> None:
    """The current pose's FK puts the solved effector on its target (within the
    session's tolerances), and the other effector where the solver's FK puts it."""
    s = create(client, PANDA, options=NO_DEADLINE)
    goal = _solver_poses(Q)[0]
    w, x, y, z = matrix_to_quaternion(goal[:3, :3]).tolist()
    px, py, pz = goal[:3, 3].tolist()
    target = {
        "effector": "panda_hand_tcp",
        "position": {"x": px, "y": py, "z": pz},
        "orientation": {"w": w, "x": x, "y": y, "z": z},
    }
    url = f"/v1/sessions/{s.id}/frames"
    result = client.post(url, json={"targets": [target]}, headers=s.headers).json()["results"][0]
    assert result["success"], result
    answer = _fk(client, s, {})
    assert answer["q"] == result["q"]
    tcp, finger = answer["effectors"]
    options = s.body["options"]
    assert np.linalg.norm(_vec(tcp["position"]) - goal[:3, 3]) <= options["position_tolerance_m"]
    dot = abs(float(_quat(tcp["orientation"]) @ matrix_to_quaternion(goal[:3, :3])))
    assert 2 * np.arccos(min(1.0, dot)) <= options["rotation_tolerance_rad"] + 1e-9
    pose = _solver_poses(result["q"])[1]
    assert np.allclose(_vec(finger["position"]), pose[:3, 3], atol=1e-12)


def test_fk_of_an_aim_effector_gives_its_direction(client: TestClient) -> None:
    arm = copy.deepcopy(EXAMPLE_ARM)
    arm["effectors"] = [{"name": "hand", "link": "hand", "mode": "aim"}]  # aim_axis +z
    s = create(client, arm, options=NO_DEADLINE)
    aim = np.array([0.6, 0.0, 0.8])
    target = {"effector": "hand", "direction": dict(zip("xyz", aim.tolist(), strict=True))}
    url = f"/v1/sessions/{s.id}/frames"
    result = client.post(url, json={"targets": [target]}, headers=s.headers).json()["results"][0]
    assert result["success"], result
    (hand,) = _fk(client, s, {})["effectors"]
    direction = _vec(hand["direction"])
    assert abs(np.linalg.norm(direction) - 1.0) < 1e-12
    angle = np.arccos(min(1.0, float(direction @ aim)))
    assert angle <= s.body["options"]["rotation_tolerance_rad"] + 1e-9
    # The aim axis is the tip frame's z: the orientation's third column.
    w, x, y, z = _quat(hand["orientation"])
    third_column = [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]
    assert np.allclose(third_column, direction, atol=1e-9)


def test_a_urdf_tip_in_aim_mode_aims_its_z_axis(client: TestClient) -> None:
    """A URDF chain has no per-tip aim_axis: "mode": "aim" aims each tip link's z axis
    (docs/chains.md says so), the approach axis of ROS tool frames."""
    s = create(client, {**PANDA, "mode": "aim"})
    answer = _fk(client, s, {"q": Q})
    for effector, pose in zip(answer["effectors"], _solver_poses(Q), strict=True):
        assert np.allclose(_vec(effector["direction"]), pose[:3, 2], atol=1e-12)


# The URDF's frame (Z up, right-handed, metres) -> each convention's numbers, from the
# importers' maps (test_conventions.py's, composed with ROS's inverse).
CONVENTIONS: list[tuple[dict[str, str], Any, Any]] = [
    # Unreal: Z up, left-handed (Y mirrored), centimetres.
    (
        {"preset": "unreal"},
        lambda p: 100 * np.array([p[0], -p[1], p[2]]),
        lambda q: np.array([q[0], -q[1], q[2], -q[3]]),
    ),
    # Y up, right-handed (glTF's axes), centimetres: (x, y, z) -> (x, z, -y).
    (
        {"up": "y", "unit": "cm"},
        lambda p: 100 * np.array([p[0], p[2], -p[1]]),
        lambda q: np.array([q[0], q[1], q[3], -q[2]]),
    ),
]


@pytest.mark.parametrize(("conventions", "position", "rotation"), CONVENTIONS)
def test_fk_speaks_the_sessions_conventions(
    client: TestClient, conventions: dict[str, str], position: Any, rotation: Any
) -> None:
    native = create(client, PANDA)
    converted = create(client, PANDA, conventions=conventions, options=NO_DEADLINE)
    a = _fk(client, native, {"q": Q})
    b = _fk(client, converted, {"q": Q})
    assert a["q"] == b["q"] == Q  # joint values stay the chain's own
    for ea, eb in zip(a["effectors"], b["effectors"], strict=True):
        assert np.allclose(_vec(eb["position"]), position(_vec(ea["position"])), atol=1e-9)
        assert _same_rotation(_quat(eb["orientation"]), rotation(_quat(ea["orientation"])))
    # A target stated in the session's conventions is where FK then puts the tip.
    tcp = b["effectors"][0]
    url = f"/v1/sessions/{converted.id}/frames"
    target = {"effector": "panda_hand_tcp", **{k: tcp[k] for k in ("position", "orientation")}}
    result = client.post(url, json={"targets": [target]}, headers=converted.headers).json()
    assert result["results"][0]["success"], result
    reached = _fk(client, converted, {})["effectors"][0]
    tolerance_cm = 100 * converted.body["options"]["position_tolerance_m"]
    assert np.linalg.norm(_vec(reached["position"]) - _vec(tcp["position"])) <= tolerance_cm


def test_fk_of_a_skeleton_keeps_its_bones_and_adds_its_effectors(client: TestClient) -> None:
    s = create(client, EXAMPLE_GLTF_LEG, conventions={"preset": "unity"})
    answer = _fk(client, s, {"joints": {"knee.x": 1.0}, "bones": {"world": ["ankle"]}})
    assert set(answer["bones"]) == {"world"}
    (foot,) = answer["effectors"]
    assert foot["name"] == "foot"
    # The foot effector sits on the ankle: the same point as the ankle bone's transform.
    ankle = answer["bones"]["world"]["ankle"]
    assert np.allclose(_vec(foot["position"]), _vec(ankle["position"]), atol=1e-12)
    default = _fk(client, s, {})  # no bones asked: the local rotations, as before
    assert set(default["bones"]) == {"local"} and len(default["effectors"]) == 1


@pytest.mark.parametrize(
    ("body", "field", "words"),
    [
        ({"q": [0.0, 0.1]}, "q", "8 values"),
        ({"joints": {"panda_joint9": 0.1}}, "joints.panda_joint9", "unknown DOF"),
        ({"bones": {"local_rotations": True}}, "bones", "gltf or bvh"),
        ({"bones": {"world": ["panda_link3"]}}, "bones", "gltf or bvh"),
    ],
)
def test_fk_errors_name_the_field_over_http_and_websocket(
    client: TestClient, body: dict[str, Any], field: str, words: str
) -> None:
    s = create(client, PANDA)
    r = client.post(f"/v1/sessions/{s.id}/fk", json=body, headers=s.headers)
    assert r.status_code == 422, r.text
    error = r.json()
    assert (error["code"], error["field"]) == ("invalid_problem", field)
    assert words in error["detail"]
    for message, msg_id in _ws_fk_errors(client, s, body):
        assert message.id == msg_id
        assert (message.error.code, message.error.field) == ("invalid_problem", field)
        assert words in message.error.message


def _ws_fk_errors(
    client: TestClient, s: Created, body: dict[str, Any]
) -> list[tuple[S.ErrorMessage, int]]:
    """The error answers to an ``fk`` message with ``body``, sent as JSON (id 1) and as
    MessagePack (id 2), each with the id it was sent with."""
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "fk", "id": 1, **body})
        text = S.ErrorMessage.model_validate(ws.receive_json())
        ws.send_bytes(msgpack.packb({"type": "fk", "id": 2, **body}))
        binary = S.ErrorMessage.model_validate(msgpack.unpackb(ws.receive_bytes()))
    return [(text, 1), (binary, 2)]


def test_fk_with_both_q_and_joints_names_a_field_over_http_and_websocket(
    client: TestClient,
) -> None:
    # Over the WebSocket this error had no field (null); HTTP named the whole body. Both
    # now name the same field, as every other error of the request does.
    s = create(client, PANDA)
    both = {"q": Q, "joints": {"panda_joint1": 0.1}}
    r = client.post(f"/v1/sessions/{s.id}/fk", json=both, headers=s.headers)
    assert r.status_code == 422, r.text
    assert (r.json()["code"], r.json()["field"]) == ("invalid_problem", "joints")
    for message, msg_id in _ws_fk_errors(client, s, both):
        assert message.id == msg_id
        assert (message.error.code, message.error.field) == ("invalid_problem", "joints")
        assert "at most one of 'q' and 'joints'" in message.error.message


def test_fk_over_the_websocket_is_the_http_answer(client: TestClient) -> None:
    s = create(client, PANDA)
    over_http = _fk(client, s, {"q": Q})
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "fk", "id": 1, "q": Q})
        text = ws.receive_json()
        ws.send_bytes(msgpack.packb({"type": "fk", "id": 2, "q": Q}))
        binary = msgpack.unpackb(ws.receive_bytes())
    for message, msg_id in ((text, 1), (binary, 2)):
        S.FkResultMessage.model_validate(message)
        assert (message.pop("id"), message.pop("type")) == (msg_id, "fk_result")
        assert message == over_http


def test_an_fk_pose_outside_the_limits_is_clipped_and_says_which_dofs(
    client: TestClient,
) -> None:
    """FK clipped a value outside its limits silently (a trial's 57.3, degrees by mistake,
    turned into 2 pi with no word); PUT .../pose says so in ``clipped``, as FK now does."""
    s = create(client, PANDA)
    bent = {"joints": {"panda_joint4": 57.3, "panda_joint2": -0.4}}
    answer = _fk(client, s, bent)
    assert answer["clipped"] == ["panda_joint4"]
    assert answer["q"][3] == pytest.approx(-0.0698, abs=1e-4)  # the joint's upper limit
    wide = list(Q)
    wide[0], wide[6] = -9.0, 9.0
    assert _fk(client, s, {"q": wide})["clipped"] == ["panda_joint1", "panda_joint7"]
    assert _fk(client, s, {"q": Q})["clipped"] == [] and _fk(client, s, {})["clipped"] == []
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_bytes(msgpack.packb({"type": "fk", "id": 1, **bent}))
        message = S.FkResultMessage.model_validate(msgpack.unpackb(ws.receive_bytes()))
    assert message.clipped == ["panda_joint4"]
