"""Written behind (IK_REDIS_WRITE_BEHIND_MS > 0): the frames this worker answered that
are not in Redis yet, and the task that writes them every interval.

What waits for the flush is a snapshot of each session taken when its frame was
committed, under the session's lock (``Pending``), never the session as it is when the
flush runs: the flush runs on the event loop while the next frame of the same session
may be solving on a frame thread, and reading the session then could store a pose
torn between two frames, or a pose newer than the counters stored with it. One write
per session per flush: its last snapshot, with every answer given since the last one.

``service.redis_store`` does the writing (``Writer``); this module keeps the queue, the
interval, the flush under way (``refresh`` waits for it) and the last flush's failure.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from .sessions import Session
from .stored_frames import KEPT_ANSWERS, StreamRecord


@dataclass(slots=True)
class Pending:
    """A session's frames answered and not yet written: its state after the last of
    them (a snapshot) and their answers, as flat (frame id, packed answer) pairs."""

    session: Session
    record: StreamRecord
    pairs: list[Any]


# Writes one flush's sessions (in one pipeline); handles a failure itself.
Writer = Callable[[list[Pending]], Awaitable[None]]


class WriteBehind:
    """The sessions waiting for the next flush, and the flush task (started by the
    first frame queued, ended when nothing waits)."""

    def __init__(self, interval_s: float, write: Writer) -> None:
        self.interval_s = interval_s
        self._write = write
        self._dirty: dict[str, Pending] = {}
        self._task: asyncio.Task[None] | None = None
        self._closing = asyncio.Event()  # close() ends the wait between flushes
        # The sessions of the flush under way, and its end (``settled`` waits for it).
        self._in_flight: tuple[set[str], asyncio.Event] | None = None
        # The last flush could not reach Redis: frames are refused until a reload works.
        self.failed = False

    def queue(self, session: Session, record: StreamRecord, pairs: list[Any]) -> None:
        """Queue ``record`` (taken under the session's lock) and these answers."""
        pending = self._dirty.get(session.id)
        if pending is None:
            self._dirty[session.id] = Pending(session, record, list(pairs))
        else:
            pending.record = record
            pending.pairs.extend(pairs)  # per frame: appended, compacted once per write
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run())

    def take(self, session_id: str) -> Pending | None:
        """Remove and return what waits for the session (it is written another way now,
        or is void)."""
        pending = self._dirty.pop(session_id, None)
        if pending is not None:
            pending.pairs = _newest_answers(pending.pairs)
        return pending

    async def settled(self, session_id: str) -> None:
        """Wait for the flush under way if it writes this session."""
        in_flight = self._in_flight
        if in_flight is not None and session_id in in_flight[0]:
            await in_flight[1].wait()

    async def _run(self) -> None:
        try:
            while self._dirty and not self._closing.is_set():
                # The interval, cut short by close(): a flush itself is never cancelled.
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._closing.wait(), self.interval_s)
                await self.flush()
        finally:
            self._task = None

    async def flush(self) -> None:
        """Write every session waiting now, in one pipeline."""
        dirty, self._dirty = self._dirty, {}
        batch = [p for p in dirty.values() if not p.session.closed]
        if not batch:
            return
        for pending in batch:
            pending.pairs = _newest_answers(pending.pairs)
        done = asyncio.Event()
        self._in_flight = ({p.session.id for p in batch}, done)
        try:
            await self._write(batch)
        finally:
            self._in_flight = None
            done.set()

    async def close(self) -> None:
        """End the wait for the next flush, let a flush under way finish (its frames are
        in no other place), then write what is left."""
        self._closing.set()
        task = self._task
        if task is not None:
            await task
        if self._dirty:
            await self.flush()


def _newest_answers(pairs: list[Any]) -> list[Any]:
    """The last ``KEPT_ANSWERS`` distinct frame ids of flat (id, answer) pairs, each
    with its newest answer, oldest first: what Redis would keep of them anyway, so a
    long interval (or no frame-rate limit) does not grow one flush's script."""
    newest: dict[Any, Any] = {}
    for key, answer in zip(pairs[::2], pairs[1::2], strict=True):
        newest.pop(key, None)
        newest[key] = answer
    kept = list(newest.items())[-KEPT_ANSWERS:]
    return [x for pair in kept for x in pair]
