"""Load (or compile) the numba core before the first real frame.

A fresh checkout compiles the core once (minutes on these machines) and writes it to
the ``__pycache__`` folders under solver/, or to ``NUMBA_CACHE_DIR`` when set
(``cache_location``); later processes load it in about a second. The warm-up is a
list of named steps (``STEPS``), each a small solve that reaches one group of compiled
functions; ``warmup()`` runs them in order (or a chosen subset, so that a caller may
compile disjoint groups in separate processes) and reports after each one.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
from numba.core import config, event

from .ik import Continuity, IKData, IKOptions, IKSolver, Target, pose_targets
from .ik.continuity import largest_step
from .model import EffectorMode
from .model.examples import bolt, panda_arm
from .path import plan_path
from .path.kernels import dp_step, frame_nodes, project_onto


@dataclass(frozen=True, slots=True)
class WarmupStep:
    name: str
    run: Callable[[], None]


@dataclass(frozen=True, slots=True)
class WarmupProgress:
    """Where a warm-up stands, sent once before the first step and after every step."""

    done: int  # steps finished
    total: int  # steps in this warm-up
    step: str | None  # the step just finished (None before the first)
    elapsed_s: float
    compiled: int  # functions numba compiled so far (0: everything came from the cache)


def _solve_and_track(mode: EffectorMode) -> None:
    chain = panda_arm(mode)
    solver = IKSolver(chain, IKOptions(time_budget_us=None, max_iter=50))
    q = chain.mid_limits() + 0.1
    solver.solve(pose_targets(chain, q))
    solver.track(pose_targets(chain, q + 0.01))
    # The SMOOTH policy's bounds (ik/continuity.py).
    smooth = IKOptions(time_budget_us=None, max_iter=50, continuity=Continuity.SMOOTH)
    solver.track(pose_targets(chain, q + 0.02), options=smooth)


def _plan() -> None:
    # The planner (solver/path/) end to end: a two-frame clip of a 7-DOF pose task.
    solver, targets, q = _planning_arm()
    solver.set_pose(q)
    plan_path(solver, [targets, pose_targets(solver.chain, q + 0.01)])


# The planner's kernels, each called as ``plan`` calls it (the same argument types, so
# the same compiled code): two thirds of the whole compile, and independent of the IK
# core and of each other, so that separate processes may compile them side by side.


def _plan_nodes() -> None:
    solver, targets, q = _planning_arm()
    data, box = _loaded(solver, targets, q)
    anchors = np.ascontiguousarray([q], dtype=np.float64)
    frame_nodes(anchors, data, box, True, 0.05, 4)


def _plan_projection() -> None:
    solver, targets, q = _planning_arm()
    data, box = _loaded(solver, targets, q)
    project_onto(q.copy(), data, box, 30)
    nodes = np.ascontiguousarray([q, q + 0.01], dtype=np.float64)
    dp_step(nodes[:1] * 1.0, np.zeros(1), np.zeros(1), nodes * 1.0, 0.5)


def _planning_arm() -> tuple[IKSolver, list[Target], np.ndarray]:
    chain = panda_arm()
    q = chain.mid_limits() + 0.1
    solver = IKSolver(chain, IKOptions(time_budget_us=None, max_iter=50))
    return solver, pose_targets(chain, q), q


def _loaded(
    solver: IKSolver, targets: list[Target], q: np.ndarray
) -> tuple[IKData, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Load ``targets`` as the planner does (``IKSolver.load_frame``): the compiled data
    and the planner's box."""
    data = solver.load_frame(targets, q)
    return data, (solver.chain.lower, solver.chain.upper, solver.free_mask())


def _no_variables() -> None:
    # A chain with no variables takes its own compiled path (errors only).
    IKSolver(bolt()).solve([Target(effector="tip", position=np.array([0.0, 0.0, 1.0]))])


STEPS: tuple[WarmupStep, ...] = (
    WarmupStep("pose", lambda: _solve_and_track(EffectorMode.POSE)),
    WarmupStep("position", lambda: _solve_and_track(EffectorMode.POSITION)),
    WarmupStep("aim", lambda: _solve_and_track(EffectorMode.AIM)),
    WarmupStep("no_variables", _no_variables),
    WarmupStep("plan_projection", _plan_projection),
    WarmupStep("plan_nodes", _plan_nodes),
    WarmupStep("plan", _plan),
)
STEP_NAMES: tuple[str, ...] = tuple(step.name for step in STEPS)


class NotCached(Exception):
    """``warmup(load_only=True)`` met a function that is not in the on-disk cache."""

    def __init__(self, step: str) -> None:
        super().__init__(f"warm-up step {step!r} needs a compile: not in the on-disk cache")
        self.step = step


class _Compiles(event.Listener):
    """Counts numba's compilations (a load from the on-disk cache is not one) and
    calls ``on_compiled`` after each; with ``refuse`` set, refuses them instead
    (raises ``NotCached`` before numba starts: nothing is compiled or changed)."""

    def __init__(self, on_compiled: Callable[[], None], *, refuse: bool) -> None:
        self.count = 0
        self.step = ""
        self._on_compiled = on_compiled
        self._refuse = refuse

    def on_start(self, ev: event.Event) -> None:
        if self._refuse:
            raise NotCached(self.step)

    def on_end(self, ev: event.Event) -> None:
        self.count += 1
        self._on_compiled()


def cache_location() -> str:
    """Where the compiled solver is cached, as numba resolved it for one of the solver's
    compiled functions: ``NUMBA_CACHE_DIR`` when numba uses it, else the ``__pycache__``
    folders of solver/ and its subpackages, else the folder numba fell back to (its
    user-wide cache: numba passes over a folder it cannot write to)."""
    # numba resolves a function's cache folder once, when it is decorated (through
    # solver/_jit.py's locators, which this module, outside the cache stamp, does not
    # import); _cache._cache_path is where it will read and write.
    used = Path(cast(Any, largest_step)._cache._cache_path)
    user_dir = getattr(config, "CACHE_DIR", "")  # numba reads it from the environment
    if user_dir and used.is_relative_to(Path(user_dir)):
        return str(user_dir)
    solver_dir = Path(__file__).resolve().parent
    if used.is_relative_to(solver_dir):
        return f"{solver_dir}/**/__pycache__"
    return str(used)


def warmup(
    progress: Callable[[WarmupProgress], None] | None = None,
    *,
    steps: Sequence[str] | None = None,
    load_only: bool = False,
) -> float:
    """Run the warm-up's steps (all of ``STEPS``, or the named ones, in ``STEPS``'s
    order); returns the seconds it took.

    ``progress`` is called on this thread before the first step, after each function
    numba compiles (``compiled`` grows; inside numba's compiler lock: keep it short)
    and after each step. With ``load_only``, a step that would compile anything raises
    ``NotCached`` instead (the steps before it are loaded).
    """
    chosen = STEPS if steps is None else _select(steps)
    start = time.perf_counter()
    done = 0
    last: str | None = None

    def report() -> None:
        if progress is not None:
            elapsed = time.perf_counter() - start
            progress(WarmupProgress(done, len(chosen), last, elapsed, compiles.count))

    compiles = _Compiles(report, refuse=load_only)
    with event.install_listener("numba:compile", compiles):
        report()
        for step in chosen:
            compiles.step = step.name
            step.run()
            done, last = done + 1, step.name
            report()
    return time.perf_counter() - start


def _select(names: Sequence[str]) -> tuple[WarmupStep, ...]:
    unknown = set(names) - set(STEP_NAMES)
    if unknown:
        raise ValueError(f"unknown warm-up steps {sorted(unknown)}; known: {list(STEP_NAMES)}")
    return tuple(step for step in STEPS if step.name in names)
