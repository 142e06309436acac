"""Sessions: one chain, one warm-started solver, one lock; and the store that holds them.

``SessionStore`` is the interface (a shared store, e.g. Redis, comes later: it would
hold the chain definition, options and current pose, and a worker would rebuild the
solver on a miss). ``InMemorySessionStore`` is the default: one process, a dict, idle
expiry and a cap.
"""

from __future__ import annotations

import abc
import asyncio
import hashlib
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from solver.ik import IKOptions, IKSolver

from .convert import ChainView


def token_digest(token: str) -> bytes:
    """Tokens are stored as SHA-256 digests: a dump of the store grants no access."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).digest()


@dataclass(eq=False, slots=True)
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

    def token_ok(self, token: str) -> bool:
        return secrets.compare_digest(token_digest(token), self.token_digest)


def new_session(
    view: ChainView, solver: IKSolver, options: IKOptions, *, now: float
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
    )
    return session, token


class StoreFull(Exception):
    """The store holds ``max_sessions``; retry after ``retry_after_s``."""

    def __init__(self, retry_after_s: float) -> None:
        super().__init__(f"session store full, retry after {retry_after_s:.0f} s")
        self.retry_after_s = retry_after_s


class SessionStore(abc.ABC):
    """Where sessions live. Async so that a networked store fits the same interface."""

    ttl_s: float
    clock: Callable[[], float]

    @abc.abstractmethod
    async def add(self, session: Session) -> None:
        """Store a new session. Raises StoreFull at the cap (after expiring idle ones)."""

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

    def idle_s(self, session: Session) -> float:
        return max(0.0, self.clock() - session.last_seen)

    def touch(self, session: Session) -> None:
        session.last_seen = self.clock()


class InMemorySessionStore(SessionStore):
    """A dict in this process (one worker). ``clock`` is injectable for tests."""

    def __init__(
        self, *, max_sessions: int, ttl_s: float, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.max_sessions = max_sessions
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
        return s

    async def expire(self) -> list[Session]:
        now = self.clock()
        gone = [s for s in self._sessions.values() if self._expired(s, now)]
        for s in gone:
            await self.remove(s.id)
        return gone
