"""Batches through a real uvicorn: pipelined batch messages answered in order with each
session's frames in order, MessagePack, an entry's own error, per-session rate limits,
the size caps of a message and of a body.

The batches go through ik_client's stream; the size caps (a message over the limit,
closed 1009; a body over it, 413) are written by hand, as the wire they test.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import httpx
import pytest
from ik_client import BatchAnswer, BatchFrame, Client, Encoding, ErrorCode, Session
from websockets.exceptions import ConnectionClosed

from .conftest import Server
from .test_server import PANDA, TIMEOUT_S, session, tool_target, ws_connect

pytestmark = pytest.mark.live


def entry(sid: str, headers: dict[str, str], frame_id: int, y: float) -> dict[str, Any]:
    token = headers["Authorization"].removeprefix("Bearer ")
    return {"session": sid, "token": token, "id": frame_id, "targets": [tool_target(y)]}


def batch_frame(s: Session, frame_id: int, y: float) -> BatchFrame:
    return {"session": s.id, "token": s.token, "id": frame_id, "targets": [tool_target(y)]}


def test_pipelined_batches_in_order_json_and_msgpack(server: Server) -> None:
    with Client(server.base, timeout_s=TIMEOUT_S) as ik:
        a, b, c = (ik.create_session(PANDA) for _ in range(3))
        with ik.stream(a) as stream:
            sent = [  # back to back: answered in order, each entry in place
                stream.send_batch(
                    [
                        batch_frame(a, i, 0.1 + 0.002 * i),
                        batch_frame(b, 100 + i, 0.12),
                        batch_frame(c, i, 0.14),
                    ]
                )  # fmt: skip
                for i in range(10)
            ]
            replies = [stream.receive() for _ in range(10)]
        with ik.stream(a, encoding=Encoding.MSGPACK) as packed:
            last = packed.batch([batch_frame(b, 7, 0.13)])
        assert [r.id for r in replies] == sent
        for i, r in enumerate(replies):
            assert isinstance(r, BatchAnswer)
            assert [(e.session, e.id) for e in r.results] == [(a.id, i), (b.id, 100 + i), (c.id, i)]
            assert all(e.result is not None and e.result.id == e.id for e in r.results)
        assert last[0].session == b.id and last[0].result is not None
        assert [ik.get_session(s).counters.frames for s in (a, b, c)] == [10, 11, 10]


def test_entry_errors_and_rate_limits(start_server: Callable[..., Server]) -> None:
    server = start_server(IK_MAX_FRAMES_PER_S="1", IK_MAX_FRAMES_PER_REQUEST="3")
    with Client(server.base, timeout_s=TIMEOUT_S) as ik:
        a, b = ik.create_session(PANDA), ik.create_session(PANDA)
        bad: Any = {**batch_frame(b, 2, 0.1), "targets": [{"effector": "tool"}]}
        with ik.stream(a, encoding=Encoding.MSGPACK) as stream:
            first = stream.batch([batch_frame(a, 1, 0.1), bad])
            # a's bucket holds 3 (IK_MAX_FRAMES_PER_REQUEST) and refills at 1/s: the 4th waits.
            second = stream.batch([batch_frame(a, i, 0.1) for i in (3, 4, 5)])
    assert [e.success for e in first] == [True, False]
    assert first[1].error is not None and first[1].error.code is ErrorCode.INVALID_FORMAT
    assert (first[1].error.field or "").startswith("frames[1].targets[0]")
    codes = [None if e.error is None else e.error.code for e in second]
    assert codes == [None, None, ErrorCode.RATE_LIMITED]
    retry_after_s = second[2].error.retry_after_s if second[2].error else None
    assert retry_after_s is not None and retry_after_s > 0


def test_size_caps(start_server: Callable[..., Server]) -> None:
    """A batch over IK_WS_MAX_MESSAGE_BYTES closes the socket 1009; over HTTP, a body
    over IK_MAX_BODY_BYTES is a 413."""
    server = start_server(IK_WS_MAX_MESSAGE_BYTES="8192", IK_MAX_BODY_BYTES="8192")
    a, ha = session(server)
    entries = [entry(a, ha, i, 0.1) for i in range(40)]  # about 12 kB of JSON
    with ws_connect(server, a, ha, max_size=None) as ws:
        ws.send(json.dumps({"type": "batch", "id": 1, "frames": entries[:5]}))
        assert json.loads(ws.recv(timeout=TIMEOUT_S))["type"] == "batch_result"
        ws.send(json.dumps({"type": "batch", "id": 2, "frames": entries}))
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=TIMEOUT_S)
    assert closed.value.rcvd is not None and closed.value.rcvd.code == 1009
    r = httpx.post(f"{server.base}/v1/batch", json={"frames": entries}, timeout=TIMEOUT_S)
    assert r.status_code == 413 and r.json()["code"] == "payload_too_large"


def test_refused_batches_at_a_high_rate_leave_the_valid_frames_their_rate(
    start_server: Callable[..., Server],
) -> None:
    """A client sending batches refused whole (over IK_MAX_REQUEST_WORK_S, too many
    entries) and entries refused on their own (a wrong token, a bad target) as fast as
    it can spends nothing of its session's IK_MAX_FRAMES_PER_S: its next valid frames
    are solved up to the burst, and the one after is still rate limited. A refill of
    0.1 frame/s keeps that true on a slow machine."""
    server = start_server(
        IK_MAX_FRAMES_PER_S="0.1", IK_MAX_FRAMES_PER_REQUEST="2", IK_MAX_REQUEST_WORK_S="0.01"
    )
    a, ha = session(server)
    # 6 ms per frame: to the frame threads, and two in a request are over the work cap.
    r = httpx.patch(
        f"{server.base}/v1/sessions/{a}",
        json={"time_budget_us": 6000},
        headers=ha,
        timeout=TIMEOUT_S,
    )
    assert r.status_code == 200, r.text
    wrong = {**entry(a, ha, 3, 0.1), "token": "not-the-token"}
    bad = {**entry(a, ha, 4, 0.1), "targets": [{"effector": "tool"}]}
    refused = [
        [entry(a, ha, 1, 0.1), entry(a, ha, 2, 0.1)],
        [entry(a, ha, i, 0.1) for i in range(3)],
        [wrong, bad],
    ]
    with ws_connect(server, a, ha) as ws:
        for msg_id in range(1, 61):
            frames = refused[msg_id % len(refused)]
            ws.send(json.dumps({"type": "batch", "id": msg_id, "frames": frames}))
        replies = [json.loads(ws.recv(timeout=TIMEOUT_S)) for _ in range(60)]
        assert all(x["success"] is False for x in replies)
        codes = {x["error"]["code"] if "error" in x else x["type"] for x in replies}
        assert codes == {"invalid_problem", "batch_result"}, codes
        valid = [entry(a, ha, 10 + k, 0.1 + 0.01 * k) for k in range(3)]
        for k, one in enumerate(valid):
            ws.send(json.dumps({"type": "batch", "id": 100 + k, "frames": [one]}))
        answers = [json.loads(ws.recv(timeout=TIMEOUT_S))["results"][0] for _ in valid]
    got = [x["error"]["code"] if "error" in x else "ok" for x in answers]
    assert got == ["ok", "ok", "rate_limited"], answers
