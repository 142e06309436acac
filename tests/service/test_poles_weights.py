"""Pole targets and blend weights through the API (issue 21 item 4): CesiumMan's legs
in Unity's conventions (Y up, left-handed) in centimetres, over HTTP and WebSocket.

Every point is in the client's frame: the knee's side is measured from the answer's
``bones.world`` (a mirror and a scale keep the sign of the measure).
"""

from __future__ import annotations

import base64
import json
import math
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgpack
import numpy as np
import pytest

from tests.solver.skeleton_refs import asset_bytes

from .helpers import Created, create

if TYPE_CHECKING:  # tests/live imports this module's helpers without the test client
    from starlette.testclient import TestClient

LEGS = [f"node_{i}" for i in range(3, 11)]
HIP, KNEE, TOE = "node_3", "node_4", "node_6"
CLIENT = {"up": "y", "handedness": "left", "unit": "cm"}


def legs_chain() -> dict[str, Any]:
    return {
        "format": "gltf",
        "glb_base64": base64.b64encode(asset_bytes("CesiumMan.glb")).decode(),
        "moving": LEGS,
        "effectors": [
            {"bone": TOE, "name": "right_foot"},
            {"bone": "node_10", "name": "left_foot"},
        ],
    }


def vec(p: np.ndarray) -> dict[str, float]:
    return {"x": float(p[0]), "y": float(p[1]), "z": float(p[2])}


def arr(v: dict[str, float]) -> np.ndarray:
    return np.array([v["x"], v["y"], v["z"]])


class Legs:
    """A session on the legs and the rest geometry, in the client's frame."""

    def __init__(self, client: TestClient) -> None:
        self.client = client
        self.s: Created = create(
            client,
            legs_chain(),
            conventions=CLIENT,
            # continuity "reach": these tests flip a knee in a frame or two, a jump a
            # smooth session (the default) would spread over several frames.
            options={"time_budget_us": 50_000, "continuity": "reach"},
        )
        n = len(self.s.body["dof"])
        rest = self.fk([0.0] * n)
        self.hip, self.toe = rest[HIP], rest[TOE]
        self.left = self.fk([0.0] * n)["node_10"]
        self.target = self.toe + 0.3 * (self.hip - self.toe)  # the knee must bend
        self.middle = 0.5 * (self.hip + self.target)
        axis = (self.hip - self.toe) / np.linalg.norm(self.hip - self.toe)
        across = np.cross(axis, [1.0, 0.0, 0.0])
        self.across = across / np.linalg.norm(across)
        self.leg_cm = float(np.linalg.norm(self.hip - self.toe))

    def fk(self, q: list[float]) -> dict[str, np.ndarray]:
        r = self.client.post(
            f"/v1/sessions/{self.s.id}/fk",
            json={"q": q, "bones": {"world": [HIP, KNEE, TOE, "node_10"]}},
            headers=self.s.headers,
        )
        assert r.status_code == 200, r.text
        return {b: arr(t["position"]) for b, t in r.json()["bones"]["world"].items()}

    def reset(self) -> None:
        n = len(self.s.body["dof"])
        r = self.client.put(
            f"/v1/sessions/{self.s.id}/pose", json={"q": [0.0] * n}, headers=self.s.headers
        )
        assert r.status_code == 200

    def frame(self, targets: list[dict[str, Any]]) -> dict[str, Any]:
        return {"targets": targets, "bones": {"world": [HIP, KNEE, TOE, "node_10"]}}

    def knee_side(self, result: dict[str, Any]) -> float:
        world = {b: arr(t["position"]) for b, t in result["bones"]["world"].items()}
        knee = world[KNEE] - world[HIP]
        axis = world[TOE] - world[HIP]
        axis /= np.linalg.norm(axis)
        return float((knee - (knee @ axis) * axis) @ self.across)


@pytest.fixture
def legs(client: TestClient) -> Legs:
    return Legs(client)


def post_frame(legs: Legs, frame: dict[str, Any]) -> dict[str, Any]:
    r = legs.client.post(f"/v1/sessions/{legs.s.id}/frames", json=frame, headers=legs.s.headers)
    assert r.status_code == 200, r.text
    return r.json()["results"][0]


def test_a_pole_flips_the_knee_over_http_and_websocket(legs: Legs) -> None:
    sides = {}
    for sign in (1.0, -1.0):
        legs.reset()
        pole = {"position": vec(legs.middle + sign * 0.5 * legs.leg_cm * legs.across)}
        result = post_frame(
            legs,
            legs.frame([{"effector": "right_foot", "position": vec(legs.target), "pole": pole}]),
        )
        assert result["success"] is True, result["status"]
        sides[sign] = legs.knee_side(result)
    assert sides[1.0] > 0.02 * legs.leg_cm and sides[-1.0] < -0.02 * legs.leg_cm
    # Over the WebSocket, msgpack, from the rest pose: the knee follows the pole from
    # front to back and round again. A stream's later frame shapes for a bounded number
    # of iterations and a half-turn swing may go on in the next (docs/engines.md), so
    # each side gets 3 frames: the knee never on the wrong side, and at the third well
    # on the pole's (a fifth of the leg). The Tait-Bryan default box held the hip at its
    # +-90 deg middle bound with the knee 0.04 of the leg off the hip-foot line; +-pi on
    # the outer angles held it at -pi on the third swing (0.025-0.045 of the leg): a
    # review, bench/history/2026-11-29-bvh-euler-wall.md.
    legs.reset()
    url = f"/v1/sessions/{legs.s.id}/ws"
    fid = 0
    with legs.client.websocket_connect(url, headers=legs.s.headers) as ws:
        for sign in (1.0, -1.0, 1.0):
            pole = {"position": vec(legs.middle + sign * legs.leg_cm * legs.across), "bone": KNEE}
            target = {"effector": "right_foot", "position": vec(legs.target), "pole": pole}
            sides = []
            for _ in range(3):
                fid += 1
                ws.send_bytes(msgpack.packb({"type": "frame", "id": fid, **legs.frame([target])}))
                answer = msgpack.unpackb(ws.receive_bytes())
                assert answer["success"] is True, answer
                sides.append(sign * legs.knee_side(answer["result"]))
            assert min(sides) > 0.0 and sides[-1] > 0.2 * legs.leg_cm, sides


def test_weight_zero_frees_an_effector_in_one_shot_and_stream(
    client: TestClient, legs: Legs
) -> None:
    far = vec(legs.hip + [5000.0, 5000.0, 5000.0])  # 50 m away: unreachable
    left = vec(legs.left + [0.0, 10.0, 0.0])
    targets = [
        {"effector": "left_foot", "position": left},
        {"effector": "right_foot", "position": far, "position_weight": 0},
    ]
    body = {"chain": legs_chain(), "conventions": CLIENT, "targets": targets}
    r = client.post("/v1/solve", json=body)
    assert r.status_code == 200, r.text
    one_shot = r.json()
    assert one_shot["success"] is True
    errors = {e["name"]: e for e in one_shot["effectors"]}
    assert errors["right_foot"]["position_error_m"] is None
    assert errors["left_foot"]["position_error_m"] <= 1e-4
    # The same over the WebSocket (JSON, the fast path): solved; at weight 1, not.
    url = f"/v1/sessions/{legs.s.id}/ws"
    with legs.client.websocket_connect(url, headers=legs.s.headers) as ws:
        ws.send_text(json.dumps({"type": "frame", "id": 1, "targets": targets}))
        assert json.loads(ws.receive_text())["success"] is True
        full = [targets[0], {"effector": "right_foot", "position": far}]
        ws.send_text(json.dumps({"type": "frame", "id": 2, "targets": full}))
        answer = json.loads(ws.receive_text())
        assert answer["type"] == "result" and answer["result"]["success"] is False


@pytest.mark.parametrize("encoding", ["json", "msgpack"])
def test_a_weight_in_between_lands_between(legs: Legs, encoding: str) -> None:
    legs.reset()
    start = legs.toe
    target = {"effector": "right_foot", "position": vec(legs.target), "position_weight": 0.5}
    url = f"/v1/sessions/{legs.s.id}/ws"
    with legs.client.websocket_connect(url, headers=legs.s.headers) as ws:
        message = {"type": "frame", "id": 1, **legs.frame([target])}
        if encoding == "json":
            ws.send_text(json.dumps(message))
            answer = json.loads(ws.receive_text())
        else:
            ws.send_bytes(msgpack.packb(message))
            answer = msgpack.unpackb(ws.receive_bytes())
    assert answer["success"] is True
    reached = arr(answer["result"]["bones"]["world"][TOE]["position"])
    expected = start + 0.5 * (legs.target - start)
    assert np.linalg.norm(reached - expected) <= 0.1  # cm


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        ({"position_weight": -0.1}, "position_weight"),
        ({"position_weight": 1.5}, "position_weight"),
        ({"rotation_weight": "1"}, "rotation_weight"),
        ({"position_weight": True}, "position_weight"),
        ({"pole": {"position": {"x": 0, "y": 1, "z": 0}, "bone": "no_such_bone"}}, "pole.bone"),
        ({"pole": {"position": {"x": 0, "y": 1, "z": 0}, "bone": "node_8"}}, "pole.bone"),
        ({"pole": {"position": {"x": 0, "y": 1}}}, "pole.position.z"),
        ({"pole": {"position": {"x": 1e7, "y": 1, "z": 0}}}, "pole.position.x"),
        ({"pole": {"position": {"x": 0, "y": 1, "z": 0}, "bone": 3}}, "pole.bone"),
    ],
)
def test_bad_weights_and_poles_get_422_naming_the_field(
    legs: Legs, extra: dict[str, Any], field: str
) -> None:
    target = {"effector": "right_foot", "position": vec(legs.target), **extra}
    r = legs.client.post(
        f"/v1/sessions/{legs.s.id}/frames", json={"targets": [target]}, headers=legs.s.headers
    )
    assert r.status_code == 422, r.text
    assert r.json()["field"].endswith(field), r.json()
    # Over the WebSocket: an error message naming it, and the socket stays open.
    url = f"/v1/sessions/{legs.s.id}/ws"
    with legs.client.websocket_connect(url, headers=legs.s.headers) as ws:
        ws.send_bytes(msgpack.packb({"type": "frame", "id": 1, "targets": [target]}))
        answer = msgpack.unpackb(ws.receive_bytes())
        assert answer["success"] is False and answer["error"]["field"].endswith(field), answer


@pytest.mark.parametrize(
    "extra",
    [
        {"position_weight": math.nan},
        {"rotation_weight": math.inf},
        {"pole": {"position": {"x": math.nan, "y": 1.0, "z": 0.0}}},
    ],
)
def test_non_finite_weights_and_poles_are_websocket_errors(
    legs: Legs, extra: dict[str, Any]
) -> None:
    target = {"effector": "right_foot", "position": vec(legs.target), **extra}
    url = f"/v1/sessions/{legs.s.id}/ws"
    with legs.client.websocket_connect(url, headers=legs.s.headers) as ws:
        ws.send_bytes(msgpack.packb({"type": "frame", "id": 1, "targets": [target]}))
        answer = msgpack.unpackb(ws.receive_bytes())
        assert answer["success"] is False
        assert answer["error"]["code"] == "invalid_format"
        name = next(iter(extra))
        assert name in answer["error"]["field"], answer


def test_engines_page_pole_example(client: TestClient) -> None:
    page = (Path(__file__).resolve().parents[2] / "docs" / "engines.md").read_text()

    def block(name: str) -> str:
        m = re.search(rf"<!-- {name}:start -->\s*```json\n(.*?)```", page, re.DOTALL)
        assert m is not None, name
        return m.group(1)

    session = json.loads(block("engines-session"))
    frame = json.loads(block("engines-poles"))
    s = create(client, session["chain"], conventions=session["conventions"])
    hip = np.array([0.0, 1.0, 0.0])  # Unity's frame: glTF's with x mirrored (x = 0 here)
    r = client.post(
        f"/v1/sessions/{s.id}/fk", json={"bones": {"world": ["ankle"]}}, headers=s.headers
    )
    start = arr(r.json()["bones"]["world"]["ankle"]["position"])
    url = f"/v1/sessions/{s.id}/ws"
    with client.websocket_connect(url, headers=s.headers) as ws:
        ws.send_json(frame)
        answer = ws.receive_json()
    assert answer["success"] is True, answer
    world = answer["result"]["bones"]["world"]
    target = arr(frame["targets"][0]["position"])
    ankle = arr(world["ankle"]["position"])
    assert np.linalg.norm(ankle - (start + 0.5 * (target - start))) <= 1e-3
    pole = arr(frame["targets"][0]["pole"]["position"])
    knee = arr(world["knee"]["position"]) - hip
    axis = (ankle - hip) / np.linalg.norm(ankle - hip)
    towards = (pole - hip) - ((pole - hip) @ axis) * axis
    assert (knee - (knee @ axis) * axis) @ towards > 0.0


def test_a_lone_hand_s_default_pole_is_its_elbow_in_an_arm_only_session(
    client: TestClient,
) -> None:
    """docs/engines.md, "Poles": a lone hand's default pulled bone is its elbow, the
    middle of the arm below the chest (the skeleton's branch, and here the last bone
    nothing moves): the pole picks the bend side as naming the elbow does. It was the
    spine, which an arm-only session never moves, so the pole did nothing (a game-dev
    trial's first pole). A bone no moving joint carries is refused, naming the field."""
    chain = {
        "format": "gltf",
        "glb_base64": base64.b64encode(asset_bytes("CesiumMan.glb")).decode(),
        "moving": ["node_16", "node_17", "node_18"],
        "effectors": [{"bone": "node_18", "name": "hand"}],
    }
    target = np.array([0.25, 1.0, -0.2])  # glTF frame: ahead of the left shoulder

    def elbow_side(sign: float, bone: str | None) -> float:
        s = create(client, chain, bones={"world": ["node_16", "node_17", "node_18"]})
        pole = {"position": vec(target + [0.0, sign * 0.5, 0.0])}
        if bone is not None:
            pole["bone"] = bone
        frame = {"targets": [{"effector": "hand", "position": vec(target), "pole": pole}]}
        r = client.post(f"/v1/sessions/{s.id}/frames", headers=s.headers, json=frame)
        result = r.json()["results"][0]
        assert result["success"], result
        world = {b: arr(w["position"]) for b, w in result["bones"]["world"].items()}
        shoulder, elbow, hand = world["node_16"], world["node_17"], world["node_18"]
        axis = (hand - shoulder) / np.linalg.norm(hand - shoulder)
        off = (elbow - shoulder) - np.dot(elbow - shoulder, axis) * axis
        return float(off[1])  # up (+) or down (-) of the shoulder-hand line

    assert np.sign(elbow_side(+1, "node_17")) == 1 and np.sign(elbow_side(-1, "node_17")) == -1
    assert np.sign(elbow_side(+1, None)) == 1 and np.sign(elbow_side(-1, None)) == -1
    s = create(client, chain)
    url = f"/v1/sessions/{s.id}/frames"
    for bone in ("node_17", "node_17"):  # accepted, then remembered as accepted
        pole = {"position": vec(target), "bone": bone}
        frame = {"targets": [{"effector": "hand", "position": vec(target), "pole": pole}]}
        assert client.post(url, headers=s.headers, json=frame).status_code == 200
    # Twice each, after an accepted bone: the service remembers accepted pairs only.
    for still in ("node_11", "node_16", "node_11", "node_16"):
        pole = {"position": vec(target), "bone": still}
        frame = {"targets": [{"effector": "hand", "position": vec(target), "pole": pole}]}
        r = client.post(f"/v1/sessions/{s.id}/frames", headers=s.headers, json=frame)
        assert r.status_code == 422, r.text
        error = r.json()
        assert error["code"] == "invalid_problem"
        assert error["field"] == "targets[0].pole.bone"
        assert (
            "no moving joint moves the origin" in error["detail"] and "'node_17'" in error["detail"]
        )


def test_a_pole_with_no_default_bone_names_its_field(client: TestClient) -> None:
    """A foot in an arm-only session: nothing on its limb moves, so a pole without
    ``bone`` has nothing to pull; it is refused naming ``targets[0].pole`` over HTTP and
    the WebSocket alike (the solver's error said no field)."""
    chain = {
        "format": "gltf",
        "glb_base64": base64.b64encode(asset_bytes("CesiumMan.glb")).decode(),
        "moving": ["node_16", "node_17", "node_18"],
        "effectors": [{"bone": "node_18", "name": "hand"}, {"bone": "node_5", "name": "foot"}],
    }
    s = create(client, chain)
    pole = {"position": vec(np.array([0.0, 0.5, 0.3]))}
    target = {"effector": "foot", "position": vec(np.array([0.1, 0.1, 0.0])), "pole": pole}
    r = client.post(f"/v1/sessions/{s.id}/frames", headers=s.headers, json={"targets": [target]})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == "targets[0].pole" and "name one in pole.bone" in r.json()["detail"]
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "frame", "id": 1, "targets": [target]})
        answer = ws.receive_json()
    assert answer["error"]["field"] == "targets[0].pole", answer


@pytest.mark.parametrize(
    "knee",
    [
        {"axes": "x", "lower": [-2.6], "upper": [2.6]},
        None,  # a ball joint, the default: it jittered until the plain answer came first
    ],
    ids=["hinge-knee", "ball-knee"],
)
def test_a_still_pole_lets_the_leg_settle(client: TestClient, knee: dict[str, Any] | None) -> None:
    # A game sending the same frame every tick (the player stands still) must get a
    # still leg back: found in a trial as a knee jittering 2 cm per frame for ever.
    chain: dict[str, Any] = {
        "format": "gltf",
        "glb_base64": base64.b64encode(asset_bytes("CesiumMan.glb")).decode(),
        "moving": ["node_7", "node_8", "node_9"],
        "effectors": [{"bone": "node_9", "name": "left_foot"}],
    }
    if knee is not None:
        chain["bones"] = {"node_8": knee}
    s = create(client, chain, options={"time_budget_us": 50_000})
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "fk", "id": 1})
        foot = arr(ws.receive_json()["effectors"][0]["position"])
        target = {
            "effector": "left_foot",
            "position": vec(foot + [0.0, 0.1, 0.05]),
            "pole": {"position": vec(foot + [0.0, 0.5, 0.6])},
        }
        steps = []
        for i in range(150):
            ws.send_json({"type": "frame", "id": 2 + i, "targets": [target]})
            result = ws.receive_json()["result"]
            assert result["status"] == "solved", result
            steps.append(result["largest_step_rad"])
    assert max(steps[-30:]) < 1e-3, steps[-30:]
