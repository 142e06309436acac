"""How patiently the client gets an answer back after a failure: ``Reconnect`` (the
policy a caller sets) and ``Backoff`` (one outage's clock), without I/O.

A policy is a deadline, not a count: a worker that restarts (loads its compiled solver,
reconnects to Redis) or a balancer that routes around a dead backend takes a time, not a
number of tries, and the tries that fit in it depend on how fast each one fails (a refused
connection fails at once, a dead host after a timeout). The waits grow exponentially
with random jitter (so that the clients of a worker that died do not all come back in
the same millisecond), up to ``max_delay_s`` (so that a server that is back is found
again within about that long), never sooner than a ``Retry-After`` the server or the
balancer sent, and never past the deadline: a ``Retry-After`` that would end after it
ends the wait at once (the caller decides). Only failures that waiting can mend use the
budget; a session that is gone (404, close 4404) or a refused token fails at once.

The figures behind the defaults (docs/websocket.md, "Reconnecting"): a worker killed
and started again on this machine answered ``/readyz`` 200 4.4-4.8 s after its start
(its compiled solver loaded from the disk cache, on two busy cores), where the old budget
(6 tries, 0.05 s doubling to 2 s) gave up after 3.15 s; deploy/haproxy.cfg marked a
killed backend down within 1 s and a restarted one up within 0.5 s of its readiness.
``deadline_s=30`` covers those several times over and still tells a game within half a
minute that the service is gone; a first start that must compile the solver (minutes)
is not covered: raise ``deadline_s`` for that, or open the stream again.
"""

from __future__ import annotations

import math
import random
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar


@dataclass(frozen=True, slots=True, kw_only=True)
class Reconnect:
    """How long and how often a failed connection or call is tried again.

    The wait before try ``n`` (0, 1, ...) is ``min(initial_delay_s * 2**n, max_delay_s)``,
    less a random part of up to ``jitter`` of it (1: "full jitter", anywhere between
    zero and the whole wait; 0: none), and at least a ``Retry-After`` sent with the
    failure. The tries stop ``deadline_s`` after the first failure since the last answer
    (or after ``attempts`` tries, when set). ``Reconnect.OFF`` (or ``deadline_s=0``)
    never tries again: the failure is raised at once.

    Attributes:
        deadline_s: How long after the first failure the last try may start [s].
        initial_delay_s: The wait before the first try, before jitter [s].
        max_delay_s: The longest wait between tries, before jitter [s].
        jitter: The random share of each wait, in [0, 1].
        attempts: At most this many tries as well (None: as many as fit in the deadline).
    """

    deadline_s: float = 30.0
    initial_delay_s: float = 0.1
    max_delay_s: float = 2.0
    jitter: float = 1.0
    attempts: int | None = None
    OFF: ClassVar[Reconnect]  # never tries again (below)

    def __post_init__(self) -> None:
        for name in ("deadline_s", "initial_delay_s", "max_delay_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        if not 0.0 <= self.jitter <= 1.0:
            raise ValueError(f"jitter must be in [0, 1], got {self.jitter!r}")
        if self.attempts is not None and self.attempts < 0:
            raise ValueError(f"attempts must be >= 0 or None, got {self.attempts!r}")

    @property
    def enabled(self) -> bool:
        return self.deadline_s > 0 and self.attempts != 0

    def delay_s(self, attempt: int, *, rng: random.Random | None = None) -> float:
        """The wait before try ``attempt`` (0, 1, ...), jitter included [s]."""
        # The exponent is bounded: 2**attempt overflows a float after ~1000 tries.
        delay = min(self.initial_delay_s * 2.0 ** min(attempt, 64), self.max_delay_s)
        if self.jitter == 0.0:
            return delay
        draw = (rng or random).random()  # jitter is not a secret: the module's generator
        return delay * (1.0 - self.jitter * draw)


Reconnect.OFF = Reconnect(deadline_s=0.0)
DEFAULT_RECONNECT = Reconnect()


class Backoff:
    """One outage's clock under a ``Reconnect`` policy: started by the first failure,
    cleared by an answer. ``next_wait_s`` says how long to wait before the next try, or
    None when the budget is spent."""

    def __init__(
        self,
        policy: Reconnect,
        *,
        clock: Callable[[], float] = time.monotonic,
        rng: random.Random | None = None,
    ) -> None:
        self.policy = policy
        self._clock = clock
        self._rng = rng
        self.tries = 0  # since the last answer
        self._started: float | None = None

    @property
    def recovering(self) -> bool:
        """A failure came and no answer since."""
        return self._started is not None

    def failed(self) -> None:
        """Note a failure; the first since the last answer starts the clock."""
        if self._started is None:
            self._started = self._clock()

    def answered(self) -> None:
        """An answer came: the next failure starts a new outage, with the whole budget."""
        self._started = None
        self.tries = 0

    def next_wait_s(self, retry_after_s: float | None = None) -> float | None:
        """The wait before the next try [s], counting it; None: give up (the deadline
        or the attempts are spent, or ``retry_after_s`` would end after the deadline)."""
        self.failed()
        assert self._started is not None
        policy = self.policy
        if not policy.enabled or (policy.attempts is not None and self.tries >= policy.attempts):
            return None
        left = self._started + policy.deadline_s - self._clock()
        wait = policy.delay_s(self.tries, rng=self._rng)
        if retry_after_s is not None and retry_after_s > 0:
            if retry_after_s > left:
                return None  # the server asks for more time than the caller gives
            wait = max(wait, retry_after_s)
        if left <= 0:
            return None
        self.tries += 1
        return min(wait, left)


def retry_after_s(value: str | None) -> float | None:
    """An HTTP ``Retry-After`` in seconds (its date form is not used by the service or
    the balancer: None, as for a missing or unreadable one)."""
    if value is None:
        return None
    try:
        seconds = float(value)
    except ValueError:
        return None
    return seconds if math.isfinite(seconds) and seconds >= 0 else None
