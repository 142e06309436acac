"""Engine conventions at the boundary: one physical target stated in each convention gives
the same physical pose, and bone data comes back as the engines' own glTF importers
would convert it.

The expected maps are written out here from the importers (glTFast / UnityGLTF for Unity,
Unreal's glTF importer, Blender's Z-up export for ROS), not computed from
``service.convert.conventions``.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from starlette.testclient import TestClient

from schemas.chain import EXAMPLE_ARM, EXAMPLE_GLTF_LEG

from .helpers import create

Vec = tuple[float, float, float]
Quat = tuple[float, float, float, float]

# glTF's frame (Y up, right-handed, metres) -> each preset's numbers.
POSITION_FROM_GLTF: dict[str, Callable[[Vec], Vec]] = {
    "gltf": lambda p: p,
    "godot": lambda p: p,
    "threejs": lambda p: p,
    "unity": lambda p: (-p[0], p[1], p[2]),  # glTFast: X mirrored
    "unreal": lambda p: (100 * p[0], 100 * p[2], 100 * p[1]),  # Y <-> Z, centimetres
    "ros": lambda p: (p[0], -p[2], p[1]),  # Z up: Blender's glTF export, inverted
}
QUATERNION_FROM_GLTF: dict[str, Callable[[Quat], Quat]] = {
    "gltf": lambda q: q,
    "godot": lambda q: q,
    "threejs": lambda q: q,
    "unity": lambda q: (q[0], q[1], -q[2], -q[3]),  # glTFast: (x, -y, -z, w)
    "unreal": lambda q: (q[0], -q[1], -q[3], -q[2]),  # Unreal: (-x, -z, -y, w)
    "ros": lambda q: (q[0], q[1], -q[3], q[2]),  # a proper rotation: the vector part turns
}
PRESETS = sorted(POSITION_FROM_GLTF)
# Solves that compare poses across sessions must not stop at a deadline on busy cores.
NO_DEADLINE = {"time_budget_us": 50_000}


def _vec(d: dict[str, float]) -> Vec:
    return d["x"], d["y"], d["z"]


def _quat(d: dict[str, float]) -> Quat:
    return d["w"], d["x"], d["y"], d["z"]


def _as_vec(p: Vec) -> dict[str, float]:
    return dict(zip("xyz", p, strict=True))


def _as_quat(q: Quat) -> dict[str, float]:
    return dict(zip("wxyz", q, strict=True))


def _angle_deg(a: Quat, b: Quat) -> float:
    return float(np.degrees(2 * np.arccos(min(1.0, abs(float(np.dot(a, b)))))))


def _pose_leg() -> dict[str, Any]:
    chain = copy.deepcopy(EXAMPLE_GLTF_LEG)
    chain["effectors"][0]["mode"] = "pose"
    chain["bones"]["hip"] = {"axes": "zxy"}
    return chain


def test_one_physical_target_in_every_convention_gives_one_pose(client: TestClient) -> None:
    # The physical target: where a known pose puts the ankle, read in glTF's frame.
    native = create(client, _pose_leg(), bones={"world": ["ankle"]})
    q_known = [0.3, -0.2, 0.4, 1.1]
    fk = client.post(
        f"/v1/sessions/{native.id}/fk",
        json={"q": q_known, "bones": {"world": ["ankle"]}},
        headers=native.headers,
    ).json()["bones"]["world"]["ankle"]
    p_gltf, r_gltf = _vec(fk["position"]), _quat(fk["rotation"])
    poses = {}
    for preset in PRESETS:
        s = create(
            client,
            _pose_leg(),
            conventions={"preset": preset},
            bones={"world": ["ankle"]},
            options=NO_DEADLINE,
        )
        target = {
            "effector": "foot",
            "position": _as_vec(POSITION_FROM_GLTF[preset](p_gltf)),
            "orientation": _as_quat(QUATERNION_FROM_GLTF[preset](r_gltf)),
        }
        r = client.post(
            f"/v1/sessions/{s.id}/frames", json={"targets": [target]}, headers=s.headers
        )
        result = r.json()["results"][0]
        assert result["success"] is True, (preset, result)
        poses[preset] = np.array(result["q"])
        # The ankle's world transform comes back in the client's numbers.
        out = result["bones"]["world"]["ankle"]
        unit = 100.0 if preset == "unreal" else 1.0
        expected_p = POSITION_FROM_GLTF[preset](p_gltf)
        assert np.allclose(_vec(out["position"]), expected_p, atol=2e-3 * unit), preset
        expected_r = QUATERNION_FROM_GLTF[preset](r_gltf)
        assert _angle_deg(_quat(out["rotation"]), expected_r) < 0.5, preset
    for preset, q in poses.items():
        assert np.allclose(q, poses["gltf"], atol=1e-6), preset


@pytest.mark.parametrize("preset", PRESETS)
def test_local_rotations_are_converted_as_the_engines_importers_do(
    client: TestClient, preset: str
) -> None:
    q = [0.3, -0.2, 0.4, 1.1]
    body = {"q": q, "bones": {"local_rotations": True, "world": ["knee"]}}
    native = create(client, _pose_leg())
    client_s = create(client, _pose_leg(), conventions={"preset": preset})
    a = client.post(f"/v1/sessions/{native.id}/fk", json=body, headers=native.headers).json()
    b = client.post(f"/v1/sessions/{client_s.id}/fk", json=body, headers=client_s.headers).json()
    for bone, rotation in a["bones"]["local"].items():
        expected = QUATERNION_FROM_GLTF[preset](_quat(rotation))
        assert np.allclose(_quat(b["bones"]["local"][bone]), expected, atol=1e-12), bone
    knee_a, knee_b = a["bones"]["world"]["knee"], b["bones"]["world"]["knee"]
    assert np.allclose(
        _vec(knee_b["position"]), POSITION_FROM_GLTF[preset](_vec(knee_a["position"])), atol=1e-9
    )


def test_a_z_up_chain_takes_y_up_left_handed_centimetres(client: TestClient) -> None:
    # EXAMPLE_ARM is Z up, metres. The same point, as a Y-up left-handed cm client says it.
    p_zup = (0.3, 0.1, 0.6)
    p_gltf = (p_zup[0], p_zup[2], -p_zup[1])  # Z up -> Y up (Blender's export)
    p_client = tuple(100 * v for v in POSITION_FROM_GLTF["unity"](p_gltf))
    conventions = {"up": "y", "handedness": "left", "unit": "cm"}
    native = create(client, EXAMPLE_ARM, options=NO_DEADLINE)
    other = create(client, EXAMPLE_ARM, conventions=conventions, options=NO_DEADLINE)
    answers = []
    for s, p in ((native, p_zup), (other, p_client)):
        r = client.post(
            f"/v1/sessions/{s.id}/frames",
            json={"targets": [{"effector": "hand", "position": _as_vec(p)}]},
            headers=s.headers,
        )
        answers.append(r.json()["results"][0])
    assert answers[0]["success"] and answers[1]["success"]
    assert np.allclose(answers[0]["q"], answers[1]["q"], atol=1e-6)


def test_a_field_beside_a_preset_overrides_it(client: TestClient) -> None:
    body = {"q": [0.3, -0.2, 0.4, 1.1], "bones": {"world": ["ankle"]}}
    unity_cm = create(client, _pose_leg(), conventions={"preset": "unity", "unit": "cm"})
    unity = create(client, _pose_leg(), conventions={"preset": "unity"})
    a = client.post(f"/v1/sessions/{unity.id}/fk", json=body, headers=unity.headers).json()
    b = client.post(f"/v1/sessions/{unity_cm.id}/fk", json=body, headers=unity_cm.headers).json()
    pa = np.array(_vec(a["bones"]["world"]["ankle"]["position"]))
    pb = np.array(_vec(b["bones"]["world"]["ankle"]["position"]))
    assert np.allclose(pb, 100 * pa)


def test_unknown_presets_are_invalid_format(client: TestClient) -> None:
    r = client.post(
        "/v1/sessions", json={"chain": EXAMPLE_ARM, "conventions": {"preset": "cryengine"}}
    )
    assert r.status_code == 422 and r.json()["field"] == "conventions.preset"


def test_sessions_say_which_conventions_they_speak(client: TestClient) -> None:
    assert create(client, EXAMPLE_ARM).body["conventions"] == {
        "up": "z",
        "handedness": "right",
        "unit_m": 1.0,
    }
    leg = create(client, _pose_leg(), conventions={"preset": "unreal"})
    expected = {"up": "z", "handedness": "left", "unit_m": 0.01}
    assert leg.body["conventions"] == expected
    info = client.get(f"/v1/sessions/{leg.id}", headers=leg.headers).json()
    assert info["conventions"] == expected
    assert create(client, _pose_leg()).body["conventions"]["up"] == "y"  # glTF's own


# An engine's bone-frame axis and rotation -> the file's, as docs/engines.md ("Not
# converted") tells a client to send an effector's aim_axis and tip_rotation.
AXIS_TO_FILE: dict[str, Callable[[Vec], Vec]] = {
    "unreal": lambda a: (a[0], a[2], a[1]),
    "unity": lambda a: (-a[0], a[1], a[2]),
    "ros": lambda a: (a[0], a[2], -a[1]),
}
TIP_ROTATION_TO_FILE: dict[str, Callable[[Quat], Quat]] = {
    "unreal": lambda q: (q[0], -q[1], -q[3], -q[2]),
    "unity": lambda q: (q[0], q[1], -q[2], -q[3]),
    "ros": lambda q: (q[0], q[1], q[3], -q[2]),
}


def _product(a: Quat, b: Quat) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _rotated(q: Quat, v: Vec) -> Vec:
    w, *xyz = _product(_product(q, (0.0, *v)), (q[0], -q[1], -q[2], -q[3]))
    return xyz[0], xyz[1], xyz[2]


@pytest.mark.parametrize("preset", sorted(AXIS_TO_FILE))
def test_an_engines_bone_axis_and_tip_rotation_are_sent_in_the_files_frame(
    client: TestClient, preset: str
) -> None:
    """aim_axis and tip_rotation are not converted: a bone axis read in the engine
    (Unreal's bone Z, say) is sent in the file's frame, mapped back as engines.md says,
    and the effector then points along that engine axis of the bone."""
    # Neither is left alone by any of the maps (nor by a map's inverse in its place).
    engine_axis: Vec = (0.6, 0.0, 0.8)
    about = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    w, x, y, z = (np.cos(0.4), *(np.sin(0.4) * about))
    engine_tip: Quat = (w, x, y, z)
    chain = _pose_leg()
    chain["effectors"] = [
        {
            "bone": "ankle",
            "name": "sole",
            "mode": "pose",
            "tip_rotation": _as_quat(TIP_ROTATION_TO_FILE[preset](engine_tip)),
        },
        {
            "bone": "ankle",
            "name": "toe",
            "mode": "aim",
            "aim_axis": _as_vec(AXIS_TO_FILE[preset](engine_axis)),
        },
    ]
    s = create(client, chain, conventions={"preset": preset})
    body = {"q": [0.3, -0.2, 0.4, 1.1], "bones": {"world": ["ankle"]}}
    fk = client.post(f"/v1/sessions/{s.id}/fk", json=body, headers=s.headers).json()
    bone = _quat(fk["bones"]["world"]["ankle"]["rotation"])
    sole, toe = fk["effectors"]
    assert np.allclose(_vec(toe["direction"]), _rotated(bone, engine_axis), atol=1e-9)
    assert _angle_deg(_quat(sole["orientation"]), _product(bone, engine_tip)) < 1e-6


def test_conventions_are_the_sessions_and_no_request_after_creation_takes_a_unit(
    client: TestClient,
) -> None:
    """A unit or conventions on a frame, a target, a pose or an FK request is refused,
    naming the field (docs/engines.md): an engine developer must not think they apply."""
    s = create(client, _pose_leg(), conventions={"preset": "unreal"})
    sid, headers = s.id, s.headers
    identity = {"w": 1, "x": 0, "y": 0, "z": 0}
    target = {"effector": "foot", "position": {"x": 10, "y": 0, "z": 40}, "orientation": identity}
    refused = [
        ("post", f"/v1/sessions/{sid}/frames", {"targets": [{**target, "unit": "cm"}]},
         "frame.targets[0].unit"),
        ("post", f"/v1/sessions/{sid}/frames", {"targets": [target], "conventions": {"unit": "m"}},
         "frame.conventions"),
        ("put", f"/v1/sessions/{sid}/pose", {"joints": {"knee.x": 0.5}, "unit": "cm"}, "unit"),
        ("post", f"/v1/sessions/{sid}/fk", {"conventions": {"preset": "ros"}}, "conventions"),
    ]  # fmt: skip
    for method, path, body, field in refused:
        r = getattr(client, method)(path, json=body, headers=headers)
        assert r.status_code == 422 and r.json()["field"] == field, (path, r.text)
    # The answer's form of the unit is not the request's.
    r = client.post("/v1/sessions", json={"chain": _pose_leg(), "conventions": {"unit_m": 0.01}})
    assert r.status_code == 422 and r.json()["field"] == "conventions.unit_m"
