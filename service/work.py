"""Classes of work, each with its own threads and its own bound (issue 23).

Chain builds, one-shot solves, a session's pooled frames and planned clips used to share
one 2-thread pool: two long clips held both threads and ``POST /v1/sessions`` waited
30 s behind them. Each class now queues on threads of its own, and refuses (503
``server_busy``) rather than queue without end. Pooled frames are also admitted by
cost, their worst case (frames x time_budget_us: the budget is the wall clock of one
frame's whole solve, restarts included): one request is capped, and one client holds
at most a share of the class's cost in flight (429 ``too_much_work``).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from enum import StrEnum
from typing import Any, TypeVar

from starlette import status

from schemas import ErrorCode

from .errors import ServiceError

T = TypeVar("T")


class WorkClass(StrEnum):
    BUILD = "build"  # chain parsing and a session's solver (POST /v1/sessions, /v1/solve)
    SOLVE = "solve"  # one-shot solves (/v1/solve)
    FRAMES = "frames"  # a session's frames and clips too long to solve inline
    PLAN = "plan"  # planned clips (one at a time: a plan takes milliseconds per frame)


def server_busy(work: WorkClass, limit: int) -> ServiceError:
    return ServiceError(
        ErrorCode.SERVER_BUSY,
        f"{limit} {work.value} jobs are already queued or running; try again shortly",
        status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
        retry_after_s=1.0,
    )


def too_much_work(held_s: float, share_s: float, retry_after_s: float) -> ServiceError:
    return ServiceError(
        ErrorCode.TOO_MUCH_WORK,
        f"this client already has {held_s:.3g} s of solving queued or running, its share "
        f"is {share_s:.3g} s (IK_MAX_CLIENT_WORK_S); wait for its answers",
        status_code=status.HTTP_429_TOO_MANY_REQUESTS,
        retry_after_s=retry_after_s,
    )


class WorkPool:
    """One class of work: its threads, and at most ``max_in_flight`` jobs queued or
    running. A job counts until its thread is done, also when its caller went away."""

    def __init__(self, work: WorkClass, threads: int, max_in_flight: int) -> None:
        self.work = work
        self.max_in_flight = max_in_flight
        self.in_flight = 0  # changed on the loop only
        self.executor = ThreadPoolExecutor(max_workers=threads, thread_name_prefix=f"ik-{work}")

    def admit(self) -> None:
        """Raises ``server_busy`` when the class is full."""
        if self.in_flight >= self.max_in_flight:
            raise server_busy(self.work, self.max_in_flight)

    def submit(self, fn: Callable[..., T], *args: Any) -> asyncio.Future[T]:
        """Queue ``fn`` (admitted or not: the caller decides); the future is the loop's."""
        self.in_flight += 1
        fut = asyncio.get_running_loop().run_in_executor(self.executor, fn, *args)
        fut.add_done_callback(self._done)
        return fut

    def _done(self, _: asyncio.Future[Any]) -> None:
        self.in_flight -= 1

    async def run(self, fn: Callable[..., T], *args: Any) -> T:
        """Admit, run ``fn`` on this class's threads, return its result. The thread's
        work is not cancelled with the caller (shield), so the count stays true."""
        self.admit()
        return await asyncio.shield(self.submit(fn, *args))

    def shutdown(self) -> None:
        self.executor.shutdown(wait=False, cancel_futures=True)


class CostShares:
    """The worst-case seconds of solving each client has queued or running in a class,
    against a per-client share: one client cannot fill a class's threads for long."""

    def __init__(self, share_s: float) -> None:
        self.share_s = share_s
        self.held: dict[str, float] = {}  # changed on the loop only

    def take(self, client: str, cost_s: float) -> None:
        """Count ``cost_s`` for ``client``, or raise ``too_much_work``. A client with
        nothing in flight is always admitted (one request's cap is checked elsewhere)."""
        held = self.held.get(client, 0.0)
        if held > 0.0 and held + cost_s > self.share_s:
            raise too_much_work(held, self.share_s, retry_after_s=held)
        self.held[client] = held + cost_s

    def give_back(self, client: str, cost_s: float) -> None:
        left = self.held.get(client, 0.0) - cost_s
        if left > 1e-9:
            self.held[client] = left
        else:
            self.held.pop(client, None)
