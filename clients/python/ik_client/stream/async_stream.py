"""``AsyncStream``: a session's WebSocket over websockets' asyncio client. While one
task reconnects, what other tasks send waits for the new connection (queued.py).
"""

from __future__ import annotations

import asyncio
import functools
from typing import Any

from websockets.asyncio.client import ClientConnection as AsyncConnection
from websockets.asyncio.client import connect as async_connect
from websockets.exceptions import ConnectionClosed

from ..errors import CloseCode, MessageDropped, stream_closed
from ..queued import SendQueue
from ..types import (
    Answer,
    BatchEntryResult,
    BatchFrame,
    BoneOutput,
    ClipResult,
    FkResult,
    Frame,
    FrameResult,
    Pong,
    PoseIn,
    Target,
)
from . import messages
from .base import BaseStream
from .recovery import ATTEMPT_FAILURES, NotServing, open_failed


class AsyncStream(BaseStream[AsyncConnection]):
    """A session's WebSocket (asyncio). Use as ``async with client.stream(session) as s``.

    ``send_frame`` / ``send_clip`` / ``send_batch`` / ``send_ping`` return the message's
    id; ``receive`` returns the next answer (in the order sent) or raises its
    ``ServiceError`` (an answer it cannot read: ``UnexpectedAnswer``; a message dropped
    unsent while reconnecting: ``MessageDropped``), waiting at most ``timeout_s``
    (``TimeoutError``). While a task reconnects, a send from another task returns at
    once and its message waits for the new connection (``queued``, at most
    ``max_queued``). ``frame``, ``clip``, ``batch`` and ``ping`` send
    one message and wait for its answer. Sends may come from several tasks; answers are read
    by one task at a time.
    """

    @functools.cached_property
    def _lock(self) -> asyncio.Lock:
        """One sender or one reconnect at a time."""
        return asyncio.Lock()

    async def __aenter__(self) -> AsyncStream:
        try:
            self._connection = await self._open()
        except ATTEMPT_FAILURES as exc:
            raise open_failed(self.url, exc) from exc
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    async def close(self) -> None:
        """Close the connection; a reconnect under way in another task stops, and that
        task's call raises ``StreamClosed`` 1000."""
        self._closed = True
        if self._connection is not None:
            await self._connection.close()

    async def send_frame(
        self,
        targets: list[Target],
        *,
        bones: BoneOutput | None = None,
        pose: PoseIn | None = None,
    ) -> int:
        """Send a frame (``pose``: the animated pose it starts from); returns its id."""
        return await self._send(messages.frame(targets, bones, pose))

    async def send_clip(self, frames: list[Frame], *, plan: bool = False) -> int:
        return await self._send(messages.clip(frames, plan))

    async def send_batch(self, frames: list[BatchFrame]) -> int:
        return await self._send(messages.batch(frames))

    async def send_ping(self) -> int:
        return await self._send({"type": "ping"})

    async def send_fk(
        self,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
        bones: BoneOutput | None = None,
    ) -> int:
        return await self._send(messages.fk(q, joints, bones))

    async def receive(self) -> Answer:
        while True:
            if (dropped := self._pipeline.take_dropped()) is not None:
                raise MessageDropped(dropped, self.max_queued)
            connection = self.connection
            try:
                # Cancelling recv() loses nothing (websockets' guarantee).
                data = await asyncio.wait_for(connection.recv(), self.timeout_s)
            except ConnectionClosed as exc:
                await self._recover(connection, exc)
                continue
            try:
                return self._answer(data)
            except NotServing as exc:
                await connection.close()  # what waits is sent again on a new connection
                await self._recover(connection, exc)

    async def frame(
        self,
        targets: list[Target],
        *,
        bones: BoneOutput | None = None,
        pose: PoseIn | None = None,
    ) -> FrameResult:
        await self.send_frame(targets, bones=bones, pose=pose)
        return messages.expect_frame(await self.receive())

    async def clip(self, frames: list[Frame], *, plan: bool = False) -> ClipResult:
        await self.send_clip(frames, plan=plan)
        return messages.expect_clip(await self.receive())

    async def batch(self, frames: list[BatchFrame]) -> list[BatchEntryResult]:
        await self.send_batch(frames)
        return messages.expect_batch(await self.receive())

    async def ping(self) -> Pong:
        await self.send_ping()
        return messages.expect_pong(await self.receive())

    async def fk(
        self,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
        bones: BoneOutput | None = None,
    ) -> FkResult:
        """Forward kinematics of a pose (``q``, ``joints`` by name, or neither: the
        session's current pose): its effectors' world poses (and, on skeleton chains,
        bone data) in the session's conventions; the pose does not change."""
        await self.send_fk(q=q, joints=joints, bones=bones)
        return messages.expect_fk(await self.receive())

    async def _open(self) -> AsyncConnection:
        return await async_connect(self.url, **self._connect_options, **self._take_sock())

    async def _send(self, body: dict[str, Any]) -> int:
        if self._held is not None:  # reconnecting: it goes out on the new connection
            return self._pipeline.hold(body, self._held)
        async with self._lock:
            # Waiting before it is sent: a send that fails is sent again after reconnecting.
            message_id, data = self._pipeline.add(body)
            connection = self.connection
            try:
                await connection.send(data)
                return message_id
            except ConnectionClosed as exc:
                failure = exc
        await self._recover(connection, failure)
        return message_id

    async def _recover(self, failed: AsyncConnection, exc: ConnectionClosed | NotServing) -> None:
        """Reconnect and resend what is waiting, or raise the close as a ``StreamClosed``."""
        if self._closed:  # closed by the caller, whatever the close code says
            raise stream_closed(CloseCode.NORMAL) from exc
        self._note_failure(exc)
        async with self._lock:
            if self._connection is not failed:
                return  # another task has reconnected already
            self._held = SendQueue(self.max_queued)  # what other tasks send meanwhile
            try:
                await self._reconnect()
            finally:
                self._held = None

    async def _reconnect(self) -> None:
        """Connect again (holding the lock) and resend what waits, within the budget."""
        for delay in self._retries.delays():
            await asyncio.sleep(delay)
            self._raise_if_closed()
            try:
                connection = await self._open()
                # What is held goes out now with the rest; a send from here on waits
                # for the lock and goes out after them.
                self._held = None
                for data in self._pipeline.resend():
                    if self._closed:  # close() came during the handshake or a send:
                        break  # nothing more goes out (the server would solve it)
                    await connection.send(data)
            except ATTEMPT_FAILURES as failure:
                if self._held is None:  # they went out on a connection that failed:
                    self._held = SendQueue(self.max_queued)  # kept, and counted no more
                self._retries.attempt_failed(failure)
                continue
            if self._closed:  # close() came while this connection opened: it goes too
                await connection.close()
                self._raise_if_closed()
            self._reconnected(connection)
            return

    def _raise_if_closed(self) -> None:
        """A reconnect stops here once ``close()`` was called (by another task)."""
        if self._closed:
            raise stream_closed(CloseCode.NORMAL)
