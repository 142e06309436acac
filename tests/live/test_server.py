"""`python -m service` for real: uvicorn, WebSockets (JSON, MessagePack), limits, shutdown.

What an ordinary client sees (shutdown's answers and close codes) goes through
ik_client; raw websockets and sockets stay where the wire itself is tested: JSON and
MessagePack messages on one socket, a malformed message, a refused handshake, an
oversized message, the token in the query string, readers that stop reading.
"""

from __future__ import annotations

import base64
import errno
import json
import os
import re
import signal
import socket
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from typing import Any

import httpx
import msgpack
import pytest
from ik_client import (
    Client,
    FrameAnswer,
    Reconnect,
    RetryLater,
    ServerRestarting,
    SolverOptionsPatch,
    Stream,
)
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from .conftest import Server

pytestmark = pytest.mark.live

TIMEOUT_S = 30.0
PANDA = {"format": "example", "name": "panda_arm"}


def tool_target(y: float) -> dict[str, Any]:
    return {
        "effector": "tool",
        "position": {"x": 0.4, "y": y, "z": 0.5},
        "orientation": {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0},
    }


def session(server: Server) -> tuple[str, dict[str, str]]:
    r = httpx.post(f"{server.base}/v1/sessions", json={"chain": PANDA}, timeout=TIMEOUT_S)
    assert r.status_code == 201, r.text
    return r.json()["id"], {"Authorization": f"Bearer {r.json()['token']}"}


def ws_connect(server: Server, sid: str, headers: dict[str, str], **kw: Any) -> ClientConnection:
    url = server.base.replace("http", "ws", 1) + f"/v1/sessions/{sid}/ws"
    return connect(url, additional_headers=headers, open_timeout=TIMEOUT_S, **kw)


def no_reconnect_stream(ik: Client, options: SolverOptionsPatch | None = None) -> Stream:
    """A new panda_arm session's stream (ik_client) that raises a close, never mends it."""
    session = ik.create_session(PANDA, options=options)
    return ik.stream(session, reconnect=Reconnect(attempts=0), timeout_s=TIMEOUT_S)


def test_logs_where_the_docs_are(server: Server) -> None:
    assert f"http://127.0.0.1:{server.port}/docs" in server.log()
    assert httpx.get(f"{server.base}/docs", timeout=TIMEOUT_S).status_code == 200
    assert httpx.get(f"{server.base}/healthz", timeout=TIMEOUT_S).json() == {"status": "ok"}


def test_log_lines_carry_the_utc_time_and_the_worker_s_pid(
    start_server: Callable[..., Server],
) -> None:
    """Operators read several workers' logs side by side: each line, uvicorn's access
    log included, starts with its ISO-8601 UTC time and the process id. The server runs
    in a zone 5:30 off UTC: where TZ is unset (UTC, as in CI) local time would pass."""
    server = start_server(TZ="Asia/Kolkata")
    before = datetime.now(UTC) - timedelta(seconds=1)
    assert httpx.get(f"{server.base}/no-such-page", timeout=TIMEOUT_S).status_code == 404
    stamp = re.compile(r"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3})Z \[(\d+)\] (\w+): ")
    deadline = time.monotonic() + 5
    while (access := [ln for ln in server.log().splitlines() if "/no-such-page" in ln]) == []:
        assert time.monotonic() < deadline, "the request was not logged"
        time.sleep(0.05)
    lines = [ln for ln in server.log().splitlines() if ln.strip()]
    (started,) = [ln for ln in lines if "IK service on http://" in ln]  # the service's own
    first = stamp.match(started)
    assert first is not None and first.group(3) == "INFO", started
    logged = stamp.match(access[0])
    assert logged is not None and logged.group(3) == "INFO", access[0]
    assert int(logged.group(2)) == int(first.group(2)) == server.proc.pid
    when = datetime.fromisoformat(logged.group(1)).replace(tzinfo=UTC)
    assert before <= when <= datetime.now(UTC) + timedelta(seconds=1)  # UTC, not local
    assert all(stamp.match(ln) for ln in lines if ' - "' in ln), "an access line without one"
    server.stop()


def test_logs_how_the_solver_got_warm(server: Server) -> None:
    log = server.log()
    loaded = "solver loaded from its on-disk cache" in log  # a warm checkout
    compiled = "compiling it now" in log and "solver compiled and loaded" in log  # a fresh one
    assert loaded != compiled, log
    assert "ready" in httpx.get(f"{server.base}/readyz", timeout=TIMEOUT_S).json()["status"]


def test_ws_json_and_msgpack_frames_in_order(server: Server) -> None:
    sid, headers = session(server)
    with ws_connect(server, sid, headers) as ws:
        # Pipelined: all sent first, answers come back in order.
        for i in range(20):
            ws.send(
                json.dumps({"type": "frame", "id": i, "targets": [tool_target(0.1 + 0.002 * i)]})
            )
        replies = [json.loads(ws.recv(timeout=TIMEOUT_S)) for _ in range(20)]
        assert [r["id"] for r in replies] == list(range(20))
        assert sum(r["success"] for r in replies) >= 19
        for i in range(20, 30):
            ws.send(msgpack.packb({"type": "frame", "id": i, "targets": [tool_target(0.14)]}))
        packed = [ws.recv(timeout=TIMEOUT_S) for _ in range(10)]
    assert all(isinstance(p, bytes) for p in packed)
    assert [msgpack.unpackb(p)["id"] for p in packed] == list(range(20, 30))


def test_ws_recoverable_error_then_next_frame_solves(server: Server) -> None:
    sid, headers = session(server)
    with ws_connect(server, sid, headers) as ws:
        ws.send("{not json")
        err = json.loads(ws.recv(timeout=TIMEOUT_S))
        assert err["success"] is False and err["error"]["code"] == "invalid_format"
        ws.send(json.dumps({"type": "frame", "id": 1, "targets": [tool_target(0.1)]}))
        assert json.loads(ws.recv(timeout=TIMEOUT_S))["result"]["id"] == 1


def test_ws_compression_is_accepted_unless_switched_off(
    server: Server, start_server: Callable[..., Server]
) -> None:
    """websockets offers permessage-deflate, as browsers do: accepted by default, not
    with IK_WS_COMPRESSION=false; frames are answered either way."""
    plain = start_server(IK_WS_COMPRESSION="false")
    for srv, extensions in ((server, ["permessage-deflate"]), (plain, [])):
        sid, headers = session(srv)
        with ws_connect(srv, sid, headers) as ws:
            assert [e.name for e in ws.protocol.extensions] == extensions
            ws.send(json.dumps({"type": "frame", "id": 7, "targets": [tool_target(0.1)]}))
            reply = json.loads(ws.recv(timeout=TIMEOUT_S))
            assert reply["id"] == 7 and reply["result"]["q"]


def test_ws_bad_token_closes_4403(server: Server) -> None:
    sid, _ = session(server)
    with ws_connect(server, sid, {"Authorization": "Bearer wrong"}) as ws:
        with pytest.raises(ConnectionClosed) as info:
            ws.recv(timeout=TIMEOUT_S)
    assert info.value.rcvd is not None and info.value.rcvd.code == 4403


def test_ws_message_over_uvicorns_limit_closes_1009(
    start_server: Callable[..., Server],
) -> None:
    small = start_server(IK_WS_MAX_MESSAGE_BYTES="4096")
    sid, headers = session(small)
    with ws_connect(small, sid, headers, max_size=None) as ws:
        ws.send(json.dumps({"type": "ping", "id": 1, "pad": "x" * 10_000}))
        with pytest.raises(ConnectionClosed) as info:
            ws.recv(timeout=TIMEOUT_S)
    assert info.value.rcvd is not None and info.value.rcvd.code == 1009


def test_sigterm_closes_open_websockets_with_1012(start_server: Callable[..., Server]) -> None:
    doomed = start_server(IK_GRACEFUL_SHUTDOWN_S="2")
    with Client(doomed.base, timeout_s=TIMEOUT_S) as ik, no_reconnect_stream(ik) as stream:
        stream.ping()
        doomed.proc.send_signal(signal.SIGTERM)
        with pytest.raises(ServerRestarting) as info:
            stream.receive()
    assert info.value.close_code == 1012
    # uvicorn shuts down gracefully, then re-raises the signal it caught.
    assert doomed.proc.wait(TIMEOUT_S) in (0, -signal.SIGTERM)
    assert "Finished server process" in doomed.log()


def test_token_is_redacted_from_the_access_log(server: Server) -> None:
    sid, headers = session(server)
    token = headers["Authorization"].removeprefix("Bearer ")
    url = server.base.replace("http", "ws", 1) + f"/v1/sessions/{sid}/ws?token={token}"
    with connect(url, open_timeout=TIMEOUT_S) as ws:
        ws.send(json.dumps({"type": "ping", "id": 1}))
        assert json.loads(ws.recv(timeout=TIMEOUT_S))["type"] == "pong"
    assert token not in server.log()


# Frames to an unreachable target each burn this 50 ms budget (pooled).
_SLOW: SolverOptionsPatch = {"time_budget_us": 50_000, "max_iter": 100_000}


def _refused(server: Server) -> bool:
    """True once a new connection is refused (polled, bounded: at most 5 s)."""
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        try:
            httpx.get(f"{server.base}/healthz", timeout=1.0)
        except httpx.ConnectError:
            return True
        except httpx.HTTPError:
            pass
        time.sleep(0.02)
    return False


def test_sigterm_answers_http_frames_in_flight_and_refuses_new_connections(
    start_server: Callable[..., Server],
) -> None:
    doomed = start_server(IK_GRACEFUL_SHUTDOWN_S="10")
    far: Any = {**tool_target(0.1), "position": {"x": 9.0, "y": 0.0, "z": 0.0}}
    frames: list[Any] = [{"id": i, "targets": [far]} for i in range(20)]  # about 1 s
    result: dict[str, Any] = {}
    with Client(doomed.base, timeout_s=TIMEOUT_S) as ik:
        session = ik.create_session(PANDA, options=_SLOW)

        def post() -> None:
            result["clip"] = ik.clip(session, frames)

        t = threading.Thread(target=post)
        t.start()
        time.sleep(0.3)  # the clip is being solved (a 20 x 50 ms clip)
        doomed.proc.send_signal(signal.SIGTERM)
        assert _refused(doomed)
        t.join(TIMEOUT_S)
    assert [x.id for x in result["clip"].results] == list(range(20))
    assert doomed.proc.wait(TIMEOUT_S) in (0, -signal.SIGTERM)


def test_sigterm_answers_the_ws_frame_in_flight_then_closes_1012(
    start_server: Callable[..., Server],
) -> None:
    doomed = start_server(IK_GRACEFUL_SHUTDOWN_S="10")
    far: Any = {**tool_target(0.1), "position": {"x": 9.0, "y": 0.0, "z": 0.0}}
    with Client(doomed.base, timeout_s=TIMEOUT_S) as ik, no_reconnect_stream(ik, _SLOW) as stream:
        sent = [stream.send_frame([far]) for _ in range(20)]  # pipelined, 50 ms each
        assert stream.receive().id == sent[0]
        doomed.proc.send_signal(signal.SIGTERM)
        answered = []
        with pytest.raises(ServerRestarting) as info:
            while True:
                answered.append(stream.receive())
    assert info.value.close_code == 1012
    # The frame in flight when SIGTERM came was answered (a result, not lost).
    assert answered and all(isinstance(a, FrameAnswer) for a in answered)
    assert [a.id for a in answered] == sent[1 : 1 + len(answered)]
    assert doomed.proc.wait(TIMEOUT_S) in (0, -signal.SIGTERM)


def _ws_frame(payload: bytes) -> bytes:
    """A client text frame (RFC 6455), payload < 65536 bytes, masked with the key 0 (a
    valid key that leaves the payload as it is: no per-byte work for large frames)."""
    mask = b"\x00\x00\x00\x00"
    if len(payload) < 126:
        return bytes([0x81, 0x80 | len(payload)]) + mask + payload
    return bytes([0x81, 0x80 | 126]) + len(payload).to_bytes(2, "big") + mask + payload


def _clip_frame(msg_id: int) -> bytes:
    """A clip of 200 frames: ~28 kB asked, ~145 kB answered (full results), so a few
    dozen unread answers fill any socket buffer the kernel grows for the connection (a
    ping's 25-byte pong needed over 100,000: seconds of a loaded server's time)."""
    frames = [{"targets": [tool_target(0.1)]}] * 200
    return _ws_frame(json.dumps({"type": "clip", "id": msg_id, "frames": frames}).encode())


def _send_until_stalled(sock: socket.socket, stall_s: float, within_s: float) -> int:
    """Pipeline clips on a non-blocking socket until a send has waited ``stall_s`` (the
    server stopped reading: backpressure reached the client); returns how many."""
    sent = 0
    unsent = bytearray()  # the rest of a frame the socket took only part of
    stalled_since: float | None = None
    deadline = time.monotonic() + within_s
    while time.monotonic() < deadline:  # bounded in time and count
        if not unsent:
            sent += 1
            unsent += _clip_frame(sent)
        try:
            # A non-blocking send may take part of a frame; the rest goes first next
            # time, or the server would read the next frame's bytes as this one's.
            del unsent[: sock.send(unsent)]
            stalled_since = None
        except BlockingIOError:
            stalled_since = stalled_since or time.monotonic()
            if time.monotonic() - stalled_since > stall_s:
                return sent
            time.sleep(0.01)
    raise AssertionError(f"never back-pressured after {sent} clips")


def _unreading_socket(srv: Server, sid: str, headers: dict[str, str]) -> socket.socket:
    """A WebSocket opened by hand with a tiny receive buffer, for a client that never
    reads its answers (a library client would read them)."""
    token = headers["Authorization"].removeprefix("Bearer ")
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", srv.port))
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        (
            f"GET /v1/sessions/{sid}/ws?token={token} HTTP/1.1\r\n"
            f"Host: 127.0.0.1:{srv.port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
        ).encode()
    )
    sock.settimeout(TIMEOUT_S)
    head = b""
    while b"\r\n\r\n" not in head:
        head += sock.recv(1)
    assert head.startswith(b"HTTP/1.1 101")
    return sock


def _metric(srv: Server, name: str) -> float:
    """One series of /metrics (the whole series name, labels included), 0 when absent."""
    text = httpx.get(f"{srv.base}/metrics", timeout=TIMEOUT_S).text
    for line in text.splitlines():
        series, _, value = line.rpartition(" ")
        if series == name:  # the whole series: not a longer name it begins
            return float(value)
    return 0.0


def _assert_no_websocket_left(srv: Server, within_s: float, why: str) -> None:
    until = time.monotonic() + within_s
    while _metric(srv, "ik_websockets") != 0.0 and time.monotonic() < until:
        time.sleep(0.1)
    assert _metric(srv, "ik_websockets") == 0.0, f"{why}:\n{srv.log()[-3000:]}"


def _assert_reset_within(srv: Server, sock: socket.socket, within_s: float) -> None:
    """The server let go of the socket: the client, which never read, sees a reset
    (a close would wait for ever for the client to read what is buffered)."""
    until = time.monotonic() + within_s
    error = 0
    while error == 0 and time.monotonic() < until:
        error = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        time.sleep(0.05)
    assert error == errno.ECONNRESET, f"socket error {error}:\n{srv.log()[-3000:]}"


def test_client_that_stops_reading_is_bounded_and_dropped(
    start_server: Callable[..., Server],
) -> None:
    """A raw client with a tiny receive buffer pipelines clips and never reads: the
    server stops reading once its write buffer is full (it answers before it reads),
    then drops the socket after IK_WS_SEND_TIMEOUT_S and lets go of it within uvicorn's
    close_timeout; the session keeps working."""
    srv = start_server(IK_WS_SEND_TIMEOUT_S="1")
    sid, headers = session(srv)
    with _unreading_socket(srv, sid, headers) as sock:  # closed when an assertion fails
        sock.setblocking(False)
        sent = _send_until_stalled(sock, stall_s=2.0, within_s=30.0)
        _assert_no_websocket_left(srv, 15.0, f"not dropped after {sent} clips")
        assert _metric(srv, 'ik_errors_total{code="slow_reader",transport="ws"}') == 1.0
        _assert_reset_within(srv, sock, 10.0)
    r = httpx.post(
        f"{srv.base}/v1/sessions/{sid}/frames",
        json={"id": 1, "targets": [tool_target(0.1)]},
        headers=headers,
        timeout=TIMEOUT_S,
    )
    assert r.status_code == 200 and r.json()["results"][0]["id"] == 1


def test_keepalive_timeout_under_a_full_buffer_ends_the_handler(
    start_server: Callable[..., Server],
) -> None:
    """A client that never reads answers nor pings: uvicorn's keepalive closes the
    connection while the write buffer cannot drain. The socket is let go of within
    uvicorn's close_timeout and the handler ends (it used to wait for IK_WS_SEND_TIMEOUT_S,
    or, waiting for a message, for ever); the session keeps working."""
    # The send time limit (60 s) far beyond what the test waits: only the close counts.
    # The keepalive ping (3 s after the accept) finds the write buffer full already
    # (the clips fill it within about a second).
    srv = start_server(
        IK_WS_PING_INTERVAL_S="3", IK_WS_PING_TIMEOUT_S="1", IK_WS_SEND_TIMEOUT_S="60"
    )
    sid, headers = session(srv)
    with _unreading_socket(srv, sid, headers) as sock:
        sock.setblocking(False)
        _send_until_stalled(sock, stall_s=1.0, within_s=30.0)
        # uvicorn closed at the keepalive timeout; the handler is in a send that cannot
        # finish: the socket is aborted within uvicorn's close_timeout (10 s), which
        # ends the send, the handler and the count.
        _assert_no_websocket_left(srv, 30.0, "the handler outlived the close")
        _assert_reset_within(srv, sock, 5.0)
    r = httpx.post(
        f"{srv.base}/v1/sessions/{sid}/frames",
        json={"id": 1, "targets": [tool_target(0.1)]},
        headers=headers,
        timeout=TIMEOUT_S,
    )
    assert r.status_code == 200 and r.json()["results"][0]["id"] == 1


# continuity "reach": a smooth session keeps its restarts within one step of the last
# answer and gives up far sooner; the tests of _SLOWER need frames that take a while.
_SLOWER: SolverOptionsPatch = {
    "time_budget_us": 50_000,
    "max_iter": 100_000,
    "max_restarts": 10_000,
    "continuity": "reach",
}

# Just out of the panda's reach (6 cm): a frame restarts until its restarts stall, ~12 ms.
_EDGE_OF_REACH = {
    "effector": "tool",
    "position": {"x": 0.9, "y": 0.0, "z": 0.3},
    "orientation": {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0},
}


def test_sigterm_past_the_graceful_time_answers_http_with_json_503(
    start_server: Callable[..., Server],
) -> None:
    """A clip longer than IK_GRACEFUL_SHUTDOWN_S: uvicorn cancels it; the client gets
    JSON it can act on, not uvicorn's plain-text 500."""
    # No grace: cancelled at once. Each frame ends in ~12 ms (its restarts stop at a
    # stall, not at the 50 ms budget): 300 frames are ~3.6 s, well past the SIGTERM at
    # 0.3 s (38 frames were ~0.5 s, and a fast run finished before it).
    doomed = start_server(IK_GRACEFUL_SHUTDOWN_S="0", IK_MAX_REQUEST_WORK_S="20")
    far: Any = _EDGE_OF_REACH
    frames: list[Any] = [{"id": i, "targets": [far]} for i in range(300)]
    result: dict[str, Any] = {}
    with Client(doomed.base, timeout_s=TIMEOUT_S) as ik:
        session = ik.create_session(PANDA, options=_SLOWER)

        def post() -> None:
            with pytest.raises(RetryLater) as refused:
                ik.clip(session, frames)
            result["error"] = refused.value

        t = threading.Thread(target=post)
        t.start()
        time.sleep(0.3)
        doomed.proc.send_signal(signal.SIGTERM)
        t.join(TIMEOUT_S)
    # A JSON body with its code (uvicorn's own would be a plain-text 500: http_500).
    error = result["error"]
    assert (error.status_code, error.code, error.retry_after_s) == (503, "shutting_down", 1.0)
    assert doomed.proc.wait(TIMEOUT_S) in (0, -signal.SIGTERM)


def test_sigterm_past_the_graceful_time_answers_the_ws_message_before_1012(
    start_server: Callable[..., Server],
) -> None:
    doomed = start_server(IK_GRACEFUL_SHUTDOWN_S="1", IK_MAX_REQUEST_WORK_S="20")
    far: Any = _EDGE_OF_REACH
    # ~12 ms a frame (restarts stop at a stall): ~3.6 s, past the SIGTERM and its 1 s grace.
    frames: list[Any] = [{"id": i, "targets": [far]} for i in range(300)]
    with (
        Client(doomed.base, timeout_s=TIMEOUT_S) as ik,
        no_reconnect_stream(ik, _SLOWER) as stream,
    ):
        clip_id = stream.send_clip(frames)
        time.sleep(0.3)
        doomed.proc.send_signal(signal.SIGTERM)
        with pytest.raises(RetryLater) as reply:
            stream.receive()
        with pytest.raises(ServerRestarting) as info:
            stream.receive()
    assert reply.value.id == clip_id and reply.value.code == "shutting_down"
    assert reply.value.retry_after_s == 1.0
    assert info.value.close_code == 1012
    assert doomed.proc.wait(TIMEOUT_S) in (0, -signal.SIGTERM)
