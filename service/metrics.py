"""Prometheus metrics, one registry per app (tests build many apps in one process).

Series: ``ik_frames_total{termination,success}``, ``ik_restarts_total``,
``ik_solve_duration_seconds`` (the solver alone), ``ik_server_duration_seconds{transport}``
(message received to reply ready), ``ik_active_sessions``, ``ik_websockets``
(open WebSockets), ``ik_errors_total{code,transport}``, ``ik_sessions_created_total``,
``ik_sessions_expired_total``, ``ik_event_loop_tasks``. Labels are enum values, never session ids.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

from solver.ik import IKResult
from solver.termination import Termination

# 10 us .. ~0.33 s, x2 steps: solves take microseconds to the frame's budget.
_BUCKETS = tuple(10e-6 * 2**k for k in range(16))


def _loop_tasks() -> float:
    try:
        return float(len(asyncio.all_tasks()))
    except RuntimeError:  # scraped outside a running loop (tests)
        return 0.0


class Metrics:
    """The service's counters and histograms."""

    def __init__(self, active_sessions: Callable[[], int]) -> None:
        r = self.registry = CollectorRegistry(auto_describe=True)
        self.frames = Counter(
            "ik_frames",
            "Frames solved, by termination code and success",
            ["termination", "success"],
            registry=r,
        )
        self.restarts = Counter("ik_restarts", "Random restarts over all frames", registry=r)
        self.solve_seconds = Histogram(
            "ik_solve_duration_seconds",
            "Time in the compiled solver per frame",
            buckets=_BUCKETS,
            registry=r,
        )
        self.server_seconds = Histogram(
            "ik_server_duration_seconds",
            "Request or message received to frame result ready",
            ["transport"],
            buckets=_BUCKETS,
            registry=r,
        )
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
        # Bind label children once: .labels() costs a dict lookup and a lock per call.
        self._frame_children = {
            (t.value, ok): self.frames.labels(termination=t.value, success=str(ok).lower())
            for t in Termination
            for ok in (True, False)
        }
        self._server_children = {
            tr: self.server_seconds.labels(transport=tr) for tr in ("http", "ws")
        }

    def frame(self, r: IKResult, server_s: float, transport: str) -> None:
        self._frame_children[(r.termination.value, r.success)].inc()
        if r.restarts:
            self.restarts.inc(r.restarts)
        self.solve_seconds.observe(r.solve_us * 1e-6)
        self._server_children[transport].observe(server_s)

    def error(self, code: str, transport: str) -> None:
        self.errors.labels(code=code, transport=transport).inc()

    def render(self) -> bytes:
        return generate_latest(self.registry)
