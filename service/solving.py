"""Where and how frames are solved: inline on the event loop, or in the solver pool.

The rule (measured, see docs/operations.md and bench/ws_inline_vs_thread.py): a request whose
worst case, frames x time_budget_us, is at most ``IK_INLINE_BUDGET_US`` is solved inline
under the session's lock (a hand-off to a thread costs more than a typical solve);
anything longer runs in a small dedicated thread pool, where the compiled core releases
the GIL, so the loop keeps serving other clients. Model building and one-shot solves
(chain parsing is Python and can take milliseconds) always run in the pool.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import gc
import logging
import math
import threading
import time
from collections.abc import Awaitable, Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

import numpy as np
from starlette import status

from schemas import ErrorCode, StartupProgress
from solver.ik import IKOptions, IKSolver
from solver.ik import Target as SolverTarget
from solver.path import PlannedPath, plan_path

from .config import Settings
from .convert import ChainView, FrameJob, SolvedFrame, plan_steps
from .errors import (
    ServiceError,
    invalid_problem,
    not_found,
    not_ready,
    plans_busy,
    store_unavailable,
    too_many_plans,
)
from .metrics import Metrics
from .sessions import STALE_RETRIES, Session, SessionStore, StaleSession
from .startup import Report, warm_solver
from .work import CostShares, WorkClass, WorkPool

log = logging.getLogger("service")
T = TypeVar("T")


WarmupFn = Callable[[Report], float]


def default_warmup(compile_processes: int) -> WarmupFn:
    """The service's warm-up: load the solver's compiled core, compiling it first in
    up to ``compile_processes`` child processes when the on-disk cache lacks it."""

    def warm(report: Report) -> float:
        return warm_solver(report, processes=compile_processes)

    return warm


class Warmup:
    """Runs the warm-up once in a thread; ``ready`` flips when it is done, ``progress``
    holds its last report until then."""

    def __init__(self, fn: WarmupFn) -> None:
        self._fn = fn
        self.ready = threading.Event()
        self.seconds: float | None = None
        self.error: str | None = None
        self._progress: StartupProgress | None = None
        self._started = time.monotonic()
        self._thread = threading.Thread(target=self._run, name="ik-warmup", daemon=True)

    def start(self) -> None:
        self._started = time.monotonic()
        self._thread.start()

    def _report(self, progress: StartupProgress) -> None:
        self._progress = progress  # one reference swap: readers see the old or the new

    @property
    def progress(self) -> StartupProgress | None:
        """The warm-up's last report, its ``elapsed_s`` brought up to now (a single
        function may compile for a minute between two reports)."""
        last = self._progress
        if last is None:
            return None
        elapsed = round(max(last.elapsed_s, time.monotonic() - self._started), 1)
        return last.model_copy(update={"elapsed_s": elapsed})

    def _run(self) -> None:
        t = time.perf_counter()
        try:
            self._fn(self._report)
        except Exception as e:  # readyz stays 503 and says why
            self.error = f"{type(e).__name__}: {e}"
            log.exception("solver warm-up failed")
            return
        self.seconds = time.perf_counter() - t
        freeze_long_lived_objects()
        log.info("solver warm in %.2f s: ready", self.seconds)
        self.ready.set()


def freeze_long_lived_objects() -> float:
    """Move every object alive now out of the cyclic GC's reach; returns the ms it took.

    After the solver is loaded the process holds ~160k tracked objects (numba, llvmlite,
    pydantic, FastAPI), nearly all alive until exit. A full collection walks them all
    (measured: 85 ms), and one lands every so often under a steady stream of frames: a
    stall of that length fails every client's frame deadline at once. Frozen objects are
    never scanned again, so later collections only walk what the service created since
    (sessions, frames in flight): well under a millisecond. One full collection first,
    so that no garbage is frozen with them.
    """
    t = time.perf_counter()
    gc.collect()
    gc.freeze()
    return (time.perf_counter() - t) * 1e3


class Runner:
    """Runs solves inline or in the pool, records metrics, keeps sessions in order."""

    def __init__(self, settings: Settings, *, metrics: Metrics, warmup: Warmup) -> None:
        """The limits and thread counts are ``settings``' (docs/operations.md)."""
        self.inline_budget_us = settings.inline_budget_us
        self.max_frames_per_s = settings.max_frames_per_s
        # One second's worth, and never less than the longest clip a request may carry.
        self.burst = max(settings.max_frames_per_s, float(settings.max_frames_per_request))
        self.metrics = metrics
        self.warmup = warmup
        # Each class of work on threads of its own (service/work.py): a long clip
        # never delays a session's creation or a one-shot solve.
        queued = settings.max_queued_jobs
        self.pools = {
            WorkClass.BUILD: WorkPool(WorkClass.BUILD, settings.build_threads, queued),
            WorkClass.SOLVE: WorkPool(WorkClass.SOLVE, settings.oneshot_threads, queued),
            WorkClass.FRAMES: WorkPool(WorkClass.FRAMES, settings.solver_threads, queued),
        }
        # A request's worst case (frames x time_budget_us) is capped; of the pooled
        # frames' worst case in flight, one client holds at most its share.
        self.max_request_work_s = settings.max_request_work_s
        self.frame_shares = CostShares(settings.max_client_work_s)
        # A planned clip takes 0.05-1 s (600 frames): they queue on a thread of their own
        # so that they never hold up the pool's frames, one-shot solves and chain builds.
        self.plan_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="ik-plan")
        # A queue of plans is a queue of seconds: beyond this many, say so at once
        # (503) rather than let clients time out waiting.
        self.max_queued_plans = settings.max_queued_plans
        # One client (an API key; a session when the server has no keys) holds at most
        # half the places, so that it cannot keep everyone else's plans out.
        self.max_plans_per_client = max(1, settings.max_queued_plans // 2)
        self.plans_in_flight = 0  # queued or running; changed on the loop only
        self.plans_by_client: dict[str, int] = {}  # the same, per client

    def shutdown(self) -> None:
        for pool in self.pools.values():
            pool.shutdown()
        self.plan_pool.shutdown(wait=False, cancel_futures=True)

    def check_ready(self) -> None:
        if not self.warmup.ready.is_set():
            raise not_ready()

    def inline(self, n_frames: int, options: IKOptions) -> bool:
        budget = options.time_budget_us
        return budget is not None and n_frames * budget <= self.inline_budget_us

    async def run(self, work: WorkClass, fn: Callable[..., T], *args: Any) -> T:
        """Run ``fn`` on the threads of its class of work (503 ``server_busy`` when the
        class is full)."""
        return await self.pools[work].run(fn, *args)

    def request_work_s(self, n_frames: int, options: IKOptions) -> float:
        """A request's worst case [s]: frames x the per-frame wall-clock budget.

        Raises:
            ServiceError: ``invalid_problem`` (field ``frames``) over IK_MAX_REQUEST_WORK_S.
        """
        budget_us = options.time_budget_us
        cost_s = math.inf if budget_us is None else n_frames * budget_us * 1e-6
        if cost_s > self.max_request_work_s:
            raise invalid_problem(
                f"{n_frames} frame(s) x time_budget_us {budget_us} is {cost_s:.3g} s of "
                f"solving at worst, over IK_MAX_REQUEST_WORK_S ({self.max_request_work_s:g} s):"
                " send fewer frames per request or a smaller time_budget_us",
                "frames",
            )
        return cost_s

    async def session_frames(
        self,
        session: Session,
        store: SessionStore,
        jobs: Sequence[FrameJob],
        t0: float,
        transport: str,
        client: str | None = None,
        may_inline: bool = True,
    ) -> list[SolvedFrame]:
        """Solve a session's frames in order, each warm-started from the previous answer.

        Frames of one session never overlap: the session's lock is held until the last
        frame is done, also when the caller goes away while a pooled solve runs. The
        caller renders the answers (``convert.render_frames``). ``client`` (an API key's
        fingerprint, else the peer's address) is who the pooled work is counted against.
        """
        client = client or session_client(session)
        out, _ = await self._under_lock(
            session, store, jobs, t0, transport, plan=False, client=client, may_inline=may_inline
        )
        return out

    async def session_plan(
        self,
        session: Session,
        store: SessionStore,
        jobs: Sequence[FrameJob],
        t0: float,
        transport: str,
    ) -> tuple[list[SolvedFrame], PlannedPath]:
        """Solve a session\'s clip as a whole (``solver.path.plan_path``): the solved frames
        and the plan. Always off the loop, on the planning thread: a plan takes milliseconds
        per frame. At most ``max_queued_plans`` at once (503 ``plans_busy``), and at
        most half of them (at least one) for one client (429 ``too_many_plans``): a
        plan counts from here until its thread is done, also if its caller went away."""
        client = session_client(session)
        held = self.plans_by_client.get(client, 0)
        if held >= self.max_plans_per_client:
            raise too_many_plans(self.max_plans_per_client)
        if self.plans_in_flight >= self.max_queued_plans:
            raise plans_busy(self.max_queued_plans)
        self.plans_in_flight += 1
        self.plans_by_client[client] = held + 1
        handed_over = False

        def on_submit(fut: asyncio.Future[Any]) -> None:
            nonlocal handed_over
            handed_over = True
            fut.add_done_callback(lambda _: self._plan_done(client))

        try:
            out, plan = await self._under_lock(
                session, store, jobs, t0, transport, plan=True, on_submit=on_submit
            )
        finally:
            if not handed_over:  # refused or failed before it reached the thread
                self._plan_done(client)
        assert plan is not None
        return out, plan

    def _plan_done(self, client: str) -> None:
        self.plans_in_flight -= 1
        held = self.plans_by_client[client] - 1
        if held:
            self.plans_by_client[client] = held
        else:
            del self.plans_by_client[client]

    async def _under_lock(
        self,
        session: Session,
        store: SessionStore,
        jobs: Sequence[FrameJob],
        t0: float,
        transport: str,
        *,
        plan: bool,
        on_submit: Callable[[asyncio.Future[Any]], None] | None = None,
        client: str = "",
        may_inline: bool = True,
    ) -> tuple[list[SolvedFrame], PlannedPath | None]:
        self.check_ready()
        wait_s = session.take_frames(
            len(jobs), now=store.clock(), rate_per_s=self.max_frames_per_s, burst=self.burst
        )
        if wait_s > 0:
            raise rate_limited(wait_s, self.max_frames_per_s)
        await session.lock.acquire()
        handoff = _LockHandoff()
        args = (session, jobs, t0, transport, plan, on_submit, client, may_inline, handoff)
        out: tuple[list[SolvedFrame], PlannedPath | None]
        try:
            if not store.commits_frames:  # sessions in this process: nothing to commit
                if session.closed:
                    raise not_found()
                options = session.options
                if not plan and may_inline and self.inline(len(jobs), options):
                    # _solve's inline case, without a coroutine of its own: a stream's
                    # usual frame (one coroutine and a nine-argument call less per frame).
                    out = _track_all(session, jobs, options, t0, self.metrics.frames, transport)
                else:
                    out = await self._solve(*args)
            else:
                solve = functools.partial(self._solve, *args)
                out = await _solve_and_commit(session, store, jobs, plan, solve)
        finally:
            if not handoff.handed_over:
                session.lock.release()
        store.touch(session)
        return out

    async def _solve(
        self,
        session: Session,
        jobs: Sequence[FrameJob],
        t0: float,
        transport: str,
        plan: bool,
        on_submit: Callable[[asyncio.Future[Any]], None] | None,
        client: str,
        may_inline: bool,
        handoff: _LockHandoff,
    ) -> tuple[list[SolvedFrame], PlannedPath | None]:
        """Solve under the session's lock: inline, on the frame threads, or planned.

        When the caller is cancelled while a thread solves, the lock goes to the thread:
        its end rewinds the session to where it stood (``Session.rewind``: the frames
        were answered to nobody) and releases it (``handoff.handed_over``; the caller
        must not)."""
        options = session.options
        metrics = self.metrics
        fut: asyncio.Future[tuple[list[SolvedFrame], PlannedPath | None]]
        if not plan and may_inline and self.inline(len(jobs), options):
            return _track_all(session, jobs, options, t0, metrics.frames, transport)
        before = session.mark()  # a solve on a thread: what a cancel puts back
        if plan:
            fut = asyncio.get_running_loop().run_in_executor(
                self.plan_pool, _plan_all, session, jobs, options, t0
            )
            # Counted on the loop (the metrics are the loop's) when the plan is done.
            fut.add_done_callback(functools.partial(_count_plan, metrics, transport))
            if on_submit is not None:
                on_submit(fut)
        else:
            loop = asyncio.get_running_loop()

            def record(batch: list[SolvedFrame], transport: str) -> None:
                # The metrics are the loop's: hand the batch over (one wake-up).
                with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                    loop.call_soon_threadsafe(metrics.frames, batch, transport)

            # Admitted before any state changes: a refusal leaves the lock free, and the
            # frames' place in the session's rate limit (nothing was solved).
            pool = self.pools[WorkClass.FRAMES]
            shares = self.frame_shares
            try:
                cost_s = self.request_work_s(len(jobs), options)
                pool.admit()
                shares.take(client, cost_s)
            except ServiceError:
                session.give_back_frames(len(jobs))
                raise
            fut = pool.submit(_track_all, session, jobs, options, t0, record, transport)
            fut.add_done_callback(lambda _: shares.give_back(client, cost_s))
        try:
            return await asyncio.shield(fut)
        except asyncio.CancelledError:
            if fut.done():
                session.rewind(before)
            else:
                fut.add_done_callback(lambda _: session.rewind(before))
                fut.add_done_callback(lambda _: session.lock.release())  # runs second
                handoff.handed_over = True
            raise


async def _solve_and_commit(
    session: Session,
    store: SessionStore,
    jobs: Sequence[FrameJob],
    plan: bool,
    solve: Callable[[], Awaitable[tuple[list[SolvedFrame], PlannedPath | None]]],
) -> tuple[list[SolvedFrame], PlannedPath | None]:
    """With a shared store (IK_REDIS_URL), under the session's lock: the stored answers
    of frames sent again, else ``solve`` and commit before answering; when another
    worker committed this session's frames first, the session is reloaded from the
    store and the frames are solved again from there."""
    for _ in range(STALE_RETRIES):
        if session.closed:
            raise not_found()
        stored = None if plan else store.stored_answer(session, jobs)
        if stored is not None:  # the same frames sent again: the same answers
            return stored, None
        out = await solve()
        try:
            await store.commit(session, jobs, out[0])
        except StaleSession:
            continue
        return out
    raise store_unavailable()


class _LockHandoff:
    """Whether a session's lock went to a solving thread (see ``Runner._solve``)."""

    __slots__ = ("handed_over",)

    def __init__(self) -> None:
        self.handed_over = False


def session_client(session: Session, peer: str | None = None) -> str:
    """Whom a session's work counts against: its API key, else the peer's address (many
    sessions from one address share one share), else the session itself."""
    if session.owner is not None:
        return session.owner
    return f"peer:{peer}" if peer else f"session:{session.id}"


def rate_limited(wait_s: float, rate: float) -> ServiceError:
    return ServiceError(
        ErrorCode.RATE_LIMITED,
        f"more than {rate:g} frames per second on this session (IK_MAX_FRAMES_PER_S)",
        status_code=status.HTTP_429_TOO_MANY_REQUESTS,
        retry_after_s=wait_s,
    )


def _track_all(
    session: Session,
    jobs: Sequence[FrameJob],
    options: IKOptions,
    t0: float,
    record: Callable[[list[SolvedFrame], str], None],
    transport: str,
) -> tuple[list[SolvedFrame], None]:
    """Runs under the session's lock (inline or in the pool); counts as it goes and
    hands the frames solved to ``record`` (metrics), also when a later frame fails."""
    out: list[SolvedFrame] = []
    solver = session.solver
    try:
        for frame_id, targets, pose in jobs:
            if pose is not None:  # the frame's animated pose: as PUT pose, then the frame
                session.start_at(pose)
            r = solver.track(targets, options=options)
            server_us = (time.perf_counter() - t0) * 1e6
            out.append(SolvedFrame(frame_id, r, server_us, solver.last_step))
            session.frames += 1
            session.solved += int(r.success)
    finally:
        record(out, transport)
    return out, None


def _plan_all(
    session: Session, jobs: Sequence[FrameJob], options: IKOptions, t0: float
) -> tuple[list[SolvedFrame], PlannedPath]:
    """``_track_all`` for a planned clip, on the planning thread: all frames or none (a
    rejected target fails the request and leaves the session's pose as it was)."""
    if session.closed:  # deleted while the plan waited for the planning thread
        raise not_found()
    start = session.solver.q.copy()
    plan = plan_path(session.solver, [targets for _, targets, _ in jobs], options=options)
    server_us = (time.perf_counter() - t0) * 1e6
    steps = plan_steps(start, [r.q for r in plan.results], options.max_joint_step_rad)
    out = [
        SolvedFrame(frame_id, r, server_us, step)
        for (frame_id, _, _), r, step in zip(jobs, plan.results, steps, strict=True)
    ]
    session.frames += len(plan.results)
    session.solved += sum(r.success for r in plan.results)
    return out, plan


def _count_plan(
    metrics: Metrics,
    transport: str,
    done: asyncio.Future[tuple[list[SolvedFrame], PlannedPath | None]],
) -> None:
    """A finished plan's frames in the metrics (a done callback: on the loop)."""
    if not done.cancelled() and done.exception() is None:
        metrics.frames(done.result()[0], transport)


def make_solver(view: ChainView, options: IKOptions) -> IKSolver:
    """A session's solver (runs in the pool: it allocates per-chain arrays)."""
    return IKSolver(view.chain, options)


def solve_once(
    view: ChainView,
    targets: list[SolverTarget],
    seed: np.ndarray | None,
    options: IKOptions,
    frame_id: int | None,
    t0: float,
) -> SolvedFrame:
    """A stateless one-shot solve (runs in the pool)."""
    r = IKSolver(view.chain, options).solve(targets, seed, options=options)
    return SolvedFrame(frame_id, r, (time.perf_counter() - t0) * 1e6)
