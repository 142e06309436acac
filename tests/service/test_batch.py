"""Batches (many characters per message) over the TestClient: one answer per entry, in
order; each entry's own errors; the same solves as frames sent one by one; limits."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import pytest
from numpy.testing import assert_allclose
from pydantic import TypeAdapter
from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

import schemas as S
from service.config import Settings
from service.sessions import InMemorySessionStore

from .helpers import Created, create, hand_frame

SERVER_MESSAGE: TypeAdapter[Any] = TypeAdapter(S.ServerMessage)
ErrorCodes = S.ErrorCode


def entry(s: Created, frame_id: int | None, y: float = 0.1, **extra: Any) -> dict[str, Any]:
    return {"session": s.id, "token": s.token, **hand_frame(frame_id, y=y), **extra}


def batch_msg(msg_id: int, entries: list[dict[str, Any]]) -> dict[str, Any]:
    return {"type": "batch", "id": msg_id, "frames": entries}


def ws_url(s: Created) -> str:
    return f"/v1/sessions/{s.id}/ws"


def send_batch(client: TestClient, via: Created, msgs: list[dict[str, Any]]) -> list[Any]:
    with client.websocket_connect(ws_url(via), headers=via.headers) as ws:
        out = []
        for m in msgs:
            ws.send_text(json.dumps(m))
            out.append(SERVER_MESSAGE.validate_python(ws.receive_json()))
    return out


def test_ws_batch_answers_each_session_in_order(client: TestClient) -> None:
    a, b, c = (create(client) for _ in range(3))
    replies = send_batch(
        client,
        a,
        [
            batch_msg(1, [entry(a, 10, 0.1), entry(b, 20, 0.12), entry(c, 30, 0.14)]),
            batch_msg(2, [entry(c, 31, 0.15), entry(a, 11, 0.11)]),
        ],
    )
    first, second = replies
    assert isinstance(first, S.BatchResultMessage) and first.id == 1 and first.success
    assert [(r.session, r.id) for r in first.results] == [(a.id, 10), (b.id, 20), (c.id, 30)]
    assert [(r.session, r.id) for r in second.results] == [(c.id, 31), (a.id, 11)]
    assert all(isinstance(r, S.BatchEntryResult) and r.result.id == r.id for r in first.results)
    counters = {
        s.id: client.get(f"/v1/sessions/{s.id}", headers=s.headers).json() for s in (a, b, c)
    }
    assert [counters[s.id]["counters"]["frames"] for s in (a, b, c)] == [2, 1, 2]
    # Each session continued from its own last answer: its pose is the last result's q.
    assert counters[c.id]["pose"]["q"] == second.results[0].result.q


def test_batch_solves_as_frames_sent_one_by_one(client: TestClient) -> None:
    """The same frames give the same joint values whether batched or sent alone."""
    batched, alone = create(client), create(client)
    ys = [0.1, 0.13, 0.16]
    with client.websocket_connect(ws_url(batched), headers=batched.headers) as ws:
        for i, y in enumerate(ys):
            ws.send_text(json.dumps(batch_msg(i, [entry(batched, i, y)])))
            got = SERVER_MESSAGE.validate_python(ws.receive_json()).results[0].result.q
            frames_url = f"/v1/sessions/{alone.id}/frames"
            r = client.post(frames_url, json=hand_frame(i, y=y), headers=alone.headers)
            assert_allclose(got, r.json()["results"][0]["q"], rtol=0, atol=1e-12)


def test_one_bad_entry_gets_its_own_error(client: TestClient) -> None:
    a, b, gone = create(client), create(client), create(client)
    assert client.delete(f"/v1/sessions/{gone.id}", headers=gone.headers).status_code == 204
    bad_target = {**entry(b, 3), "targets": [{"effector": "hand", "position": {"x": "0.3"}}]}
    unknown = {
        **entry(b, 4),
        "targets": [{"effector": "foot", "position": {"x": 0, "y": 0, "z": 0}}],
    }
    entries = [
        entry(a, 1),
        {**entry(b, 2), "token": "not-the-token"},
        bad_target,
        unknown,
        entry(gone, 5),
        "not an entry",
        entry(b, 6),
    ]
    (reply,) = send_batch(client, a, [batch_msg(1, entries)])
    assert isinstance(reply, S.BatchResultMessage) and not reply.success
    codes = [r.error.code if isinstance(r, S.BatchEntryError) else "ok" for r in reply.results]
    assert codes == [
        "ok",
        ErrorCodes.FORBIDDEN,
        ErrorCodes.INVALID_FORMAT,
        ErrorCodes.INVALID_PROBLEM,
        ErrorCodes.NOT_FOUND,
        ErrorCodes.INVALID_FORMAT,
        "ok",
    ]
    errors = {i: r for i, r in enumerate(reply.results) if isinstance(r, S.BatchEntryError)}
    assert errors[2].error.field is not None and errors[2].error.field.startswith(
        "frames[2].targets"
    )
    assert errors[3].error.field == "frames[3].targets[0].effector"
    assert [(errors[i].session, errors[i].id) for i in (1, 4, 5)] == [
        (b.id, 2),
        (gone.id, 5),
        (None, None),
    ]
    assert reply.results[6].session == b.id and reply.results[6].success


@pytest.mark.parametrize("with_bones_key", [False, True])
def test_msgpack_batch_gets_msgpack_answer(client: TestClient, with_bones_key: bool) -> None:
    """Both ways through the server (the fast path, and pydantic for an entry that
    carries ``bones``) give the same answer."""
    a, b = create(client), create(client)
    extra = {"bones": None} if with_bones_key else {}
    msg = batch_msg(7, [entry(a, 1, **extra), entry(b, 2, **extra)])
    with client.websocket_connect(ws_url(a), headers=a.headers) as ws:
        ws.send_bytes(msgpack.packb(msg))
        reply = S.BatchResultMessage.model_validate(msgpack.unpackb(ws.receive_bytes()))
    assert reply.id == 7 and reply.success
    assert [(r.session, r.id) for r in reply.results] == [(a.id, 1), (b.id, 2)]


def test_rate_limit_is_per_session(make_client: Callable[..., TestClient]) -> None:
    # A bucket of 2 frames per session (burst: IK_MAX_FRAMES_PER_REQUEST), refilled at 1/s.
    client = make_client(Settings(max_frames_per_s=1.0, max_frames_per_request=2))
    a, b = create(client), create(client)
    msgs = [batch_msg(1, [entry(a, 1), entry(a, 2)]), batch_msg(2, [entry(a, 3), entry(b, 4)])]
    first, second = send_batch(client, a, msgs)
    assert isinstance(first, S.BatchResultMessage) and first.success
    assert isinstance(second, S.BatchResultMessage)
    assert [r.success for r in second.results] == [False, True]
    limited = second.results[0]
    assert isinstance(limited, S.BatchEntryError) and limited.id == 3
    assert limited.error.code == S.ErrorCode.RATE_LIMITED and limited.error.retry_after_s


def test_too_many_entries_fail_the_whole_message(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_frames_per_request=2))
    a = create(client)
    (reply,) = send_batch(client, a, [batch_msg(1, [entry(a, i) for i in range(3)])])
    assert isinstance(reply, S.ErrorMessage) and reply.id == 1
    assert reply.error.code == S.ErrorCode.INVALID_PROBLEM and reply.error.field == "frames"
    r = client.post("/v1/batch", json={"frames": [entry(a, i) for i in range(3)]})
    assert r.status_code == 422 and r.json()["code"] == "invalid_problem"


def test_a_pooled_batch_over_the_work_cap_fails_whole_naming_frames(
    make_client: Callable[..., TestClient],
) -> None:
    """docs/api.md and websocket.md: a batch that goes to the frame threads (an entry's
    time_budget_us over IK_INLINE_BUDGET_US) fails whole when the sum of its entries'
    budgets is over IK_MAX_REQUEST_WORK_S, as a clip does, and nothing is solved."""
    client = make_client(Settings(max_request_work_s=0.01))
    a, b = create(client), create(client)
    patched = client.patch(f"/v1/sessions/{a.id}", json={"time_budget_us": 4000}, headers=a.headers)
    assert patched.status_code == 200, patched.text
    entries = [entry(a, 1), entry(a, 2), entry(a, 3), entry(b, 1)]  # 3 x 4 ms + b's budget
    (reply,) = send_batch(client, b, [batch_msg(1, entries)])
    assert isinstance(reply, S.ErrorMessage) and reply.id == 1, reply
    assert reply.error.code == S.ErrorCode.INVALID_PROBLEM and reply.error.field == "frames"
    assert "IK_MAX_REQUEST_WORK_S" in reply.error.message
    r = client.post("/v1/batch", json={"frames": entries})
    assert r.status_code == 422, r.text
    assert r.json()["code"] == "invalid_problem" and r.json()["field"] == "frames"
    for s in (a, b):
        info = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()
        assert info["counters"]["frames"] == 0, info


def test_deleting_the_socket_s_own_session_ends_its_batches(client: TestClient) -> None:
    """websocket.md: a batch socket belongs to the session it was opened on. Another
    entry's session deleted fails that entry alone; the socket's own session deleted
    closes the socket 4404 at its next batch, whatever sessions the batch names."""
    own, other, gone = create(client), create(client), create(client)
    with client.websocket_connect(ws_url(own), headers=own.headers) as ws:
        ws.send_text(json.dumps(batch_msg(1, [entry(other, 1), entry(gone, 1)])))
        assert ws.receive_json()["success"] is True
        assert client.delete(f"/v1/sessions/{gone.id}", headers=gone.headers).status_code == 204
        ws.send_text(json.dumps(batch_msg(2, [entry(other, 2), entry(gone, 2)])))
        reply = SERVER_MESSAGE.validate_python(ws.receive_json())
        assert isinstance(reply, S.BatchResultMessage)
        assert reply.results[0].success
        gone_entry = reply.results[1]
        assert isinstance(gone_entry, S.BatchEntryError)
        assert gone_entry.error.code == S.ErrorCode.NOT_FOUND
        assert client.delete(f"/v1/sessions/{own.id}", headers=own.headers).status_code == 204
        ws.send_text(json.dumps(batch_msg(3, [entry(other, 3)])))
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_json()
    assert closed.value.code == 4404 and closed.value.reason == "not_found"


def test_batch_message_needs_increasing_ids(client: TestClient) -> None:
    a = create(client)
    first, again = send_batch(client, a, [batch_msg(5, [entry(a, 1)]), batch_msg(5, [entry(a, 2)])])
    assert isinstance(first, S.BatchResultMessage)
    assert isinstance(again, S.ErrorMessage) and again.error.code == S.ErrorCode.ID_REUSE


def test_http_batch(client: TestClient) -> None:
    a, b = create(client), create(client)
    body = {"frames": [entry(a, 1), {**entry(b, 2), "token": "wrong"}, entry(b, 3)]}
    r = client.post("/v1/batch", json=body)
    assert r.status_code == 200, r.text
    out = S.BatchResults.model_validate(r.json())
    assert [(x.session, x.id, x.success) for x in out.results] == [
        (a.id, 1, True),
        (b.id, 2, False),
        (b.id, 3, True),
    ]
    assert isinstance(out.results[1], S.BatchEntryError)
    assert out.results[1].error.code == S.ErrorCode.FORBIDDEN
    compact = client.post("/v1/batch?results=compact", json={"frames": [entry(a, 4)]}).json()
    (only,) = S.BatchResults.model_validate(compact).results
    assert isinstance(only, S.BatchEntryResult)
    assert isinstance(only.result, S.CompactFrameResult)
    assert np.isfinite(only.result.q).all()


# Mistakes a game engine's serializer makes, with the field a frame sent alone names.
_ENGINE_MISTAKES = [
    ({"targets": [{"effector": "hand", "position": [0.3, 0.1, 0.6]}]}, "targets[0].position"),
    ({"id": 3.0}, "id"),
    # A missing component: the hint reads the object it is missing from.
    (
        {"targets": [{"effector": "hand", "position": {"X": 0.3, "Y": 0.1, "Z": 0.6}}]},
        "targets[0].position.x",
    ),
]


@pytest.mark.parametrize(("mistake", "field"), _ENGINE_MISTAKES)
@pytest.mark.parametrize("transport", ["ws-json", "ws-msgpack", "http"])
def test_an_entry_s_mistake_gets_the_hint_a_frame_gets(
    client: TestClient, mistake: dict[str, Any], field: str, transport: str
) -> None:
    """An array where a vector belongs, or an id sent as 3.0, is told what to send in a
    batch entry too, not only pydantic's "a valid dictionary" or "a valid integer"."""
    a, b = create(client), create(client)
    with client.websocket_connect(ws_url(a), headers=a.headers) as ws:
        ws.send_text(json.dumps({"type": "frame", "id": 1, **hand_frame(None), **mistake}))
        alone = ws.receive_json()["error"]
        entries = [entry(a, 2), {**entry(b, 2), **mistake}]
        if transport == "http":
            answer = client.post("/v1/batch", json={"frames": entries}).json()
        elif transport == "ws-json":
            ws.send_text(json.dumps(batch_msg(2, entries)))
            answer = ws.receive_json()
        else:
            ws.send_bytes(msgpack.packb(batch_msg(2, entries)))
            answer = msgpack.unpackb(ws.receive_bytes())
    good, bad = answer["results"]
    assert good["success"] and good["session"] == a.id
    assert alone["field"] == f"frame.{field}"
    assert bad["error"] == {**alone, "field": f"frames[1].{field}"}
    hinted = ("not an array", "whole number", "lower case")
    assert any(words in alone["message"] for words in hinted), alone


@pytest.mark.parametrize("body", [{}, {"frames": []}, {"frames": "x"}, [], {"frames": [], "x": 1}])
def test_http_batch_envelope_errors(client: TestClient, body: Any) -> None:
    r = client.post("/v1/batch", json=body)
    assert r.status_code == 422 and r.json()["code"] == "invalid_format"


@pytest.mark.parametrize(
    ("inline_budget_us", "where"),
    [(20.0, "on the loop, a slice of 20 us at a time"), (5.0, "on the frame threads")],
)
def test_where_a_batch_is_solved_does_not_change_its_answers(
    make_client: Callable[..., TestClient], inline_budget_us: float, where: str
) -> None:
    """Entries with a 20 us budget: solved on the loop in slices of 20 us (a few entries
    each, the loop turning between them), or, with a smaller inline budget, on the frame
    threads; every entry is answered, in order, and each session moves on."""
    client = make_client(Settings(inline_budget_us=inline_budget_us))
    sessions = [create(client, options={"time_budget_us": 20.0}) for _ in range(4)]
    entries = [
        entry(s, 10 * k + i, 0.1 + 0.01 * k) for k in range(5) for i, s in enumerate(sessions)
    ]
    (reply,) = send_batch(client, sessions[0], [batch_msg(1, entries)])
    assert isinstance(reply, S.BatchResultMessage), where
    assert [(r.session, r.id) for r in reply.results] == [(e["session"], e["id"]) for e in entries]
    assert all(isinstance(r, S.BatchEntryResult) for r in reply.results), where
    for s in sessions:
        info = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()
        assert info["counters"]["frames"] == 5


def test_refused_batches_and_frames_cost_nothing_of_the_rate_limit(
    make_client: Callable[..., TestClient],
) -> None:
    """docs/websocket.md: a frame solved, or answered from storage, costs one of its
    session's IK_MAX_FRAMES_PER_S; one refused, alone or as a batch's entry, costs
    nothing. A client sending refused batches and frames at a high rate can still send
    its valid frames; valid frames over the limit are still limited."""
    now = [0.0]  # the rate limit's clock, frozen: no frame comes back with time
    store = InMemorySessionStore(max_sessions=10, ttl_s=1e9, clock=lambda: now[0])
    settings = Settings(max_frames_per_s=1.0, max_frames_per_request=2, max_request_work_s=0.01)
    client = make_client(settings, store=store)
    a, b, gone = create(client), create(client), create(client)
    # a's frames go to the frame threads (6 ms each): two in a request are over the cap.
    patched = client.patch(f"/v1/sessions/{a.id}", json={"time_budget_us": 6000}, headers=a.headers)
    assert patched.status_code == 200, patched.text
    assert client.delete(f"/v1/sessions/{gone.id}", headers=gone.headers).status_code == 204
    bad_target = {**entry(a, 3), "targets": [{"effector": "foot", "position": {"x": 0}}]}
    over_cap = [entry(a, 1), entry(a, 2)]
    refused = [
        (over_cap, "invalid_problem"),  # IK_MAX_REQUEST_WORK_S, for the whole batch
        ([entry(a, i) for i in range(3)], "invalid_problem"),  # IK_MAX_FRAMES_PER_REQUEST
        ([], "invalid_format"),  # no entries
        ([{**entry(a, 4), "token": "wrong"}, bad_target], "batch_result"),  # entries refused
        ([entry(gone, 5), {**entry(a, 6), "targets": []}], "batch_result"),
    ]
    with client.websocket_connect(ws_url(b), headers=b.headers) as ws:
        msg_id = 0
        for _ in range(10):
            for frames, expected in refused:
                msg_id += 1
                ws.send_text(json.dumps(batch_msg(msg_id, frames)))
                reply = ws.receive_json()
                got = reply["error"]["code"] if "error" in reply else reply["type"]
                assert got == expected, reply
                assert reply["success"] is False, reply
            ws.send_text(json.dumps(batch_msg(msg_id, [entry(a, 7)])))  # id_reuse
            assert ws.receive_json()["error"]["code"] == "id_reuse"
            r = client.post("/v1/batch", json={"frames": over_cap})
            assert r.status_code == 422 and r.json()["field"] == "frames", r.text
            clip = {"frames": [hand_frame(1), hand_frame(2)]}
            r = client.post(f"/v1/sessions/{a.id}/frames", json=clip, headers=a.headers)
            assert r.status_code == 422 and r.json()["field"] == "frames", r.text
        info = client.get(f"/v1/sessions/{a.id}", headers=a.headers).json()
        assert info["counters"]["frames"] == 0, info
        # a's bucket is whole: two frames (its burst), one in a batch, one alone...
        ws.send_text(json.dumps(batch_msg(msg_id + 1, [entry(a, 10)])))
        assert ws.receive_json()["success"] is True
        r = client.post(f"/v1/sessions/{a.id}/frames", json=hand_frame(11), headers=a.headers)
        assert r.status_code == 200, r.text
        # ...and the third is over the limit, in a batch and alone.
        ws.send_text(json.dumps(batch_msg(msg_id + 2, [entry(a, 12)])))
        (limited,) = ws.receive_json()["results"]
        assert limited["error"]["code"] == "rate_limited", limited
    r = client.post(f"/v1/sessions/{a.id}/frames", json=hand_frame(12), headers=a.headers)
    assert r.status_code == 429 and r.json()["code"] == "rate_limited", r.text


def test_a_session_in_a_batch_does_not_expire_while_the_batch_waits(
    make_client: Callable[..., TestClient],
) -> None:
    """A character idle for most of IK_SESSION_TTL_S whose batch waits for its session's
    lock (another request on it) past the TTL is in use: the expiry sweep must not take
    it meanwhile, answering the entry and leaving the next tick a not_found."""
    now = [0.0]
    store = InMemorySessionStore(max_sessions=10, ttl_s=10.0, clock=lambda: now[0])
    client = make_client(store=store)
    character = create(client)
    session = client.portal.call(store.get, character.id)
    assert session is not None
    now[0] = 9.0  # idle 9 s of 10
    client.portal.call(session.lock.acquire)  # another request holds the session
    answers: list[Any] = []
    sending = threading.Thread(
        target=lambda: answers.append(
            client.post("/v1/batch", json={"frames": [entry(character, 1)]})
        )
    )
    sending.start()
    deadline = time.monotonic() + 10
    while not session.lock._waiters and time.monotonic() < deadline:  # the batch waits
        time.sleep(0.005)
    assert session.lock._waiters, "the batch never reached the session's lock"
    now[0] = 11.0  # 11 s after the last frame before the batch, 2 s after the batch came
    client.portal.call(store.expire)
    client.portal.call(session.lock.release)
    sending.join(10)
    (first,) = answers
    assert first.json()["results"][0]["success"], first.text
    again = client.post("/v1/batch", json={"frames": [entry(character, 2)]}).json()
    assert again["results"][0]["success"], again


def test_a_session_idle_past_its_ttl_is_not_found_through_a_socket_that_opened_it(
    make_client: Callable[..., TestClient],
) -> None:
    """A socket's batches remember the sessions they opened; one idle past the TTL (no
    socket of its own, not yet swept) was still solved through them, and kept alive,
    while HTTP answered 404 for it (game-server trial). Both now answer not_found."""
    now = [0.0]
    store = InMemorySessionStore(max_sessions=10, ttl_s=10.0, clock=lambda: now[0])
    client = make_client(store=store)
    owner, character = create(client), create(client)
    with client.websocket_connect(ws_url(owner), headers=owner.headers) as ws:
        ws.send_text(json.dumps(batch_msg(1, [entry(character, 1)])))
        assert ws.receive_json()["results"][0]["success"]
        now[0] = 11.0  # the character idle 11 s; the owner's socket keeps the owner
        ws.send_text(json.dumps(batch_msg(2, [entry(owner, 2), entry(character, 2)])))
        kept, gone = ws.receive_json()["results"]
    assert kept["success"], kept
    assert gone["error"]["code"] == "not_found" and gone["session"] == character.id, gone
    r = client.get(f"/v1/sessions/{character.id}", headers=character.headers)
    assert r.status_code == 404, r.text


def test_a_batch_refused_whole_is_no_use_of_its_sessions(
    make_client: Callable[..., TestClient],
) -> None:
    """A batch marks its sessions used when it admits them (so the sweep leaves them
    while it waits); refused whole (over IK_MAX_REQUEST_WORK_S here), it is no use of
    them, as a frame refused alone is not: their idle time stands (review)."""
    now = [0.0]
    store = InMemorySessionStore(max_sessions=10, ttl_s=10.0, clock=lambda: now[0])
    client = make_client(Settings(max_request_work_s=0.01), store=store)
    a, b = create(client), create(client)
    patched = client.patch(f"/v1/sessions/{a.id}", json={"time_budget_us": 4000}, headers=a.headers)
    assert patched.status_code == 200, patched.text
    now[0] = 9.0
    entries = [entry(a, 1), entry(a, 2), entry(a, 3), entry(b, 1)]
    r = client.post("/v1/batch", json={"frames": entries})
    assert r.status_code == 422 and r.json()["field"] == "frames", r.text
    for s in (a, b):
        session = client.portal.call(store.get, s.id)
        assert session is not None and store.idle_s(session) == 9.0
    now[0] = 10.5  # past the TTL since their last use: the refused batch was none
    assert client.portal.call(store.expire) and len(store) == 0
