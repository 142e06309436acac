"""Limits on what a peer controls, against a real server (issue 23): header bytes and
count, the time to send headers and body, connections per address, unread pongs.
Raw sockets on 127.0.0.1, bounded in count and time."""

from __future__ import annotations

import base64
import json
import os
import socket
import time
from collections.abc import Callable, Iterator

import httpx
import pytest
from websockets.frames import Frame, Opcode

from .conftest import Server
from .test_server import TIMEOUT_S, session

pytestmark = pytest.mark.live

HEADER_TIMEOUT_S = 1.0
BODY_TIMEOUT_S = 1.0
MAX_CONNECTIONS = 12
LIMITS = {
    "IK_MAX_HEADER_BYTES": "4096",
    "IK_MAX_HEADERS": "50",
    "IK_HEADER_TIMEOUT_S": str(HEADER_TIMEOUT_S),
    "IK_BODY_TIMEOUT_S": str(BODY_TIMEOUT_S),
    "IK_MAX_CONNECTIONS_PER_ADDRESS": str(MAX_CONNECTIONS),
    "IK_WS_MAX_WRITE_BUFFER_BYTES": "65536",
    # High, so that the unread-pong bound is what drops the ping flood below.
    "IK_WS_MAX_PINGS_PER_S": "1000000",
}
# What "within the configured timeout" allows for a loaded, noisy machine.
SLACK_S = 3.0


@pytest.fixture(scope="module")
def limited(start_server: Callable[..., Server]) -> Server:
    return start_server(**LIMITS)


@pytest.fixture
def connect(limited: Server) -> Iterator[Callable[[], socket.socket]]:
    opened: list[socket.socket] = []

    def open_one() -> socket.socket:
        s = socket.create_connection(("127.0.0.1", limited.port), timeout=TIMEOUT_S)
        opened.append(s)
        return s

    yield open_one
    for s in opened:
        s.close()


def _response(s: socket.socket) -> tuple[int, dict[str, str]]:
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = s.recv(65536)
        assert chunk, f"closed without an answer: {data!r}"
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    status = int(head.split()[1])
    headers = dict(
        line.decode().lower().split(": ", 1) for line in head.split(b"\r\n")[1:] if b": " in line
    )
    while len(body) < int(headers.get("content-length", 0)):
        body += s.recv(65536)
    return status, json.loads(body) if body else {}


def _closed_within(s: socket.socket, seconds: float) -> float:
    """Seconds until the server closed ``s`` (reading and discarding), at most ``seconds``."""
    t = time.monotonic()
    s.settimeout(seconds)
    try:
        while s.recv(65536):
            pass
    except ConnectionResetError:
        pass
    except TimeoutError:
        pytest.fail(f"still open after {seconds} s")
    return time.monotonic() - t


def test_an_oversized_header_gets_431_json(connect: Callable[[], socket.socket]) -> None:
    s = connect()
    s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\nX-Big: " + b"a" * 8192)  # unterminated
    status, body = _response(s)
    assert status == 431 and body["code"] == "payload_too_large"
    assert "IK_MAX_HEADER_BYTES" in body["detail"]


def test_too_many_headers_get_431_json(connect: Callable[[], socket.socket]) -> None:
    s = connect()
    fields = b"".join(b"X-%d: 1\r\n" % i for i in range(80))
    s.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n" + fields + b"\r\n")
    status, body = _response(s)
    assert status == 431 and body["code"] == "payload_too_large"


def test_a_request_with_a_body_sharing_the_read_is_not_counted_as_headers(
    limited: Server,
) -> None:
    r = httpx.post(f"{limited.base}/v1/solve", content=b"x" * 10_000, timeout=TIMEOUT_S)
    assert r.status_code == 422  # read as a body (not JSON), not refused as headers


def test_slowloris_and_idle_sockets_are_closed_within_the_header_timeout(
    connect: Callable[[], socket.socket],
) -> None:
    idle = connect()
    slow = connect()
    slow.sendall(b"GET /healthz HTTP/1.1\r\nHost: x\r\n")
    for _ in range(3):  # a header line now and then, never the blank line
        time.sleep(HEADER_TIMEOUT_S / 4)
        slow.sendall(b"X-Slow: 1\r\n")
    assert _closed_within(slow, HEADER_TIMEOUT_S + SLACK_S) >= 0
    assert _closed_within(idle, HEADER_TIMEOUT_S + SLACK_S) >= 0


def test_a_body_sent_too_slowly_is_dropped(connect: Callable[[], socket.socket]) -> None:
    s = connect()
    s.sendall(b"POST /v1/solve HTTP/1.1\r\nHost: x\r\nContent-Length: 1000\r\n\r\n{")
    assert _closed_within(s, BODY_TIMEOUT_S + SLACK_S) >= 0


def test_connections_per_address_are_capped(
    limited: Server, connect: Callable[[], socket.socket]
) -> None:
    held = [connect() for _ in range(MAX_CONNECTIONS)]
    time.sleep(0.2)  # accepted (the server counts at accept)
    extra = connect()
    assert _closed_within(extra, HEADER_TIMEOUT_S / 2) < HEADER_TIMEOUT_S
    for s in held:
        s.close()
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:  # the count goes down as they close
        try:
            if httpx.get(f"{limited.base}/healthz", timeout=2.0).status_code == 200:
                break
        except httpx.HTTPError:
            time.sleep(0.1)
    else:
        pytest.fail("no new connection accepted after the others closed")


def _upgraded(server: Server, s: socket.socket) -> None:
    """A WebSocket handshake by hand on ``s`` (a client library would read in the
    background; these clients never read)."""
    sid, headers = session(server)
    key = base64.b64encode(os.urandom(16))
    s.sendall(
        b"GET /v1/sessions/%s/ws HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\n"
        b"Connection: Upgrade\r\nSec-WebSocket-Key: %s\r\nSec-WebSocket-Version: 13\r\n"
        b"Authorization: %s\r\n\r\n" % (sid.encode(), key, headers["Authorization"].encode())
    )
    status, _ = _response(s)
    assert status == 101


def test_a_client_that_pings_and_never_reads_is_dropped(
    limited: Server, connect: Callable[[], socket.socket]
) -> None:
    s = connect()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    _upgraded(limited, s)
    ping = Frame(Opcode.PING, b"p" * 125).serialize(mask=True)
    batch = ping * 1000  # 131 kB of pings: 127 kB of pongs the client never reads
    sent = 0
    with pytest.raises(OSError):  # reset or broken pipe once the server dropped it
        for _ in range(400):  # at most 52 MB
            s.sendall(batch)
            sent += len(batch)
    assert sent < 40_000_000, f"{sent} bytes of pings before the drop"


def test_a_client_that_pings_too_often_is_dropped(start_server: Callable[..., Server]) -> None:
    server = start_server(IK_WS_MAX_PINGS_PER_S="20")
    s = socket.create_connection(("127.0.0.1", server.port), timeout=TIMEOUT_S)
    with s:
        _upgraded(server, s)
        s.sendall(Frame(Opcode.PING, b"p").serialize(mask=True) * 21)
        assert _closed_within(s, TIMEOUT_S) < TIMEOUT_S
