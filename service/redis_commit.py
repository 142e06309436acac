"""The one Lua script that writes a session to Redis, and the group commit that runs it.

The script creates a session (checking the session and per-key caps) or commits its
new state, version and answers if the version is still the one the worker started
from; either way it renews every key's expiry. ``GroupCommit`` runs the script for
every caller that arrives while a round trip is under way in one pipeline; ``connect``
makes the client they use; ``ReadinessProbe`` is ``/readyz``'s check, which says why
Redis failed (``redis_cause``).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable
from typing import Any

import redis.asyncio as aioredis
from redis.exceptions import (
    AuthenticationError,
    BusyLoadingError,
    NoScriptError,
    OutOfMemoryError,
    ReadOnlyError,
    RedisError,
    ResponseError,
)
from redis.exceptions import TimeoutError as RedisTimeout

from .errors import store_unavailable

log = logging.getLogger("service")

# KEYS: s, a, o, chain, all, owner (all again when none); ARGV: version expected ('new':
# create), state, ttl [ms], kept answers, session id, meta ('' keeps it), then pairs of
# (frame id, answer). Returns the new version, -1 when the session is gone, -2 when the
# version moved (another worker committed first), -3 / -4 at the session / owner cap.
COMMIT_SCRIPT = """
local ttl = tonumber(ARGV[3])
local t = redis.call('TIME')
local now = tonumber(t[1]) * 1000 + math.floor(tonumber(t[2]) / 1000)
local v
if ARGV[1] == 'new' then
  local max_all, max_owner = tonumber(ARGV[7]), tonumber(ARGV[8])
  redis.call('ZREMRANGEBYSCORE', KEYS[5], '-inf', now)
  if redis.call('ZCARD', KEYS[5]) >= max_all then return -3 end
  if KEYS[6] ~= KEYS[5] then
    redis.call('ZREMRANGEBYSCORE', KEYS[6], '-inf', now)
    if redis.call('ZCARD', KEYS[6]) >= max_owner then return -4 end
  end
  v = 0
  redis.call('HSET', KEYS[1], 'v', 0, 'state', ARGV[2], 'meta', ARGV[6])
else
  local expected = tonumber(ARGV[1])
  local current = redis.call('HGET', KEYS[1], 'v')
  if not current then return -1 end
  if tonumber(current) ~= expected then return -2 end
  v = expected + 1
  redis.call('HSET', KEYS[1], 'v', v, 'state', ARGV[2])
  if ARGV[6] ~= '' then redis.call('HSET', KEYS[1], 'meta', ARGV[6]) end
  for i = 7, #ARGV, 2 do
    redis.call('HSET', KEYS[2], ARGV[i], ARGV[i + 1])
    redis.call('LREM', KEYS[3], 0, ARGV[i])  -- an id sent again moves to the end
    redis.call('RPUSH', KEYS[3], ARGV[i])
  end
  local extra = redis.call('LLEN', KEYS[3]) - tonumber(ARGV[4])
  while extra > 0 do
    redis.call('HDEL', KEYS[2], redis.call('LPOP', KEYS[3]))
    extra = extra - 1
  end
end
for i = 1, 4 do redis.call('PEXPIRE', KEYS[i], ttl) end
redis.call('ZADD', KEYS[5], now + ttl, ARGV[5])
if KEYS[6] ~= KEYS[5] then
  redis.call('ZADD', KEYS[6], now + ttl, ARGV[5])
  redis.call('PEXPIRE', KEYS[6], ttl)
end
return v
"""
GONE, MOVED, SESSIONS_FULL, OWNER_FULL = -1, -2, -3, -4


class GroupCommit:
    """Runs the commit script for every caller that arrives while a round trip is under
    way in one pipeline: one round trip per batch, not per frame.

    EVALSHA by hand rather than redis-py's ``Script`` in a pipeline: that one asks
    ``SCRIPT EXISTS`` before every pipeline, a second round trip each time (measured:
    216 us of CPU per lone commit with it). The script is loaded once, and again when
    Redis answers NOSCRIPT (it restarted and lost it)."""

    def __init__(
        self,
        client: aioredis.Redis,
        script: str,
        failures: FailureLog | None = None,
        observe: Callable[[float], None] | None = None,
    ) -> None:
        self._client = client
        self._script = script
        self._failures = failures or FailureLog()  # told when a commit succeeds
        # Told each pipeline's seconds, stored or failed (ik_redis_commit_duration_seconds:
        # a frame's answer waits for it, and ik_server_duration_seconds ends before).
        self._observe = observe
        self._sha: str | None = None
        self._pending: list[tuple[list[str], list[Any], asyncio.Future[Any]]] = []
        self._flushing = False

    async def run(self, keys: list[str], args: list[Any]) -> int:
        fut: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        self._pending.append((keys, args, fut))
        if not self._flushing:
            self._flushing = True
            asyncio.get_running_loop().create_task(self._flush())
        return int(await fut)

    async def execute(self, batch: list[tuple[list[str], list[Any], Any]]) -> list[Any]:
        """Run the script for each (keys, args, _) of ``batch`` in one pipeline; the
        results in order (an exception for a failed one). Raises when all failed."""
        start = time.perf_counter()
        try:
            results = await self._execute(batch)
            if any(isinstance(r, NoScriptError) for r in results):
                self._sha = None  # Redis restarted: load it, run the batch again
                results = await self._execute(batch)
        finally:
            if self._observe is not None:
                self._observe(time.perf_counter() - start)
        # Only a batch stored whole is Redis answering again: with raise_on_error=False
        # a refusal (OOM at maxmemory, READONLY, MISCONF) is a result, not a raise, and
        # each refused frame would end the outage in the log and restart its throttle.
        if not any(isinstance(r, Exception) for r in results):
            self._failures.answered()
        return results

    async def _execute(self, batch: list[tuple[list[str], list[Any], Any]]) -> list[Any]:
        if self._sha is None:
            self._sha = str(await self._client.script_load(self._script))
        pipe = self._client.pipeline(transaction=False)
        for keys, args, _ in batch:
            pipe.execute_command("EVALSHA", self._sha, len(keys), *keys, *args)
        results: list[Any] = await pipe.execute(raise_on_error=False)
        return results

    async def _flush(self) -> None:
        try:
            while self._pending:
                batch, self._pending = self._pending, []
                try:
                    results = await self.execute(batch)
                except Exception as e:  # the whole batch failed (connection, timeout)
                    results = [e] * len(batch)
                for (_, _, fut), r in zip(batch, results, strict=True):
                    if fut.done():
                        continue
                    if isinstance(r, Exception):
                        fut.set_exception(r)
                    else:
                        fut.set_result(r)
        finally:
            self._flushing = False


def connect(url: str, timeout_s: float) -> aioredis.Redis:
    """A client whose every call gives up after ``timeout_s`` (no call hangs when Redis
    is gone) and that reconnects by itself on the next call."""
    return aioredis.Redis.from_url(
        url,
        socket_timeout=timeout_s,
        socket_connect_timeout=timeout_s,
        health_check_interval=0,
        retry_on_timeout=False,
    )


def refuses(e: RedisError) -> bool:
    """Redis answered, and refused: a configuration to fix, not an outage to wait out
    (redis-py's AuthenticationError is a ConnectionError, so it is tested first)."""
    return isinstance(e, AuthenticationError | ResponseError)


def refuses_writes(e: RedisError) -> bool:
    """Redis refused a write for its own state, not this worker's credentials: out of
    memory at maxmemory (OOM), a read-only replica (READONLY), a failed snapshot
    (MISCONF, which redis-py leaves a plain ResponseError)."""
    return isinstance(e, OutOfMemoryError | ReadOnlyError) or str(e).startswith("MISCONF")


def redis_cause(e: RedisError) -> str:
    """Why Redis failed a call, in an operator's words, for ``/readyz`` (which the
    balancer may serve to anyone): a refusal with Redis's own reason; an outage by its
    kind only, since redis-py's message names the host and port (the log has it)."""
    name = type(e).__name__
    if refuses_writes(e):  # a ResponseError too, but IK_REDIS_URL is not what to check
        return f"Redis refuses writes ({name}: {e}): see Redis's own log and settings"
    if refuses(e):
        return (
            f"Redis refuses this worker ({name}: {e}): check the user, password and "
            "database number in IK_REDIS_URL"
        )
    if isinstance(e, RedisTimeout):
        return f"Redis did not answer within IK_REDIS_TIMEOUT_S ({name})"
    if isinstance(e, BusyLoadingError):  # a ConnectionError to redis-py, but it answered
        return f"Redis is loading its data set into memory ({name}): it serves when done"
    return f"Redis cannot be reached ({name}; the worker's log says where it tried)"


class FailureLog:
    """The WARNING for requests Redis failed, at most once per ``every_s`` per cause,
    with how many were left out since: one line per failed frame flooded the log
    (8,516 lines in a 7 s outage, an operator trial; 60 a second per 60 Hz client).
    When Redis answers again (``answered``), one line says so, with the failures left
    out since the last warning: without it the log ended at the last warning, and the
    outage's end and size were nowhere."""

    def __init__(self, every_s: float = 10.0, clock: Any = time.monotonic) -> None:
        self.every_s = every_s
        self.clock = clock
        self.last: dict[str, float] = {}
        self.left_out: dict[str, int] = {}
        self.failing_since: float | None = None  # the first failure since Redis answered

    def failed(self, e: RedisError) -> None:
        cause = redis_cause(e)
        now = self.clock()
        if self.failing_since is None:
            self.failing_since = now
        if now - self.last.get(cause, -math.inf) < self.every_s:
            self.left_out[cause] = self.left_out.get(cause, 0) + 1
            return
        more = self.left_out.pop(cause, 0)
        since = f"; {more} more since the last such line" if more else ""
        # A refusal's cause quotes Redis's message already: not twice on one line.
        said = str(e)
        detail = "" if not said or said in cause else f" ({said})"
        log.warning("a request failed: %s%s%s", cause, detail, since)
        self.last[cause] = now

    def answered(self) -> None:
        """Redis stored a commit (not merely answered: a refusal is an answer, and
        PING answers while writes are refused). After failures, one line: Redis is
        back, for how long requests failed, and how many were not logged since the last
        warning. The next outage's first failure is logged at once. Called after every
        batch stored whole: one test when nothing failed."""
        if self.failing_since is None:
            return
        failed_s = self.clock() - self.failing_since
        left_out = sum(self.left_out.values())
        self.failing_since = None
        self.last.clear()
        self.left_out.clear()
        log.info(
            "Redis answers again (requests failed for %.1f s); %d failed request(s) not "
            "logged since the last warning",
            failed_s,
            left_out,
        )


class ReadinessProbe:
    """``/readyz``'s check of Redis: a PING; when it fails, ``store_unavailable`` whose
    detail is the operator's cause (``redis_cause``), logged when the cause changes
    (a refusal at ERROR: it needs a fix), not at every probe, with where the worker
    tried; and once when Redis answers again. A PING that answers does not end the
    requests' failures (``FailureLog``): Redis answers it while it refuses writes (out
    of memory at maxmemory, a read-only replica)."""

    def __init__(self, client: aioredis.Redis) -> None:
        self.client = client
        self.last_cause: str | None = None

    async def check(self) -> None:
        try:
            await self.client.ping()
        except RedisError as e:
            cause = redis_cause(e)
            if cause != self.last_cause:
                level = logging.ERROR if refuses(e) else logging.WARNING
                said = str(e)
                detail = "" if not said or said in cause else f": {said}"
                log.log(level, "not ready: %s (at %s%s)", cause, where(self.client), detail)
            self.last_cause = cause
            raise store_unavailable(detail=cause) from None
        if self.last_cause is not None:
            log.info("ready: Redis at %s answers again", where(self.client))
        self.last_cause = None


def where(client: aioredis.Redis) -> str:
    """The address a client connects to, for the log: host and port, or the socket's
    path, and whether it speaks TLS (never the URL: it may hold a password)."""
    pool = client.connection_pool
    kwargs = pool.connection_kwargs
    if "path" in kwargs:
        return f"unix socket {kwargs['path']}"
    tls = " over TLS (rediss://)" if pool.connection_class.__name__ == "SSLConnection" else ""
    return f"{kwargs.get('host', 'localhost')}:{kwargs.get('port', 6379)}{tls}"
