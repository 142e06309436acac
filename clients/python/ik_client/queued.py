"""What an asyncio stream holds back while it reconnects: the messages sent since the
connection dropped, which go out on the new connection, at most ``max_queued`` of them
(the same rule as the TypeScript client's ``src/queued.ts``).

A game that keeps sending targets through an outage (a server restart, a Wi-Fi drop)
would otherwise grow its memory for as long as the outage lasts, then have the server
solve every stale target, in order, before the current one. Past the limit the oldest
waiting message is dropped (``MessageDropped``): what goes out on the new connection is
the most recent targets. Messages that went out before the drop are not held here: they
are sent again and answered exactly once, whatever the limit.
"""

from __future__ import annotations

import math
from typing import Generic, TypeVar

# At most this many messages wait for a reconnect, by default: a second of a 60 Hz game's
# frames. A blip shorter than that loses nothing; after a longer outage the server solves
# the last second's targets, not every stale one.
DEFAULT_MAX_QUEUED = 60

Item = TypeVar("Item")


def max_queued_option(value: float) -> float:
    """``value`` (a ``max_queued`` argument) checked: an int >= 0, or ``math.inf`` (keep
    every message, as the client did before the limit).

    Raises:
        ValueError: Anything else (a negative number, a fraction, NaN, a bool).
    """
    if value == math.inf or (isinstance(value, int) and not isinstance(value, bool) and value >= 0):
        return value
    raise ValueError(f"max_queued must be an int >= 0 or math.inf, got {value!r}")


class SendQueue(Generic[Item]):
    """The messages waiting for a reconnect, oldest first, at most ``limit``."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self._items: list[Item] = []

    def __len__(self) -> int:
        return len(self._items)

    def add(self, item: Item) -> list[Item]:
        """Hold ``item``; returns what no longer fits: the oldest items beyond ``limit``
        (``item`` itself when ``limit`` is 0)."""
        self._items.append(item)
        over = len(self._items) - self.limit
        if over <= 0:
            return []
        dropped = self._items[: int(over)]
        del self._items[: int(over)]
        return dropped
