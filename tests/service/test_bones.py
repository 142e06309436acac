"""Bone output: on request only (session default, per-frame override), over HTTP and the
WebSocket, and the FK call (POST .../fk, WebSocket ``fk``)."""

from __future__ import annotations

import msgpack
import numpy as np
from starlette.testclient import TestClient

import schemas as S
from schemas.chain import EXAMPLE_GLTF_LEG

from .helpers import create

FOOT = {"effector": "foot", "position": {"x": 0.1, "y": 0.3, "z": 0.2}}


def test_results_carry_bones_only_when_asked(client: TestClient) -> None:
    plain = create(client, EXAMPLE_GLTF_LEG)
    url = f"/v1/sessions/{plain.id}/frames"
    r = client.post(url, json={"targets": [FOOT]}, headers=plain.headers).json()
    assert "bones" not in r["results"][0]
    r = client.post(
        url + "?results=compact",
        json={"targets": [FOOT], "bones": {"world": ["ankle"]}},
        headers=plain.headers,
    ).json()
    S.CompactFrameResults.model_validate(r)
    assert set(r["results"][0]["bones"]) == {"world"}
    # A session default, and a frame that turns it off.
    with_bones = create(client, EXAMPLE_GLTF_LEG, bones={"local_rotations": True})
    url = f"/v1/sessions/{with_bones.id}/frames"
    clip = {
        "frames": [{"targets": [FOOT]}, {"targets": [FOOT], "bones": {"local_rotations": False}}]
    }
    results = client.post(url, json=clip, headers=with_bones.headers).json()["results"]
    S.FrameResults.model_validate({"results": results})
    assert set(results[0]["bones"]["local"]) == {"hip", "knee"}
    assert "bones" not in results[1]


def test_local_rotations_are_unit_quaternions_of_the_pose(client: TestClient) -> None:
    s = create(client, EXAMPLE_GLTF_LEG, bones={"local_rotations": True})
    r = client.post(f"/v1/sessions/{s.id}/frames", json={"targets": [FOOT]}, headers=s.headers)
    result = r.json()["results"][0]
    knee = result["bones"]["local"]["knee"]
    angle = result["joints"]["knee.x"]
    # The knee rotates about x from an identity rest rotation: (cos a/2, sin a/2, 0, 0).
    expected = [np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0]
    assert np.allclose([knee["w"], knee["x"], knee["y"], knee["z"]], expected)


def test_fk_over_http_does_not_move_the_session(client: TestClient) -> None:
    s = create(client, EXAMPLE_GLTF_LEG)
    url = f"/v1/sessions/{s.id}/fk"
    r = client.post(
        url, json={"joints": {"knee.x": 1.0}, "bones": {"world": ["ankle"]}}, headers=s.headers
    )
    assert r.status_code == 200, r.text
    body = S.FkResult.model_validate(r.json())
    assert body.bones is not None and body.bones.world is not None
    ankle = body.bones.world["ankle"].position
    # Hip at y=1; knee 0.45 below; the shin turned 1 rad about x.
    assert np.allclose(
        [ankle.x, ankle.y, ankle.z], [0.0, 0.55 - 0.45 * np.cos(1.0), -0.45 * np.sin(1.0)]
    )
    pose = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["pose"]
    assert pose["joints"]["knee.x"] == s.body["pose"]["joints"]["knee.x"]
    bad = client.post(url, json={"q": [0.0], "joints": {"knee.x": 1.0}}, headers=s.headers)
    assert bad.status_code == 422 and bad.json()["field"] == "joints"
    bad = client.post(url, json={"q": [0.0]}, headers=s.headers)
    assert bad.status_code == 422 and bad.json()["field"] == "q"
    bad = client.post(url, json={"bones": {"world": ["ankel"]}}, headers=s.headers)
    assert bad.status_code == 422 and bad.json()["field"] == "bones.world[0]"


def test_fk_on_a_chain_without_bones_refuses_only_bone_data(client: TestClient) -> None:
    s = create(client)
    url = f"/v1/sessions/{s.id}/fk"
    # Found by schemathesis: asking for no bone output at all was a 500; it is now the
    # effectors' poses without bones (test_fk.py checks their values).
    for body in ({}, {"bones": {"local_rotations": False, "world": []}, "joints": {}}):
        r = client.post(url, json=body, headers=s.headers)
        assert r.status_code == 200, r.text
        answer = S.FkResult.model_validate(r.json())
        assert answer.bones is None and [e.name for e in answer.effectors] == ["hand"]
    r = client.post(url, json={"bones": {"local_rotations": True}}, headers=s.headers)
    assert r.status_code == 422 and "gltf or bvh" in r.json()["detail"], r.text
    assert r.json()["field"] == "bones"
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "fk", "id": 1, "bones": {"world": ["hand"]}})
        error = S.ErrorMessage.model_validate(ws.receive_json()).error
        assert error.code == "invalid_problem" and "gltf or bvh" in error.message
        assert error.field == "bones"


def test_websocket_frames_and_fk_carry_bones(client: TestClient) -> None:
    s = create(client, EXAMPLE_GLTF_LEG, conventions={"preset": "unity"})
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "frame", "id": 1, "targets": [FOOT]})  # the fast path
        a = S.ResultMessage.model_validate(ws.receive_json())
        assert a.success and a.result.bones is None
        ws.send_json({"type": "frame", "id": 2, "targets": [FOOT], "bones": {"world": ["ankle"]}})
        b = S.ResultMessage.model_validate(ws.receive_json())
        assert b.result.bones is not None and b.result.bones.world is not None
        ankle = b.result.bones.world["ankle"].position
        # Unity mirrors X: the target's x = 0.1 is reached at x = 0.1 in Unity's numbers.
        assert np.allclose([ankle.x, ankle.y, ankle.z], [0.1, 0.3, 0.2], atol=1e-3)
        ws.send_bytes(msgpack.packb({"type": "fk", "id": 3, "bones": {"world": ["ankle"]}}))
        c = S.FkResultMessage.model_validate(msgpack.unpackb(ws.receive_bytes()))
        assert c.q == b.result.q  # the current pose: the last answer
        ws.send_json({"type": "fk", "id": 4, "bones": {"world": ["nope"]}})
        d = S.ErrorMessage.model_validate(ws.receive_json())
        assert d.error.field == "bones.world[0]"
