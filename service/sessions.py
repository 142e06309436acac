"""Sessions: one chain, one warm-started solver, one lock; and the store that holds them.

``SessionStore`` is the interface. ``InMemorySessionStore`` is the default: one
process, a dict, idle expiry and a cap. ``service.redis_store.RedisSessionStore``
(IK_REDIS_URL) shares sessions between workers: it holds the chain definition, options,
token digest, owner, counters and pose, and a worker rebuilds the solver on a miss; its
extra steps (a frame's commit, a retried frame's stored answer) are no-ops here.
"""

from __future__ import annotations

import abc
import asyncio
import hashlib
import math
import secrets
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

import schemas as S
from solver.ik import IKOptions, IKSolver, StreamState

from .convert import ChainView, FrameJob, SolvedFrame
from .errors import not_found, store_unavailable
from .stored_frames import StoredAnswer

# Times a change is made again when another worker committed the session first (a
# shared store): the session is reloaded each time, so more than one retry means the
# session is being fought over by several streams at once.
STALE_RETRIES = 3
_tuple_new = tuple.__new__


def token_digest(token: str) -> bytes:
    """Tokens are stored as SHA-256 digests: a dump of the store grants no access."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).digest()


class StreamMark(NamedTuple):
    """Where a session's stream stood before frames were solved: what ``Session.rewind``
    puts back."""

    stream: StreamState
    frames: int
    solved: int
    rest: np.ndarray | None  # Session.rest (a frame's animated pose changes it)


# weakref_slot: a shared store finds a session it forgot while something still holds it.
@dataclass(eq=False, slots=True, weakref_slot=True)
class Session:
    """A stream of frames for one chain.

    Attributes:
        id: Public id (URL-safe, 128 random bits).
        token_digest: SHA-256 of the access token.
        view: The chain and its lookups.
        solver: The warm-started solver; its ``q`` is the session's current pose.
        options: Effective solver options.
        created_at: Unix time of creation [s].
        last_seen: Monotonic time of the last use [s].
        lock: Serialises frames (and pose / option changes) in arrival order.
        frames, solved: Counters.
        websockets: Open WebSocket connections (a session with one never expires).
        closed: Set when deleted or expired; waiting frames then answer not_found.
        owner: Fingerprint of the API key that created it (None when keys are off).
        bucket, bucket_at: Frame-rate token bucket (frames available, when counted).
        rest: The rest pose set with the pose (None: the middle of the limits).
        version: Commits of this session in a shared store (its optimistic lock).
        definition_key: Content hash of its chain definition in a shared store.
        answers: The last answers committed, by frame id (a shared store's replay).
        definition: The create request's chain, conventions and bones (JSON), from which
            another worker rebuilds the model; a shared store keeps it (empty after).
    """

    id: str
    token_digest: bytes
    view: ChainView
    solver: IKSolver
    options: IKOptions
    created_at: float
    last_seen: float
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    frames: int = 0
    solved: int = 0
    websockets: int = 0
    closed: bool = False
    owner: str | None = None
    bucket: float = math.inf
    bucket_at: float = 0.0
    rest: np.ndarray | None = None
    version: int = 0
    definition_key: str = ""
    answers: dict[int, StoredAnswer] = field(default_factory=dict)
    definition: bytes = b""

    def set_pose(self, q: np.ndarray) -> None:
        """Set the pose and the rest pose (``IKSolver.set_pose``), remembering the rest
        pose so that a shared store can rebuild the solver as it is."""
        self.solver.set_pose(q)
        self.rest = self.solver.q.copy()

    def start_at(self, pose: np.ndarray) -> None:
        """Set a frame's animated pose (``convert.frame_pose``) before its solve, as
        ``set_pose`` does: a NaN (a DOF the frame's ``joints`` left out) keeps the
        current value."""
        q = self.solver.q
        self.set_pose(np.where(np.isnan(pose), q, pose))

    def put_rest(self, rest: np.ndarray | None) -> None:
        """Put back a rest pose (None: the middle of the limits, the solver's default)
        without changing where the stream stands."""
        stream = self.solver.stream_state()
        self.set_pose(self.view.chain.mid_limits() if rest is None else rest)
        self.solver.restore(stream)
        self.rest = rest

    def mark(self) -> StreamMark:
        """Where the stream stands now (pose, carried BFGS matrix, counters, rest pose)."""
        # tuple.__new__: the NamedTuple's own __new__ is Python code (a batch marks
        # each of its sessions).
        return _tuple_new(
            StreamMark, (self.solver.stream_state(), self.frames, self.solved, self.rest)
        )

    def rewind(self, mark: StreamMark) -> None:
        """Undo the frames solved since ``mark`` (answered to nobody: their request was
        cancelled while a thread solved them, as uvicorn cancels what still runs at the
        end of a graceful shutdown), so that they leave no trace: a resend starts where
        they did, and a shared store's copy is the state it committed. A frame that
        carried an animated pose changed the rest pose too: it is put back."""
        if self.rest is not mark.rest:
            self.put_rest(mark.rest)
        self.solver.restore(mark.stream)
        self.frames, self.solved = mark.frames, mark.solved

    def take_frames(self, n: int, *, now: float, rate_per_s: float, burst: float) -> float:
        """Spend ``n`` frames from the session's token bucket.

        Returns 0.0 when allowed, else the seconds until ``n`` frames are available
        (nothing is spent then). ``rate_per_s`` 0 means unlimited.
        """
        if rate_per_s <= 0:
            return 0.0
        level = min(burst, self.bucket + (now - self.bucket_at) * rate_per_s)
        self.bucket_at = now
        if level >= n:
            self.bucket = level - n
            return 0.0
        self.bucket = level
        return (n - level) / rate_per_s

    def give_back_frames(self, n: int) -> None:
        """Return ``n`` frames taken by ``take_frames`` for frames then refused before
        being solved (a refused request costs nothing of the rate limit)."""
        self.bucket += n  # capped at the burst by the next ``take_frames``

    def token_ok(self, token: str) -> bool:
        return secrets.compare_digest(token_digest(token), self.token_digest)


def chain_definition(body: S.SessionCreate) -> bytes:
    """What another worker needs to build a session's model: the create request's chain,
    conventions and bones, as JSON (a shared store keeps it once per distinct value)."""
    return body.model_dump_json(
        include={"chain", "conventions", "bones"}, exclude_none=True
    ).encode()


def new_session(
    view: ChainView, solver: IKSolver, options: IKOptions, *, now: float, owner: str | None = None
) -> tuple[Session, str]:
    """A session with fresh id and token (from ``secrets``); returns (session, token)."""
    token = secrets.token_urlsafe(32)
    session = Session(
        id=secrets.token_urlsafe(16),
        token_digest=token_digest(token),
        view=view,
        solver=solver,
        options=options,
        created_at=time.time(),
        last_seen=now,
        owner=owner,
        bucket_at=now,
    )
    return session, token


class StoreFull(Exception):
    """The store holds ``max_sessions``; retry after ``retry_after_s``."""

    def __init__(self, retry_after_s: float) -> None:
        super().__init__(f"session store full, retry after {retry_after_s:.0f} s")
        self.retry_after_s = retry_after_s


class OwnerFull(Exception):
    """The API key already holds its maximum of sessions."""

    def __init__(self, limit: int) -> None:
        super().__init__(f"this API key holds its maximum of {limit} sessions")
        self.limit = limit


class StaleSession(Exception):
    """Another worker committed frames of this session first; the session has been
    reloaded from the store, and the frames are to be solved again from there."""


class SessionStore(abc.ABC):
    """Where sessions live. Async so that a networked store fits the same interface."""

    ttl_s: float
    clock: Callable[[], float]
    # True when frames are committed to a store other workers share (``commit``,
    # ``stored_answer`` do something): the frame path skips both steps otherwise.
    commits_frames: bool = False

    @abc.abstractmethod
    async def add(self, session: Session) -> None:
        """Store a new session. Raises StoreFull at the cap (after expiring idle ones),
        OwnerFull when its owner (API key) holds ``max_per_owner`` sessions."""

    @abc.abstractmethod
    async def get(self, session_id: str) -> Session | None:
        """The live session with this id (an expired one is removed and not returned)."""

    @abc.abstractmethod
    async def remove(self, session_id: str) -> Session | None:
        """Delete a session; returns it (marked closed) or None."""

    @abc.abstractmethod
    async def expire(self) -> list[Session]:
        """Remove sessions idle longer than ``ttl_s`` without an open WebSocket."""

    @abc.abstractmethod
    def __len__(self) -> int: ...

    # -- a shared store's steps; nothing to do when sessions live in this process -------
    def stored_answer(self, session: Session, jobs: Sequence[FrameJob]) -> list[SolvedFrame] | None:
        """The answers already given to exactly these frames (same ids, same targets),
        or None: the frames are to be solved. Called under the session's lock."""
        return None

    async def commit(
        self, session: Session, jobs: Sequence[FrameJob], out: list[SolvedFrame]
    ) -> None:
        """Make the frames just solved durable before they are answered. Called under the
        session's lock.

        Raises:
            StaleSession: another worker committed first (the session is reloaded).
            ServiceError: ``not_found`` (deleted elsewhere), ``store_unavailable``.
        """
        return None

    async def save(self, session: Session) -> None:
        """Write a changed pose or options through (PUT pose, PATCH options)."""
        return None

    async def refresh(self, session: Session) -> None:
        """Reload what other workers may have changed (before a pose or options change)."""
        return None

    async def latest(self, session: Session) -> None:
        """Reload what other workers changed before the session's state is read (GET
        of the session, FK of its current pose): behind a balancer another worker may
        have answered its latest frames. Under the session's lock, so that a frame of
        this worker's is not half applied; nothing to do (and no wait for the lock) for
        sessions in this process's memory.

        Raises:
            ServiceError: ``not_found`` (deleted), ``store_unavailable``.
        """
        if not self.commits_frames:
            return
        async with session.lock:
            if session.closed:
                raise not_found()
            await self.refresh(session)

    async def change(self, session: Session, apply: Callable[[], None]) -> None:
        """Reload ``session``, ``apply`` a pose or options change to it and write it
        through; under the session's lock. When another worker committed in between
        (``StaleSession``) the change is applied again to the reloaded session, up to
        ``STALE_RETRIES`` times, then 503 ``store_unavailable`` (never a lost change)."""
        for _ in range(STALE_RETRIES):
            await self.refresh(session)
            apply()
            try:
                await self.save(session)
            except StaleSession:
                continue
            return
        raise store_unavailable()

    async def check(self) -> None:
        """Raises ServiceError ``store_unavailable`` when the store does not answer."""
        return None

    async def close(self) -> None:
        """Release connections (the app's shutdown)."""
        return None

    def idle_s(self, session: Session) -> float:
        return max(0.0, self.clock() - session.last_seen)

    def touch(self, session: Session) -> None:
        session.last_seen = self.clock()


class InMemorySessionStore(SessionStore):
    """A dict in this process (one worker). ``clock`` is injectable for tests."""

    def __init__(
        self,
        *,
        max_sessions: int,
        ttl_s: float,
        clock: Callable[[], float] = time.monotonic,
        max_per_owner: int | None = None,
    ) -> None:
        self.max_sessions = max_sessions
        self.max_per_owner = max_per_owner
        self._owned: dict[str, int] = {}
        self.ttl_s = ttl_s
        self.clock = clock
        self._sessions: dict[str, Session] = {}

    def __len__(self) -> int:
        return len(self._sessions)

    def _expired(self, s: Session, now: float) -> bool:
        return s.websockets == 0 and now - s.last_seen > self.ttl_s

    async def add(self, session: Session) -> None:
        if len(self._sessions) >= self.max_sessions:
            await self.expire()
        if len(self._sessions) >= self.max_sessions:
            now = self.clock()
            idle = [now - s.last_seen for s in self._sessions.values() if s.websockets == 0]
            # The most idle session expires first; with none expirable, try again in a ttl.
            retry = self.ttl_s - max(idle) if idle else self.ttl_s
            raise StoreFull(max(1.0, retry))
        owner = session.owner
        if owner is not None and self.max_per_owner is not None:
            if self._owned.get(owner, 0) >= self.max_per_owner:
                await self.expire()
            if self._owned.get(owner, 0) >= self.max_per_owner:
                raise OwnerFull(self.max_per_owner)
            self._owned[owner] = self._owned.get(owner, 0) + 1
        self._sessions[session.id] = session

    async def get(self, session_id: str) -> Session | None:
        s = self._sessions.get(session_id)
        if s is not None and self._expired(s, self.clock()):
            await self.remove(session_id)
            return None
        return s

    async def remove(self, session_id: str) -> Session | None:
        s = self._sessions.pop(session_id, None)
        if s is not None:
            s.closed = True
            if s.owner is not None and s.owner in self._owned:
                self._owned[s.owner] -= 1
                if self._owned[s.owner] <= 0:
                    del self._owned[s.owner]
        return s

    async def expire(self) -> list[Session]:
        now = self.clock()
        gone = [s for s in self._sessions.values() if self._expired(s, now)]
        for s in gone:
            await self.remove(s.id)
        return gone
