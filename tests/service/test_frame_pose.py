"""A frame's animated ``pose`` (IK on top of an animation): a frame may carry the pose it
starts from, over HTTP, the WebSocket (JSON and MessagePack), in a batch entry and in a
tracked clip; as ``PUT .../pose`` then the frame, in one step. Redis: the stored answer
of a frame sent again and a cancelled frame's rewind are in tests/service/test_redis_store.py.
"""

from __future__ import annotations

import json
from typing import Any

import msgpack
import numpy as np
import pytest
from starlette.testclient import TestClient

import schemas as S
from service import convert
from solver.ik import IKSolver, StreamState

from .helpers import Created, create, hand_frame

# Generous: what a frame finds must not depend on how busy the machine is.
OPTIONS = {"time_budget_us": 50_000.0}
# The example arm (shoulder z, shoulder y, elbow): an animated pose, and the previous
# answer's target far from it.
ANIMATED = [0.4, 0.3, 1.1]
TAIL = {"format": "example", "name": "tail"}


def _fk_position(client: TestClient, s: Created, q: list[float], effector: int = 0) -> dict:
    r = client.post(f"/v1/sessions/{s.id}/fk", json={"q": q}, headers=s.headers)
    assert r.status_code == 200, r.text
    position: dict[str, float] = r.json()["effectors"][effector]["position"]
    return position


def _at(position: dict[str, float], frame_id: int, effector: str = "hand") -> dict[str, Any]:
    return {"id": frame_id, "targets": [{"effector": effector, "position": position}]}


def _post(client: TestClient, s: Created, body: dict[str, Any]) -> list[dict[str, Any]]:
    r = client.post(f"/v1/sessions/{s.id}/frames", json=body, headers=s.headers)
    assert r.status_code == 200, r.text
    results: list[dict[str, Any]] = r.json()["results"]
    return results


def _moved_away(client: TestClient) -> tuple[Created, list[float]]:
    """A session whose previous answer is far from ``ANIMATED``; its q."""
    s = create(client, options=OPTIONS)
    (first,) = _post(client, s, hand_frame(1, x=0.3, y=-0.3, z=0.5))
    assert first["success"]
    assert np.max(np.abs(np.subtract(first["q"], ANIMATED))) > 0.3
    return s, first["q"]


def test_http_frame_starts_from_its_animated_pose(client: TestClient) -> None:
    """A frame whose target is met at the animated pose answers that pose, with a
    largest step of ~0; without ``pose`` the same frame moves from the previous answer.
    The next frame without ``pose`` continues from the answer."""
    s, before = _moved_away(client)
    target = _fk_position(client, s, ANIMATED)
    (r,) = _post(client, s, {**_at(target, 2), "pose": {"q": ANIMATED}})
    assert r["success"] and r["id"] == 2
    np.testing.assert_allclose(r["q"], ANIMATED, rtol=0, atol=1e-6)
    assert r["largest_step_rad"] < 1e-6 and not r["jumped"]
    pose = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["pose"]["q"]
    np.testing.assert_allclose(pose, r["q"], rtol=0, atol=0)
    # Without the pose: from the previous answer, far from it.
    other, q_other = _moved_away(client)
    (plain,) = _post(client, other, _at(target, 2))
    assert plain["largest_step_rad"] > 0.05
    # A later frame without pose continues from the answer.
    (later,) = _post(client, s, hand_frame(3, x=target["x"], y=target["y"], z=target["z"]))
    assert later["largest_step_rad"] < 1e-6
    assert before != pytest.approx(later["q"], abs=1e-3)


def test_http_frame_joints_set_some_dofs_and_keep_the_others(client: TestClient) -> None:
    """``joints``: the DOFs named take the animated values, the others keep the current
    pose (the previous answer), and the frame starts there. Out of limits is clipped."""
    s, before = _moved_away(client)
    elbow = s.body["dof"][2]["name"]
    assert elbow == "elbow"
    start = [before[0], before[1], 2.0]
    target = _fk_position(client, s, start)
    (r,) = _post(client, s, {**_at(target, 2), "pose": {"joints": {"elbow": 2.0}}})
    np.testing.assert_allclose(r["q"], start, rtol=0, atol=1e-6)
    assert r["largest_step_rad"] < 1e-6
    # Clipped into the limits (elbow: [0, 2.6]).
    clipped = [before[0], before[1], 2.6]
    target = _fk_position(client, s, clipped)
    (r,) = _post(client, s, {**_at(target, 3), "pose": {"joints": {"elbow": 9.0}}})
    np.testing.assert_allclose(r["q"], clipped, rtol=0, atol=1e-6)


@pytest.mark.parametrize("encoding", ["json", "msgpack"])
def test_ws_frame_starts_from_its_animated_pose(client: TestClient, encoding: str) -> None:
    """The WebSocket ``frame`` message with ``pose`` (the pydantic path; the fast path
    declines it) answers from the animated pose, in either encoding; the next frame
    without it continues from the answer (the fast path)."""
    s, _ = _moved_away(client)
    target = _fk_position(client, s, ANIMATED)
    msgs = [
        {"type": "frame", **_at(target, 5), "pose": {"q": ANIMATED}},
        {"type": "frame", **_at(target, 6)},
    ]
    replies = []
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        for m in msgs:
            if encoding == "json":
                ws.send_text(json.dumps(m))
                replies.append(ws.receive_json())
            else:
                ws.send_bytes(msgpack.packb(m))
                replies.append(msgpack.unpackb(ws.receive_bytes()))
    for reply in replies:
        assert reply["type"] == "result" and reply["success"], reply
        np.testing.assert_allclose(reply["result"]["q"], ANIMATED, rtol=0, atol=1e-6)
        assert reply["result"]["largest_step_rad"] < 1e-6


def test_batch_entry_with_pose_among_entries_without(client: TestClient) -> None:
    """A batch entry with ``pose`` starts from it; an entry without, of the same session
    after it, continues from its answer; another session's entry is not touched. Over
    HTTP and the WebSocket."""
    for transport in ("http", "ws"):
        s, _ = _moved_away(client)
        other, other_q = _moved_away(client)
        target = _fk_position(client, s, ANIMATED)
        entries = [
            {"session": other.id, "token": other.token, **hand_frame(1, x=0.3, y=-0.3, z=0.5)},
            {"session": s.id, "token": s.token, **_at(target, 2), "pose": {"q": ANIMATED}},
            {"session": s.id, "token": s.token, **_at(target, 3)},
        ]
        if transport == "http":
            r = client.post("/v1/batch", json={"frames": entries})
            assert r.status_code == 200, r.text
            results = r.json()["results"]
        else:
            with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
                ws.send_text(json.dumps({"type": "batch", "id": 1, "frames": entries}))
                results = ws.receive_json()["results"]
        assert [e["success"] for e in results] == [True, True, True], results
        np.testing.assert_allclose(results[0]["result"]["q"], other_q, rtol=0, atol=1e-4)
        for e in results[1:]:
            np.testing.assert_allclose(e["result"]["q"], ANIMATED, rtol=0, atol=1e-6)
            assert e["result"]["largest_step_rad"] < 1e-6


def test_tracked_clip_frames_may_carry_poses_a_planned_clip_may_not(client: TestClient) -> None:
    """A tracked clip: each frame with ``pose`` starts from it, one without from the
    answer before. A planned clip has one start: its frames' poses are refused, naming
    the frame (and nothing is solved)."""
    s, before = _moved_away(client)
    target = _fk_position(client, s, ANIMATED)
    other = [0.0, 0.5, 0.8]
    target2 = _fk_position(client, s, other)
    frames = [
        {**_at(target, 2), "pose": {"q": ANIMATED}},
        _at(target, 3),
        {**_at(target2, 4), "pose": {"q": other}},
    ]
    results = _post(client, s, {"frames": frames})
    for r, q in zip(results, [ANIMATED, ANIMATED, other], strict=True):
        np.testing.assert_allclose(r["q"], q, rtol=0, atol=1e-6)
        assert r["largest_step_rad"] < 1e-6
    s2, before2 = _moved_away(client)
    r = client.post(
        f"/v1/sessions/{s2.id}/frames",
        json={
            "frames": [_at(target, 2), {**_at(target, 3), "pose": {"q": ANIMATED}}],
            "plan": True,
        },
        headers=s2.headers,
    )
    assert r.status_code == 422 and r.json()["code"] == "invalid_problem", r.text
    assert r.json()["field"] == "frames[1].pose"
    info = client.get(f"/v1/sessions/{s2.id}", headers=s2.headers).json()
    assert info["pose"]["q"] == before2 and info["counters"]["frames"] == 1
    with client.websocket_connect(f"/v1/sessions/{s2.id}/ws", headers=s2.headers) as ws:
        clip = {"type": "clip", "id": 1, "plan": True, "frames": frames}
        ws.send_text(json.dumps(clip))
        reply = ws.receive_json()
    assert not reply["success"] and reply["error"]["code"] == "invalid_problem"
    assert reply["error"]["field"] == "frames[0].pose"


def test_bad_poses_name_their_field(client: TestClient) -> None:
    """A pose that does not fit the chain is refused naming the field, as PUT pose's
    errors do: ``pose.q`` / ``pose.joints.<name>`` for a frame (HTTP and WebSocket),
    ``frames[i].pose...`` for a batch entry (the other entries are solved) and a clip's
    frame. Nothing is solved."""
    s, before = _moved_away(client)
    frame = hand_frame(2)
    cases = [({"q": [0.1, 0.2]}, "pose.q"), ({"joints": {"knee": 0.1}}, "pose.joints.knee")]
    for pose, field in cases:
        r = client.post(
            f"/v1/sessions/{s.id}/frames", json={**frame, "pose": pose}, headers=s.headers
        )
        assert r.status_code == 422 and r.json()["code"] == "invalid_problem", r.text
        assert r.json()["field"] == field
        body = {"frames": [hand_frame(2), {**hand_frame(3), "pose": pose}]}
        r = client.post(f"/v1/sessions/{s.id}/frames", json=body, headers=s.headers)
        assert r.status_code == 422 and r.json()["field"] == f"frames[1].{field}", r.text
        with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
            ws.send_text(json.dumps({"type": "frame", **frame, "pose": pose}))
            reply = ws.receive_json()
            assert reply["error"]["code"] == "invalid_problem"
            assert reply["error"]["field"] == field
            entries = [
                {"session": s.id, "token": s.token, **hand_frame(4)},
                {"session": s.id, "token": s.token, **hand_frame(5), "pose": pose},
            ]
            ws.send_text(json.dumps({"type": "batch", "id": 10, "frames": entries}))
            reply = ws.receive_json()
            assert "results" in reply, reply
            ok, bad = reply["results"]
        assert "result" in ok and not bad["success"]  # the other entry is solved
        assert bad["error"]["code"] == "invalid_problem"
        assert bad["error"]["field"] == f"frames[1].{field}"
    # Both q and joints: the schema's error (pydantic), naming the pose.
    r = client.post(
        f"/v1/sessions/{s.id}/frames",
        json={**frame, "pose": {"q": ANIMATED, "joints": {"elbow": 1.0}}},
        headers=s.headers,
    )
    assert r.status_code == 422 and "pose" in r.text, r.text


def test_the_animated_pose_is_the_rest_pose(client: TestClient) -> None:
    """The posture pull (the null-space step of a redundant chain) steers towards the
    frame's animated pose, as after PUT pose: a 40-DOF tail holding a target met at the
    animated pose stays there frame after frame, where a stream whose rest pose is
    another (the pose set before) drifts away along its self-motion."""
    s = create(client, TAIL, options={"time_budget_us": 20_000.0})
    n = len(s.body["dof"])
    elsewhere = [0.3] * n
    r = client.put(f"/v1/sessions/{s.id}/pose", json={"q": elsewhere}, headers=s.headers)
    assert r.status_code == 200, r.text
    animated = [-0.2 if i % 2 else 0.25 for i in range(n)]
    target = _fk_position(client, s, animated)
    # The tip sways by a few millimetres (a frame whose target is met as it stands
    # does not move).
    sway = [{**target, "x": target["x"] + 0.003 * np.sin(i)} for i in range(40)]
    frames = [{**_at(sway[0], 1, "tip"), "pose": {"q": animated}}]
    frames += [_at(sway[i], i + 1, "tip") for i in range(1, 40)]
    results = _post(client, s, {"frames": frames})
    assert all(r["success"] for r in results)
    drift = np.max(np.abs(np.subtract(results[-1]["q"], animated)))
    assert drift < 0.01, drift
    # The control: the same stream from the animated pose with the rest pose left at
    # the pose set before drifts along its self-motion towards it.
    store = client.app.state.ik.store  # type: ignore[attr-defined]
    session = client.portal.call(store.get, s.id)
    assert session is not None
    solver = IKSolver(session.view.chain, session.options)
    solver.set_pose(np.array(elsewhere))
    solver.restore(StreamState(np.array(animated), None, False, 0))
    for frame in frames:
        targets = convert.targets(S.Frame(**frame).targets, session.view, "targets")
        q = solver.track(targets, options=session.options).q
    assert np.max(np.abs(q - animated)) > 0.1
