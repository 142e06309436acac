"""Sessions in Redis (IK_REDIS_URL), shared by every worker behind the balancer.

What is where (prefix ``ik:``; every key of a session expires after IK_SESSION_TTL_S
without use, and each commit renews it):

- ``chain:<sha256>``: a chain definition (the create request's chain, conventions and
  bones, JSON), stored once per distinct definition. Each process keeps the models it
  built by that hash (``ChainView``), so a second session of a known chain costs no
  build, and a worker that meets a session it does not hold builds its model once.
- ``s:<id>``: a hash: ``meta`` (token digest, owner, chain hash, options, created at),
  ``state`` (pose, carried BFGS matrix, rest pose, counters) and ``v``, the session's
  version: the number of commits.
- ``a:<id>`` / ``o:<id>``: the last ``KEPT_ANSWERS`` answers by frame id, and their order.
- ``all`` and ``owner:<fingerprint>``: sorted sets of session ids by expiry time (the
  session cap and the per-key cap).

Written per frame, before the answer is sent: the state, the version and the answer, in
one Lua script. The frames of every session that commit while one round trip is under
way go together in the next pipeline (a group commit), so the round trip is shared and
its cost per frame falls as load grows; nothing is ever answered before it is stored.
The guarantee: an answered frame survives the death of its worker. Another worker
continues from its pose, and a frame sent again under the same id with the same targets
gets the stored answer instead of a second solve.

Ordering across workers: a worker that holds a session solves from its copy and commits
with the version it started from; if another worker committed in between, the script
refuses, the session is reloaded and the frame solved again (``StaleSession``). Within
one worker a session is one object, whose lock orders its frames: one forgotten as idle
while something holds it (a WebSocket's batches) is taken back, never loaded twice.

Redis not answering: every call gives up after IK_REDIS_TIMEOUT_S (503
``store_unavailable`` with Retry-After); the first call after Redis is back works.
"""

from __future__ import annotations

import asyncio
import functools
import hashlib
import logging
import time
import weakref
from collections import OrderedDict
from collections.abc import Awaitable, Callable, Sequence
from typing import Any

import msgpack
import redis.asyncio as aioredis
from redis.exceptions import RedisError

from solver.ik import IKOptions, IKSolver, StreamState

from . import redis_commit
from .convert import ChainView, FrameJob, SolvedFrame
from .errors import ServiceError, not_found, store_unavailable
from .redis_commit import COMMIT_SCRIPT, GONE, MOVED, OWNER_FULL, SESSIONS_FULL, GroupCommit
from .redis_reads import ChangedReader, read_session
from .sessions import OwnerFull, Session, SessionStore, StaleSession, StoreFull
from .stored_frames import (
    KEPT_ANSWERS,
    StoredAnswer,
    StreamRecord,
    answer_key,
    jobs_digest,
    pack_answer,
    pack_stream,
    unpack_answer,
    unpack_stream,
)
from .write_behind import Pending, WriteBehind

log = logging.getLogger("service")

ViewBuilder = Callable[[bytes], Awaitable[ChainView]]  # a chain's model from its definition
# Options <-> their stored JSON-ready dict; a solver for a model and options.
OptionsLoader = Callable[[dict[str, Any]], IKOptions]
OptionsDumper = Callable[[IKOptions], dict[str, Any]]
SolverBuilder = Callable[[ChainView, IKOptions], Awaitable[IKSolver]]

CACHED_VIEWS = 64  # models kept per process, by chain definition hash
# Session.version of a session this worker must reload before its next frame: a write
# failed (Redis gone) or was refused (another worker wrote first, written behind).
RELOAD = -1


def definition_key(definition: bytes) -> str:
    return hashlib.sha256(definition).hexdigest()


class RedisSessionStore(SessionStore):
    """Sessions in Redis; this process keeps the ones it has served (and their solvers)."""

    commits_frames = True

    def __init__(
        self,
        client: aioredis.Redis,
        *,
        max_sessions: int,
        ttl_s: float,
        build_view: ViewBuilder,
        build_solver: SolverBuilder,
        load_options: OptionsLoader,
        dump_options: OptionsDumper,
        max_per_owner: int | None = None,
        write_behind_s: float = 0.0,
        observe_commit: Callable[[float], None] | None = None,
        prefix: str = "ik:",
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.client = client
        self.max_sessions = max_sessions
        self.max_per_owner = max_per_owner
        self.ttl_s = ttl_s
        self.clock = clock
        self._p = prefix
        self._build_view = build_view
        self._build_solver = build_solver
        self._load_options = load_options
        self._dump_options = dump_options
        self._sessions: dict[str, Session] = {}
        self._loading: dict[str, asyncio.Task[Session | None]] = {}
        # Sessions forgotten as idle that something still holds (a WebSocket remembers
        # the sessions its batches opened): a load takes the same object back.
        self._forgotten = weakref.WeakValueDictionary[str, Session]()
        self._views: OrderedDict[str, ChainView] = OrderedDict()
        self._failures = redis_commit.FailureLog()  # the requests' WARNING, throttled
        self._commit = GroupCommit(client, COMMIT_SCRIPT, self._failures, observe_commit)
        # Written behind (IK_REDIS_WRITE_BEHIND_MS > 0): None when written through.
        self.behind = WriteBehind(write_behind_s, self._write_behind) if write_behind_s else None
        self._count = 0
        self._probe = redis_commit.ReadinessProbe(client)
        self._changed = ChangedReader(client, prefix)

    def __len__(self) -> int:
        """Sessions in Redis (every worker's) at this worker's last sweep, give or take
        the sessions it created or deleted since: up to IK_SWEEP_INTERVAL_S old."""
        return self._count

    # -- keys ------------------------------------------------------------------------
    def _keys(self, session_id: str, chain: str, owner: str | None) -> list[str]:
        p = self._p
        all_key = p + "all"
        return [
            f"{p}s:{session_id}",
            f"{p}a:{session_id}",
            f"{p}o:{session_id}",
            f"{p}chain:{chain}",
            all_key,
            all_key if owner is None else f"{p}owner:{owner}",
        ]

    def _ttl_ms(self) -> int:
        return max(1, int(self.ttl_s * 1000))

    def _meta(self, session: Session) -> bytes:
        return bytes(
            msgpack.packb(
                [
                    session.token_digest,
                    session.owner,
                    session.definition_key,
                    self._dump_options(session.options),
                    session.created_at,
                ]
            )
        )

    @staticmethod
    def _record(session: Session) -> StreamRecord:
        """The session's stream state now, copied (call it under the session's lock)."""
        q, h, anchored, misses = session.solver.stream_state()
        h = None if h is None else h.copy()
        frames, solved = session.frames, session.solved
        return StreamRecord(q.copy(), h, session.rest, frames, solved, anchored, misses)

    # -- the interface ---------------------------------------------------------------
    async def add(self, session: Session) -> None:
        definition = session.definition
        key = definition_key(definition)
        session.definition_key = key
        keys = self._keys(session.id, key, session.owner)
        no_cap = 2**62
        owner_cap = no_cap if self.max_per_owner is None else self.max_per_owner
        state = pack_stream(self._record(session))
        args: list[bytes | str | int] = ["new", state, self._ttl_ms()]
        args += [KEPT_ANSWERS, session.id, self._meta(session), self.max_sessions, owner_cap]
        try:
            await self.client.set(keys[3], definition, px=self._ttl_ms())
            v = await self._commit.run(keys, args)
        except RedisError as e:
            raise self._unavailable(e) from None
        if v == SESSIONS_FULL:
            raise StoreFull(retry_after_s=self.ttl_s)
        if v == OWNER_FULL:
            raise OwnerFull(self.max_per_owner or 0)
        session.version = int(v)
        session.definition = b""
        self._sessions[session.id] = session
        self._count += 1
        self._views[key] = session.view

    async def get(self, session_id: str) -> Session | None:
        held = self._sessions.get(session_id)
        if held is not None:
            return held
        loading = self._loading.get(session_id)
        if loading is None:
            # A task of its own, which every request of the session waits for: a request
            # that goes away (its client disconnected) ends its own wait, never the load.
            loading = asyncio.get_running_loop().create_task(self._load(session_id))
            self._loading[session_id] = loading
            loading.add_done_callback(functools.partial(self._loaded, session_id))
        return await asyncio.shield(loading)

    def _loaded(self, session_id: str, task: asyncio.Task[Session | None]) -> None:
        if self._loading.get(session_id) is task:  # a later load may have taken its place
            self._loading.pop(session_id)
        if not task.cancelled():
            task.exception()  # retrieved: the waiters get it; with none left, nobody need

    async def _load(self, session_id: str) -> Session | None:
        forgotten = self._forgotten.get(session_id)
        if forgotten is not None and not forgotten.closed:
            return await self._take_back(forgotten)
        try:
            stored, answers = await read_session(self.client, self._p, session_id)
            if not stored:
                return None
            token, owner, chain, options, created_at = msgpack.unpackb(stored[b"meta"])
            view = self._views.get(chain)
            definition: bytes | None = None
            if view is None:
                found = await self.client.get(f"{self._p}chain:{chain}")
                definition = found if isinstance(found, bytes) else None
                if definition is None:
                    return None
        except RedisError as e:
            raise self._unavailable(e) from None
        if view is None:
            assert definition is not None
            view = await self._build_view(definition)
            self._remember_view(chain, view)
        opts = self._load_options(options)
        solver = await self._build_solver(view, opts)
        now = self.clock()
        session = Session(
            id=session_id,
            token_digest=token,
            view=view,
            solver=solver,
            options=opts,
            created_at=created_at,
            last_seen=now,
            owner=owner,
            bucket_at=now,
            definition_key=chain,
        )
        self._restore(session, stored, answers)
        held = self._sessions.setdefault(session_id, session)
        log.info("session %s loaded from Redis at version %d", session_id[:6], held.version)
        return held

    async def _take_back(self, session: Session) -> Session | None:
        """A session this worker forgot as idle while something still holds it: that
        object again, brought up to date under its lock, never a second copy beside it
        (two copies would solve from two poses and flush over each other's frames)."""
        async with session.lock:
            try:
                await self.refresh(session)
            except ServiceError:
                if session.closed:  # gone from Redis
                    return None
                raise
        session.last_seen = self.clock()
        return self._sessions.setdefault(session.id, session)

    def _remember_view(self, key: str, view: ChainView) -> None:
        self._views[key] = view
        self._views.move_to_end(key)
        while len(self._views) > CACHED_VIEWS:
            self._views.popitem(last=False)

    def _restore(
        self, session: Session, stored: dict[bytes, bytes], answers: dict[bytes, bytes]
    ) -> None:
        record = unpack_stream(stored[b"state"], session.view.chain.n_dof)
        session.put_rest(record.rest)  # None: the middle of the limits
        state = StreamState(record.q, record.inverse_hessian, record.anchored, record.misses)
        session.solver.restore(state)
        session.frames, session.solved = record.frames, record.solved
        session.version = int(stored[b"v"])
        followers = session.view.chain.followers
        session.answers = {int(k): unpack_answer(v, followers) for k, v in answers.items()}

    async def remove(self, session_id: str) -> Session | None:
        session = self._sessions.pop(session_id, None)
        p = self._p
        try:
            owner = session.owner if session is not None else None
            async with self.client.pipeline(transaction=False) as pipe:
                pipe.delete(f"{p}s:{session_id}", f"{p}a:{session_id}", f"{p}o:{session_id}")
                pipe.zrem(f"{p}all", session_id)
                if owner is not None:
                    pipe.zrem(f"{p}owner:{owner}", session_id)
                await pipe.execute()
        except RedisError as e:
            raise self._unavailable(e) from None
        if session is not None:
            session.closed = True
            self._count = max(0, self._count - 1)
        return session

    async def expire(self) -> list[Session]:
        """Forget the sessions this worker has not used for a ttl (Redis keeps them while
        any worker uses them and expires them itself); keep the ones with an open
        WebSocket alive in Redis; count the sessions there."""
        now = self.clock()
        idle = [
            s
            for s in self._sessions.values()
            if s.websockets == 0 and now - s.last_seen > self.ttl_s
        ]
        for s in idle:
            del self._sessions[s.id]
            self._forgotten[s.id] = s
        streaming = [s for s in self._sessions.values() if s.websockets > 0]
        p, ttl = self._p, self._ttl_ms()
        try:
            async with self.client.pipeline(transaction=False) as pipe:
                for s in streaming:
                    for key in (f"{p}s:{s.id}", f"{p}a:{s.id}", f"{p}o:{s.id}"):
                        pipe.pexpire(key, ttl)
                    pipe.pexpire(f"{p}chain:{s.definition_key}", ttl)
                pipe.zremrangebyscore(f"{p}all", "-inf", int(time.time() * 1000))
                pipe.zcard(f"{p}all")
                results = await pipe.execute()
            self._count = int(results[-1])
        except RedisError as e:
            log.warning("session sweep: Redis does not answer (%s)", type(e).__name__)
        return []

    # -- a frame's steps -------------------------------------------------------------
    def stored_answer(self, session: Session, jobs: Sequence[FrameJob]) -> list[SolvedFrame] | None:
        key = answer_key(jobs)
        if key is None:
            return None
        answer = session.answers.get(key)
        if answer is None or answer.digest != jobs_digest(jobs):
            return None
        return list(answer.frames)

    async def commit(
        self, session: Session, jobs: Sequence[FrameJob], out: list[SolvedFrame]
    ) -> None:
        if session.version == RELOAD:  # a write failed or was refused: Redis is right
            await self._reload_or_unavailable(session)
            raise StaleSession(session.id)
        key = answer_key(jobs)
        answer = None if key is None else StoredAnswer(jobs_digest(jobs), tuple(out))
        pairs = [] if answer is None else [key, pack_answer(answer)]
        behind = self.behind
        if behind is None:
            await self._write(session, "", pairs)
        elif behind.failed:
            session.version = RELOAD  # the next frame finds out whether Redis is back
            raise store_unavailable()
        else:  # the state now, under the session's lock: the flush comes later
            behind.queue(session, self._record(session), pairs)
        if answer is not None and key is not None:  # the oldest out (ids may start again)
            session.answers.pop(key, None)
            session.answers[key] = answer
            if len(session.answers) > KEPT_ANSWERS:
                del session.answers[next(iter(session.answers))]

    async def _reload_or_unavailable(self, session: Session) -> None:
        """Reload ``session`` from Redis (503 ``store_unavailable`` if Redis is still gone)."""
        behind = self.behind
        if behind is not None:
            behind.take(session.id)  # what this worker had not written is void
        await self.refresh(session)
        if behind is not None:
            behind.failed = False

    async def save(self, session: Session) -> None:
        if self.behind is not None:
            self.behind.take(session.id)  # written now, with the new pose or options
        await self._write(session, self._meta(session), [])

    def _args(
        self, session: Session, record: StreamRecord, meta: bytes | str, pairs: list[Any]
    ) -> list[Any]:
        state = pack_stream(record)
        args = [session.version, state, self._ttl_ms(), KEPT_ANSWERS, session.id]
        return [*args, meta, *pairs]

    async def _write(
        self,
        session: Session,
        meta: bytes | str,
        pairs: list[Any],
        record: StreamRecord | None = None,
    ) -> None:
        """Write ``record`` (default: the state now, under the lock), ``meta``, answers."""
        keys = self._keys(session.id, session.definition_key, session.owner)
        args = self._args(session, record or self._record(session), meta, pairs)
        try:
            v = await self._commit.run(keys, args)
        except RedisError as e:
            # What this worker solved is not stored: whatever it holds now may be ahead
            # of Redis, so it reloads before its next frame.
            session.version = RELOAD
            raise self._unavailable(e) from None
        self._written(session, v)
        if v == GONE:
            raise not_found()
        if v == MOVED:
            await self.refresh(session)
            raise StaleSession(session.id)

    def _written(self, session: Session, v: int) -> None:
        """Take a commit's answer: the new version, or the session gone / moved on."""
        if v == GONE:
            self._forget(session)
        elif v == MOVED:
            session.version = RELOAD
        else:
            session.version = v

    # -- written behind (IK_REDIS_WRITE_BEHIND_MS > 0) ---------------------------------
    async def _write_behind(self, batch: list[Pending]) -> None:
        """One flush: each session's snapshot and answers, in one pipeline."""
        calls = []
        for p in batch:
            s = p.session
            keys = self._keys(s.id, s.definition_key, s.owner)
            calls.append((keys, self._args(s, p.record, "", p.pairs), s))
        try:
            results = await self._commit.execute(calls)
        except RedisError as e:  # no answer: frames are refused until a reload works
            results = [e] * len(calls)
            assert self.behind is not None
            self.behind.failed = True
        # Refused (out of memory, read-only) or gone: logged; the sessions reload.
        if (error := next((v for v in results if isinstance(v, RedisError)), None)) is not None:
            self._unavailable(error)
        for (_, _, s), v in zip(calls, results, strict=True):
            if isinstance(v, Exception):
                s.version = RELOAD
            else:
                self._written(s, int(v))

    def _forget(self, session: Session) -> None:
        session.closed = True
        if self._sessions.get(session.id) is session:
            del self._sessions[session.id]

    async def refresh(self, session: Session) -> None:
        # Written behind: frames this worker answered may not be in Redis yet; they go
        # first, or the restore below would rewind the pose (a joint jump on the next
        # frame) and the counters.
        behind = self.behind
        pending = None
        if behind is not None:
            await behind.settled(session.id)
            pending = behind.take(session.id)
        if pending is not None and session.version != RELOAD:
            try:
                await self._write(session, "", pending.pairs, pending.record)
            except StaleSession:  # another worker wrote first: reloaded from Redis
                return
        try:
            fresh = await self._changed.read(session.id, session.version)
        except RedisError as e:
            raise self._unavailable(e) from None
        if fresh is None:
            return  # the version this worker holds (or just wrote) is the stored one
        stored, answers = fresh
        if not stored:
            self._forget(session)
            raise not_found()
        options = msgpack.unpackb(stored[b"meta"])[3]
        session.options = self._load_options(options)
        self._restore(session, stored, answers)

    async def check(self) -> None:
        await self._probe.check()

    async def close(self) -> None:
        if self.behind is not None:  # what is written behind goes before the exit
            await self.behind.close()
        await self.client.aclose()

    def _unavailable(self, e: RedisError) -> ServiceError:
        self._failures.failed(e)
        return store_unavailable()
