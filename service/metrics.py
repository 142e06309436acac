"""Prometheus metrics, one registry per app (tests build many apps in one process).

Series: ``ik_frames_total{termination,success}``, ``ik_restarts_total``,
``ik_solve_duration_seconds`` (the solver alone), ``ik_server_duration_seconds{transport}``
(message received to reply ready), ``ik_active_sessions``, ``ik_websockets``
(open WebSockets), ``ik_errors_total{code,transport}``, ``ik_sessions_created_total``,
``ik_sessions_expired_total``, ``ik_event_loop_tasks``; with sessions in Redis
``ik_redis_commit_duration_seconds`` (a group commit's pipeline, which a frame's answer
waits for after ``ik_server_duration_seconds`` ends). Labels are enum values, never
session ids.

The per-frame series (frames, restarts, the two duration histograms) are plain numbers
updated on the event loop and turned into Prometheus families at scrape time
(``_FrameSeries``): prometheus_client's counters and histograms take a lock per
increment, and a frame made seven of them (about 20 us of a frame's CPU in a loaded
worker). The rest are ordinary prometheus_client metrics (rare events).
"""

from __future__ import annotations

import asyncio
from bisect import bisect_left
from collections.abc import Callable, Iterator, Sequence

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    disable_created_metrics,
    generate_latest,
)
from prometheus_client.core import CounterMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.registry import Collector
from prometheus_client.utils import floatToGoString

from schemas import ErrorCode
from solver.ik import IKResult, IKStatus
from solver.optim import Termination

from .convert import SolvedFrame

# No ``<name>_created`` series beside each counter and histogram: it doubled the series
# a Prometheus stores per worker and says only when the worker started (an operator
# trial). prometheus_client's switch is global to the process, which is the service.
disable_created_metrics()

# 10 us .. ~0.33 s, x2 steps: solves take microseconds to the frame's budget.
DURATION_BUCKETS_S = tuple(10e-6 * 2**k for k in range(16))
# 100 us .. ~1.6 s, x2 steps: a Redis round trip on a LAN, up to a timed-out one
# (IK_REDIS_TIMEOUT_S, 0.5 s by default).
COMMIT_BUCKETS_S = tuple(100e-6 * 2**k for k in range(15))
SOLVED = IKStatus.SOLVED


def _loop_tasks() -> float:
    try:
        return float(len(asyncio.all_tasks()))
    except RuntimeError:  # scraped outside a running loop (tests)
        return 0.0


_TRANSPORTS = ("http", "ws")


class _Histogram:
    """Bucket counts (non-cumulative, +Inf last) and the sum of observations."""

    __slots__ = ("counts", "total")

    def __init__(self) -> None:
        self.counts = [0] * (len(DURATION_BUCKETS_S) + 1)
        self.total = 0.0

    def observe(self, value: float) -> None:
        # bisect_left: the first bound >= value, i.e. Prometheus' "le" bucket.
        self.counts[bisect_left(DURATION_BUCKETS_S, value)] += 1
        self.total += value

    def buckets(self) -> list[tuple[str, float]]:
        out = []
        running = 0
        for bound, n in zip((*DURATION_BUCKETS_S, float("inf")), self.counts, strict=True):
            running += n
            out.append((floatToGoString(bound), float(running)))
        return out


class _FrameSeries(Collector):
    """``ik_frames_total``, ``ik_restarts_total``, ``ik_solve_duration_seconds`` and
    ``ik_server_duration_seconds`` as plain numbers, exported when scraped.

    Updated only on the event loop's thread (pooled solves are recorded when the pool
    hands them back), and read there by /metrics, so no lock is needed.
    """

    def __init__(self) -> None:
        self.keys = [(t.value, ok) for t in Termination for ok in (True, False)]
        self.slot = {key: i for i, key in enumerate(self.keys)}
        self.frames = [0] * len(self.keys)
        self.restarts = 0
        self.solve = _Histogram()
        self.server = {tr: _Histogram() for tr in _TRANSPORTS}

    def collect(self) -> Iterator[Metric]:
        frames = CounterMetricFamily(
            "ik_frames",
            "Frames solved, by termination code and success",
            labels=["termination", "success"],
        )
        for (term, ok), n in zip(self.keys, self.frames, strict=True):
            frames.add_metric([term, str(ok).lower()], float(n))
        yield frames
        restarts = CounterMetricFamily("ik_restarts", "Random restarts over all frames")
        restarts.add_metric([], float(self.restarts))
        yield restarts
        solve = HistogramMetricFamily(
            "ik_solve_duration_seconds", "Time in the compiled solver per frame"
        )
        solve.add_metric([], self.solve.buckets(), self.solve.total)
        yield solve
        server = HistogramMetricFamily(
            "ik_server_duration_seconds",
            "Request or message received to frame result ready",
            labels=["transport"],
        )
        for tr, h in self.server.items():
            server.add_metric([tr], h.buckets(), h.total)
        yield server


class Metrics:
    """The service's counters and histograms."""

    def __init__(self, active_sessions: Callable[[], int]) -> None:
        r = self.registry = CollectorRegistry(auto_describe=True)
        self.series = _FrameSeries()
        r.register(self.series)
        self.sessions = Gauge("ik_active_sessions", "Sessions in the store", registry=r)
        self.sessions.set_function(lambda: float(active_sessions()))
        self.websockets = Gauge("ik_websockets", "Open WebSocket connections", registry=r)
        self.errors = Counter(
            "ik_errors",
            "Client-visible errors by code and transport",
            ["code", "transport"],
            registry=r,
        )
        # Read at scrape time, on the event loop: what a soak watches for leaks.
        self.tasks = Gauge("ik_event_loop_tasks", "Tasks on the server's event loop", registry=r)
        self.tasks.set_function(_loop_tasks)
        self.sessions_created = Counter("ik_sessions_created", "Sessions created", registry=r)
        self.sessions_expired = Counter("ik_sessions_expired", "Sessions expired", registry=r)
        # One observation per pipeline (frames committed together share it), not per
        # frame; exported only by a worker with IK_REDIS_URL (``watch_commits``).
        self.redis_commit = Histogram(
            "ik_redis_commit_duration_seconds",
            "Redis round trip of a group commit (stored or failed)",
            buckets=COMMIT_BUCKETS_S,
            registry=None,
        )

    def watch_commits(self) -> Callable[[float], None]:
        """Export ``ik_redis_commit_duration_seconds``; returns what observes it."""
        self.registry.register(self.redis_commit)
        return self.redis_commit.observe

    def frame(self, r: IKResult, server_s: float, transport: str) -> None:
        """Count one solved frame. Call on the event loop's thread only."""
        series = self.series
        # The member itself as the key: a StrEnum hashes and compares as its string,
        # and ``.value`` is a Python-level property (one per frame).
        series.frames[series.slot[(r.termination, r.status is SOLVED)]] += 1
        if r.restarts:
            series.restarts += r.restarts
        series.solve.observe(r.solve_us * 1e-6)
        series.server[transport].observe(server_s)

    def frames(self, batch: Sequence[SolvedFrame], transport: str) -> None:
        """Count solved frames, as ``frame`` each. Event loop's thread only."""
        # ``frame``'s body with its lookups done once: a batch of 50 characters counts
        # 50 frames per message.
        series = self.series
        counts = series.frames
        slot = series.slot
        solve = series.solve
        server = series.server[transport]
        for solved in batch:
            r = solved.result
            counts[slot[(r.termination, r.status is SOLVED)]] += 1
            if r.restarts:
                series.restarts += r.restarts
            solve.observe(r.solve_us * 1e-6)
            server.observe(solved.server_us * 1e-6)

    def error(self, code: ErrorCode, transport: str) -> None:
        """Count one client-visible error (the label is the code's value)."""
        self.errors.labels(code=code.value, transport=transport).inc()

    def render(self) -> bytes:
        return generate_latest(self.registry)
