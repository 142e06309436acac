"""One greedy client must not hold the server while another waits (issue 23)."""

from __future__ import annotations

import threading
import time

import msgpack
import pytest
from websockets.frames import Frame, Opcode

from .conftest import Server
from .test_server import TIMEOUT_S, session, ws_connect

pytestmark = pytest.mark.live

GREEDY_FRAMES = 300
# Out of the panda's reach: every frame burns its whole (inline) time budget.
UNREACHABLE = {
    "effector": "tool",
    "position": {"x": 5.0, "y": 0.0, "z": 0.5},
    "orientation": {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0},
}


def test_a_burst_of_frames_on_one_socket_does_not_hold_up_another(server: Server) -> None:
    """A socket writes 300 slow frames in one write (the server reads them in one go);
    a second client's ping, sent once the burst is being solved, is answered before
    most of the burst: the server takes turns between connections, not one read at a
    time. The order is what is asserted; how long the ping took is bench's job."""
    greedy_sid, greedy_headers = session(server)
    polite_sid, polite_headers = session(server)
    burst = b"".join(
        Frame(
            Opcode.BINARY,
            msgpack.packb({"type": "frame", "id": i, "targets": [UNREACHABLE]}),
        ).serialize(mask=True)
        for i in range(GREEDY_FRAMES)
    )
    answered_at: list[float] = []
    with (
        ws_connect(server, greedy_sid, greedy_headers, compression=None) as greedy,
        ws_connect(server, polite_sid, polite_headers) as polite,
    ):

        def read_greedy() -> None:
            for _ in range(GREEDY_FRAMES):
                reply = msgpack.unpackb(greedy.recv(timeout=TIMEOUT_S))
                assert reply["type"] == "result", reply
                answered_at.append(time.monotonic())

        reader = threading.Thread(target=read_greedy)
        reader.start()
        greedy.socket.sendall(burst)  # raw frames: one write, as a hostile client would
        deadline = time.monotonic() + TIMEOUT_S
        while not answered_at and time.monotonic() < deadline:
            time.sleep(0.001)
        polite.send(msgpack.packb({"type": "ping", "id": 1}))
        assert msgpack.unpackb(polite.recv(timeout=TIMEOUT_S))["type"] == "pong"
        pong_at = time.monotonic()
        reader.join(TIMEOUT_S)
    assert len(answered_at) == GREEDY_FRAMES
    after_pong = sum(t > pong_at for t in answered_at)
    assert after_pong > GREEDY_FRAMES // 2, f"only {after_pong} answers came after the pong"
