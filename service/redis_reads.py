"""Reading a session back from Redis: whole (a worker that does not hold it), or only
if another worker committed since this one's copy (GET, FK, a pose or options change).

Both take one round trip. The conditional read compares the version in Redis, so that
a worker which already holds the latest state (the usual case: the balancer sends a
session's requests to the worker that answers its frames) gets a nil back instead of
the state and the last ``KEPT_ANSWERS`` answers, and restores nothing.
"""

from __future__ import annotations

import redis.asyncio as aioredis
from redis.commands.core import AsyncScript

from .stored_frames import oldest_first

# (the session's hash, its answers by frame id, oldest first)
StoredSession = tuple[dict[bytes, bytes], dict[bytes, bytes]]

# KEYS: s, a, o; ARGV: the version the worker holds. Returns nil when it is the stored
# one, else the three reads as flat lists (an empty first list: the session is gone).
_READ_IF_CHANGED = """
if redis.call('HGET', KEYS[1], 'v') == ARGV[1] then return nil end
return {redis.call('HGETALL', KEYS[1]), redis.call('HGETALL', KEYS[2]),
        redis.call('LRANGE', KEYS[3], 0, -1)}
"""


def _keys(prefix: str, session_id: str) -> list[str]:
    return [f"{prefix}s:{session_id}", f"{prefix}a:{session_id}", f"{prefix}o:{session_id}"]


def _pairs(flat: list[bytes]) -> dict[bytes, bytes]:
    return dict(zip(flat[::2], flat[1::2], strict=True))


async def read_session(client: aioredis.Redis, prefix: str, session_id: str) -> StoredSession:
    """A session's hash and its answers oldest first (both empty: no such session)."""
    s, a, o = _keys(prefix, session_id)
    async with client.pipeline(transaction=False) as pipe:
        pipe.hgetall(s)
        pipe.hgetall(a)
        pipe.lrange(o, 0, -1)
        stored, answers, order = await pipe.execute()
    return stored, oldest_first(order, answers)


class ChangedReader:
    """``read`` a session only if its stored version is not ``version``."""

    def __init__(self, client: aioredis.Redis, prefix: str) -> None:
        self._prefix = prefix
        # redis-py's Script: EVALSHA, loaded again by itself after a Redis restart.
        self._script: AsyncScript = client.register_script(_READ_IF_CHANGED)

    async def read(self, session_id: str, version: int) -> StoredSession | None:
        """None when Redis holds ``version`` (this worker's copy is the latest), else
        as ``read_session``."""
        found = await self._script(keys=_keys(self._prefix, session_id), args=[version])
        if found is None:
            return None
        stored, answers, order = found
        return _pairs(stored), oldest_first(order, _pairs(answers))
