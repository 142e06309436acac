"""Sessions created per client address when the server has no API keys (issue 23)."""

from __future__ import annotations

from collections.abc import Callable


class SessionStarts:
    """Sessions created per client address, a token bucket each (one minute's worth of
    burst): without API keys, one address filled the 1,000-session cap in 1.8 s."""

    def __init__(self, per_minute: float, clock: Callable[[], float]) -> None:
        self.rate_per_s = per_minute / 60.0
        self.burst = max(1.0, per_minute)
        self.clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}  # address -> (level, at)

    def take(self, address: str) -> float:
        """0.0 when ``address`` may create a session now (and counts it), else the
        seconds until it may. Unlimited when the rate is 0."""
        if self.rate_per_s <= 0:
            return 0.0
        now = self.clock()
        level, at = self._buckets.get(address, (self.burst, now))
        level = min(self.burst, level + (now - at) * self.rate_per_s)
        if level < 1.0:
            self._buckets[address] = (level, now)
            return (1.0 - level) / self.rate_per_s
        self._buckets[address] = (level - 1.0, now)
        if len(self._buckets) > 10_000:  # bounded: forget the buckets full again
            refill = self.rate_per_s
            for a, (lv, t) in list(self._buckets.items()):
                if lv + (now - t) * refill >= self.burst:
                    del self._buckets[a]
        return 0.0
