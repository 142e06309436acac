"""Batches through a real uvicorn: pipelined batch messages answered in order with each
session's frames in order, MessagePack, an entry's own error, per-session rate limits,
the size caps of a message and of a body."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import httpx
import msgpack
import pytest
from websockets.exceptions import ConnectionClosed

from .conftest import Server
from .test_server import TIMEOUT_S, session, tool_target, ws_connect

pytestmark = pytest.mark.live


def entry(sid: str, headers: dict[str, str], frame_id: int, y: float) -> dict[str, Any]:
    token = headers["Authorization"].removeprefix("Bearer ")
    return {"session": sid, "token": token, "id": frame_id, "targets": [tool_target(y)]}


def frames_of(server: Server, sid: str, headers: dict[str, str]) -> int:
    r = httpx.get(f"{server.base}/v1/sessions/{sid}", headers=headers, timeout=TIMEOUT_S)
    return int(r.json()["counters"]["frames"])


def test_pipelined_batches_in_order_json_and_msgpack(server: Server) -> None:
    (a, ha), (b, hb), (c, hc) = session(server), session(server), session(server)
    with ws_connect(server, a, ha) as ws:
        for i in range(10):  # sent back to back: answered in order, each entry in place
            es = [
                entry(a, ha, i, 0.1 + 0.002 * i),
                entry(b, hb, 100 + i, 0.12),
                entry(c, hc, i, 0.14),
            ]
            ws.send(json.dumps({"type": "batch", "id": i, "frames": es}))
        replies = [json.loads(ws.recv(timeout=TIMEOUT_S)) for _ in range(10)]
        ws.send(msgpack.packb({"type": "batch", "id": 10, "frames": [entry(b, hb, 7, 0.13)]}))
        packed = ws.recv(timeout=TIMEOUT_S)
    assert [r["id"] for r in replies] == list(range(10))
    assert all(r["type"] == "batch_result" for r in replies)
    for i, r in enumerate(replies):
        assert [(e["session"], e["id"]) for e in r["results"]] == [(a, i), (b, 100 + i), (c, i)]
        assert all(e["result"]["id"] == e["id"] for e in r["results"])
    assert isinstance(packed, bytes)
    last = msgpack.unpackb(packed)
    assert last["id"] == 10 and last["results"][0]["session"] == b
    assert [frames_of(server, s, h) for s, h in ((a, ha), (b, hb), (c, hc))] == [10, 11, 10]


def test_entry_errors_and_rate_limits(start_server: Callable[..., Server]) -> None:
    server = start_server(IK_MAX_FRAMES_PER_S="1", IK_MAX_FRAMES_PER_REQUEST="3")
    (a, ha), (b, hb) = session(server), session(server)
    bad = {**entry(b, hb, 2, 0.1), "targets": [{"effector": "tool"}]}
    with ws_connect(server, a, ha) as ws:
        ws.send(msgpack.packb({"type": "batch", "id": 1, "frames": [entry(a, ha, 1, 0.1), bad]}))
        first = msgpack.unpackb(ws.recv(timeout=TIMEOUT_S))
        # a's bucket holds 3 (IK_MAX_FRAMES_PER_REQUEST) and refills at 1/s: the 4th waits.
        es = [entry(a, ha, i, 0.1) for i in (3, 4, 5)]
        ws.send(msgpack.packb({"type": "batch", "id": 2, "frames": es}))
        second = msgpack.unpackb(ws.recv(timeout=TIMEOUT_S))
    assert [e["success"] for e in first["results"]] == [True, False]
    assert first["results"][1]["error"]["code"] == "invalid_format"
    assert first["results"][1]["error"]["field"].startswith("frames.1.targets.0")
    codes = [e.get("error", {}).get("code") for e in second["results"]]
    assert codes[:2] == [None, None] and codes[2] == "rate_limited"
    assert second["results"][2]["error"]["retry_after_s"] > 0


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
