"""``Stream``: a session's WebSocket over websockets' threading client, blocking, one
thread at a time; it reconnects inside the call that met the drop.
"""

from __future__ import annotations

import time
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection as SyncConnection
from websockets.sync.client import connect as sync_connect

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


class Stream(BaseStream[SyncConnection]):
    """A session's WebSocket (blocking; one thread at a time). Use as
    ``with client.stream(session) as s``; the same calls as ``AsyncStream``.
    ``receive`` waits at most ``timeout_s`` (``TimeoutError``)."""

    def __enter__(self) -> Stream:
        try:
            self._connection = self._open()
        except ATTEMPT_FAILURES as exc:
            raise open_failed(self.url, exc) from exc
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()

    def send_frame(
        self,
        targets: list[Target],
        *,
        bones: BoneOutput | None = None,
        pose: PoseIn | None = None,
    ) -> int:
        """Send a frame (``pose``: the animated pose it starts from); returns its id."""
        return self._send(messages.frame(targets, bones, pose))

    def send_clip(self, frames: list[Frame], *, plan: bool = False) -> int:
        return self._send(messages.clip(frames, plan))

    def send_batch(self, frames: list[BatchFrame]) -> int:
        return self._send(messages.batch(frames))

    def send_ping(self) -> int:
        return self._send({"type": "ping"})

    def send_fk(
        self,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
        bones: BoneOutput | None = None,
    ) -> int:
        return self._send(messages.fk(q, joints, bones))

    def receive(self) -> Answer:
        while True:
            try:
                data = self.connection.recv(timeout=self.timeout_s)
            except ConnectionClosed as exc:
                self._recover(exc)
                continue
            try:
                return self._answer(data)
            except NotServing as exc:
                self.connection.close()  # what waits is sent again on a new connection
                self._recover(exc)

    def frame(
        self,
        targets: list[Target],
        *,
        bones: BoneOutput | None = None,
        pose: PoseIn | None = None,
    ) -> FrameResult:
        self.send_frame(targets, bones=bones, pose=pose)
        return messages.expect_frame(self.receive())

    def clip(self, frames: list[Frame], *, plan: bool = False) -> ClipResult:
        self.send_clip(frames, plan=plan)
        return messages.expect_clip(self.receive())

    def batch(self, frames: list[BatchFrame]) -> list[BatchEntryResult]:
        self.send_batch(frames)
        return messages.expect_batch(self.receive())

    def ping(self) -> Pong:
        self.send_ping()
        return messages.expect_pong(self.receive())

    def fk(
        self,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
        bones: BoneOutput | None = None,
    ) -> FkResult:
        """Forward kinematics of a pose (``q``, ``joints`` by name, or neither: the
        session's current pose): its effectors' world poses (and, on skeleton chains,
        bone data) in the session's conventions; the pose does not change."""
        self.send_fk(q=q, joints=joints, bones=bones)
        return messages.expect_fk(self.receive())

    def _open(self) -> SyncConnection:
        options = {**self._connect_options, **self._take_sock()}
        connection: SyncConnection = sync_connect(self.url, **options)
        # websockets 17.1 warns about a connection not entered as a context manager;
        # this one lives as long as the stream, which closes it (its exit is close()).
        return connection.__enter__()

    def _send(self, body: dict[str, Any]) -> int:
        message_id, data = self._pipeline.add(body)
        try:
            self.connection.send(data)
        except ConnectionClosed as exc:
            self._recover(exc)
        return message_id

    def _recover(self, exc: ConnectionClosed | NotServing) -> None:
        """Reconnect and resend what is waiting, or raise the close as a ``StreamClosed``."""
        self._note_failure(exc)
        for delay in self._retries.delays():
            time.sleep(delay)
            try:
                connection = self._open()
                for data in self._pipeline.resend():
                    connection.send(data)
            except ATTEMPT_FAILURES as failure:
                self._retries.attempt_failed(failure)
                continue
            self._reconnected(connection)
            return
