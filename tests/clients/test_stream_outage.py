"""The Python stream against a scripted WebSocket server on 127.0.0.1: the error answers
that are part of an outage (``not_ready`` from a restarted worker still warming up, after
a drop; ``shutting_down``) are not the caller's answers: the stream reconnects, no
sooner than their ``retry_after_s``, and sends the message again under its first id.
Outside an outage, or with reconnecting off, the caller gets them as before."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import time
from collections.abc import Callable
from typing import Any

import pytest
from ik_client import AsyncClient, Client, MessageDropped, Pong, Reconnect, RetryLater, StreamClosed
from websockets.asyncio.server import ServerConnection, serve

REF = dataclasses.make_dataclass("Ref", ["id", "token"])("s", "t")
RETRY_AFTER_S = 0.3
QUICK = Reconnect(initial_delay_s=0.01, max_delay_s=0.05, deadline_s=10.0)


def error(message_id: int, code: str) -> str:
    body = {"code": code, "message": code, "retry_after_s": RETRY_AFTER_S}
    return json.dumps({"id": message_id, "type": "result", "success": False, "error": body})


# What a connection does with a message: answer it (a pong), "drop" the connection, or
# answer with an error code.
Script = Callable[[int, int], str]  # (connection number, message id) -> action


class Scripted:
    """A WebSocket server that acts on each message as ``script`` says, and notes every
    (connection, message id, time) it saw and each connection's opening time."""

    def __init__(self, script: Script) -> None:
        self.script = script
        self.seen: list[tuple[int, int]] = []
        self.opened: list[float] = []
        self.answered_at: dict[int, float] = {}

    async def handler(self, ws: ServerConnection) -> None:
        conn = len(self.opened)
        self.opened.append(time.monotonic())
        async for raw in ws:
            message_id = json.loads(raw)["id"]
            self.seen.append((conn, message_id))
            action = self.script(conn, message_id)
            if action == "drop":
                ws.transport.abort()
                return
            if action == "pong":
                await ws.send(json.dumps({"id": message_id, "type": "pong"}))
            else:
                await ws.send(error(message_id, action))
                self.answered_at[conn] = time.monotonic()


async def _pings(server: Scripted, reconnect: Reconnect, n: int) -> tuple[list[Any], int]:
    """``n`` pings one after the other: each answer (or the error raised), reconnects."""
    async with serve(server.handler, "127.0.0.1", 0) as ws_server:
        port = ws_server.sockets[0].getsockname()[1]
        async with (
            AsyncClient(f"http://127.0.0.1:{port}") as ik,
            ik.stream(REF, reconnect=reconnect) as stream,
        ):
            out: list[Any] = []
            for _ in range(n):
                try:
                    out.append(await stream.ping())
                except RetryLater as e:
                    out.append(e)
            return out, stream.reconnects


def run(server: Scripted, reconnect: Reconnect, n: int) -> tuple[list[Any], int]:
    return asyncio.run(asyncio.wait_for(_pings(server, reconnect, n), 30.0))


def test_not_ready_after_a_drop_is_the_restart_warming_up() -> None:
    # Connection 0 answers, then drops; 1 is the restarted worker not ready yet; 2 is ready.
    def script(conn: int, message_id: int) -> str:
        if conn == 0:
            return "pong" if message_id == 0 else "drop"
        return "not_ready" if conn == 1 else "pong"

    server = Scripted(script)
    answers, reconnects = run(server, QUICK, 2)
    assert [type(a) for a in answers] == [Pong, Pong]
    assert reconnects == 2
    # The message went out three times, always under its first id.
    assert server.seen == [(0, 0), (0, 1), (1, 1), (2, 1)]
    # The next connection waited for the answer's retry_after_s.
    assert server.opened[2] - server.answered_at[1] >= RETRY_AFTER_S


def test_shutting_down_is_sent_again_on_a_new_connection() -> None:
    def script(conn: int, message_id: int) -> str:
        return "shutting_down" if (conn, message_id) == (0, 1) else "pong"

    server = Scripted(script)
    answers, reconnects = run(server, QUICK, 3)
    assert [type(a) for a in answers] == [Pong, Pong, Pong]
    assert reconnects == 1
    assert server.seen == [(0, 0), (0, 1), (1, 1), (1, 2)]
    assert server.opened[1] - server.answered_at[0] >= RETRY_AFTER_S


@pytest.mark.parametrize(
    ("code", "reconnect"),
    [
        ("not_ready", QUICK),  # a stream opened on a warming server: no outage of ours
        ("shutting_down", Reconnect.OFF),  # reconnecting off: the caller decides
        ("not_ready", Reconnect.OFF),
    ],
)
def test_otherwise_the_caller_gets_the_error(code: str, reconnect: Reconnect) -> None:
    server = Scripted(lambda conn, message_id: code if message_id == 0 else "pong")
    answers, reconnects = run(server, reconnect, 2)
    assert isinstance(answers[0], RetryLater) and answers[0].code == code
    assert answers[0].retry_after_s == RETRY_AFTER_S
    assert isinstance(answers[1], Pong)
    assert reconnects == 0 and server.seen == [(0, 0), (0, 1)]


def test_a_server_that_stays_not_ready_ends_the_budget_with_its_code() -> None:
    def script(conn: int, message_id: int) -> str:
        if conn == 0:
            return "pong" if message_id == 0 else "drop"
        return "not_ready"

    server = Scripted(script)
    short = Reconnect(initial_delay_s=0.01, max_delay_s=0.05, deadline_s=1.0)
    t0 = time.monotonic()
    with pytest.raises(StreamClosed) as raised:
        run(server, short, 2)
    # Each try waited the answer's retry_after_s; the one that would end past the
    # deadline was not made.
    assert time.monotonic() - t0 < 1.0 + 2.0
    assert raised.value.close_code == 1013 and raised.value.reason == "not_ready"
    assert 3 <= len(server.opened) <= 2 + 1.0 / RETRY_AFTER_S  # the first, the one after the drop


@pytest.mark.parametrize(("status", "retried"), [(403, False), (503, True)])
def test_a_refused_reconnect_is_tried_again_only_if_waiting_can_mend_it(
    status: int, retried: bool
) -> None:
    """After a drop, a proxy in front refuses the upgrade: 503 (no worker up yet) is
    waited out until the server takes the connection again; 403 (a proxy's rule) ends
    the stream at once, not after the reconnect deadline (a review: every refusal was
    tried again for the whole budget)."""
    refusals = {"left": 3}

    def refuse(connection: ServerConnection, request: Any) -> Any:
        if len(server.opened) == 1 and refusals["left"] > 0:
            refusals["left"] -= 1
            return connection.respond(status, "refused\n")
        return None

    server = Scripted(lambda conn, message_id: "drop" if conn == 0 else "pong")

    async def pings() -> tuple[list[Any], float]:
        async with serve(server.handler, "127.0.0.1", 0, process_request=refuse) as ws:
            port = ws.sockets[0].getsockname()[1]
            async with AsyncClient(f"http://127.0.0.1:{port}") as ik:
                started = time.monotonic()
                try:
                    async with ik.stream(REF, reconnect=QUICK) as stream:
                        return [await stream.ping()], time.monotonic() - started
                except StreamClosed as e:
                    return [e], time.monotonic() - started

    (outcome,), took_s = asyncio.run(asyncio.wait_for(pings(), 30.0))
    if retried:
        assert isinstance(outcome, Pong) and refusals["left"] == 0
    else:
        assert isinstance(outcome, StreamClosed) and refusals["left"] == 2
    assert took_s < QUICK.deadline_s / 2


def test_sends_while_reconnecting_wait_at_most_max_queued() -> None:
    """While one task reconnects, another's sends return at once and wait for the new
    connection, at most ``max_queued`` of them: the newest go out, the older are dropped
    unsent (``receive`` raises ``MessageDropped`` in their turn), and the message that
    had gone out before the drop is sent again and answered (the TypeScript client's
    test/queue.test.ts, alike)."""
    down = {"on": False}

    def refuse(connection: ServerConnection, request: Any) -> Any:
        return connection.respond(503, "down\n") if down["on"] else None

    server = Scripted(lambda conn, message_id: "drop" if (conn, message_id) == (0, 1) else "pong")

    async def outage() -> tuple[list[int], int, list[Any], bool]:
        async with serve(server.handler, "127.0.0.1", 0, process_request=refuse) as ws:
            port = ws.sockets[0].getsockname()[1]
            async with (
                AsyncClient(f"http://127.0.0.1:{port}") as ik,
                ik.stream(REF, reconnect=QUICK, max_queued=3) as stream,
            ):
                await stream.ping()
                down["on"] = True
                await stream.send_ping()  # id 1: goes out, and the server drops the connection
                first = asyncio.create_task(stream.receive())  # meets the drop, reconnects
                while not stream.reconnecting:
                    await asyncio.sleep(0.005)
                ids = [await stream.send_ping() for _ in range(5)]
                peak = stream.queued
                down["on"] = False
                outcomes: list[Any] = [await first]
                for _ in ids:
                    try:
                        outcomes.append(await stream.receive())
                    except MessageDropped as e:
                        outcomes.append(e)
                return ids, peak, outcomes, stream.reconnecting

    ids, peak, outcomes, reconnecting = asyncio.run(asyncio.wait_for(outage(), 30.0))
    assert ids == [2, 3, 4, 5, 6] and peak == 3 and not reconnecting
    assert outcomes[0] == Pong(1)
    dropped = [(type(d), d.id, d.max_queued) for d in outcomes[1:3]]
    assert dropped == [(MessageDropped, 2, 3), (MessageDropped, 3, 3)]
    assert outcomes[3:] == [Pong(4), Pong(5), Pong(6)]
    assert [m for conn, m in server.seen if conn == 1] == [1, 4, 5, 6]  # 2, 3 never sent


def _close_mid_reconnect(
    reconnect: Reconnect,
    closing_time: Callable[[Any], bool],
    settle_s: float,
    process_request: Any = None,
) -> tuple[Scripted, Any, int]:
    """A stream whose connection the server drops at message 1; ``close()`` from another
    task once ``closing_time(stream)``; then ``settle_s`` for a reconnect that went on
    to show. Returns the server, what the receiving task got, and the reconnects."""
    server = Scripted(lambda conn, message_id: "drop" if (conn, message_id) == (0, 1) else "pong")

    async def run() -> tuple[Any, int]:
        async with serve(server.handler, "127.0.0.1", 0, process_request=process_request) as ws:
            port = ws.sockets[0].getsockname()[1]
            async with (
                AsyncClient(f"http://127.0.0.1:{port}") as ik,
                ik.stream(REF, reconnect=reconnect) as stream,
            ):
                await stream.ping()
                await stream.send_ping()  # id 1: goes out, and the server drops the connection
                receiving = asyncio.create_task(stream.receive())  # meets the drop, waits
                while not closing_time(stream):
                    await asyncio.sleep(0.005)
                await stream.close()
                (outcome,) = await asyncio.gather(receiving, return_exceptions=True)
                await asyncio.sleep(settle_s)
                return outcome, stream.reconnects

    outcome, reconnects = asyncio.run(asyncio.wait_for(run(), 30.0))
    return server, outcome, reconnects


def test_close_while_reconnecting_abandons_the_reconnect() -> None:
    """``close()`` from another task while the stream waits to reconnect ends the stream:
    the task that was reconnecting gets a ``StreamClosed`` 1000, and no connection is
    opened again (the TypeScript stream's ``close()`` abandons its reconnect alike).
    Before, the reconnect went on after ``close()`` returned: it opened a connection
    that nobody closed, and sent again what had no answer."""
    wait_s = 0.5
    slow = Reconnect(initial_delay_s=wait_s, jitter=0.0, deadline_s=10.0)
    server, outcome, reconnects = _close_mid_reconnect(slow, lambda s: s.reconnecting, wait_s)
    assert isinstance(outcome, StreamClosed) and outcome.close_code == 1000, outcome
    assert reconnects == 0
    assert len(server.opened) == 1
    assert server.seen == [(0, 0), (0, 1)]


def test_close_during_the_reconnects_handshake_sends_nothing_again() -> None:
    """``close()`` while the reconnect's handshake is under way (a worker slow to
    accept): the new connection is closed before anything is sent again on it. Before,
    the messages without an answer went out after ``close()`` had returned, and the
    server solved them (review)."""
    quick = Reconnect(initial_delay_s=0.01, jitter=0.0, deadline_s=10.0)
    handshakes: list[float] = []

    async def slow_second_handshake(connection: Any, request: Any) -> None:
        handshakes.append(time.monotonic())
        if len(handshakes) == 2:
            await asyncio.sleep(0.5)

    # 0.7 s after close(): the slow handshake has ended, and a resend would be seen.
    server, outcome, _ = _close_mid_reconnect(
        quick, lambda _: len(handshakes) >= 2, 0.7, slow_second_handshake
    )
    assert isinstance(outcome, StreamClosed) and outcome.close_code == 1000, outcome
    assert server.seen == [(0, 0), (0, 1)]


@pytest.mark.parametrize("bad", [-1, 1.5, float("nan"), True])
def test_max_queued_is_checked_before_anything_opens(bad: Any) -> None:
    with Client("http://127.0.0.1:9") as ik, pytest.raises(ValueError, match="max_queued"):
        ik.stream(REF, max_queued=bad)
