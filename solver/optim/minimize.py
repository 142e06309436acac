"""Public entry point of the optimizer: ``minimize`` over a box with the multi-pass BFGS.

The loop itself lives in ``loop`` (compiled); this module validates input, packs
options into the core's vectors and turns its integers back into typed results.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt
from numba.core.registry import CPUDispatcher

from ..arrays import Matrix, Vector
from ..errors import DimensionMismatch, InvalidProblem
from . import codes as C
from .analyzer import AnalyzerPolicy
from .loop import run_solver
from .objective import registered_for
from .options import GradientMode, MinimizeOptions
from .result import AcceptedStep, MinimizeResult, PassRecord

_GRAD_MODES = {
    GradientMode.ANALYTIC: C.GRAD_ANALYTIC,
    GradientMode.FORWARD: C.GRAD_FORWARD,
    GradientMode.CENTRAL: C.GRAD_CENTRAL,
}


def pack_options(
    options: MinimizeOptions, *, seed: int
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int64]]:
    """The core's option vectors (layout in ``codes``)."""
    fopt = np.empty(C.N_FOPT)
    fopt[C.F_GTOL] = options.gtol
    fopt[C.F_XTOL] = options.xtol
    fopt[C.F_FTOL] = options.ftol
    fopt[C.F_F_GOAL] = -math.inf if options.f_goal is None else options.f_goal
    fopt[C.F_MAX_STEP] = options.max_step
    fopt[C.F_C1] = options.armijo_c1
    fopt[C.F_C2] = options.curvature_c2
    fopt[C.F_STEPTOL] = options.line_search_min_step
    budget = options.time_budget_s
    fopt[C.F_BUDGET] = math.inf if budget is None else budget
    fopt[C.F_RESTART_RADIUS] = options.restart_radius
    fopt[C.F_CURVATURE_EPS] = options.skip_update_eps
    iopt = np.empty(C.N_IOPT, dtype=np.int64)
    iopt[C.I_MAX_ITER] = options.max_iter
    iopt[C.I_MAX_FEV] = options.max_fev
    iopt[C.I_STALL_WINDOW] = options.stall_window
    iopt[C.I_GRAD_MODE] = _GRAD_MODES[options.gradient]
    iopt[C.I_CURVATURE] = int(options.curvature)
    iopt[C.I_MAX_RESTARTS] = options.max_restarts
    iopt[C.I_SEED] = seed
    iopt[C.I_HAS_GOAL] = int(options.f_goal is not None)
    iopt[C.I_SCALE_H0] = int(options.scale_initial_h)
    iopt[C.I_MAX_PASSES] = options.max_passes
    iopt[C.I_METRIC_EVERY] = options.metric_every
    iopt[C.I_METRIC_UNTIL] = options.metric_until
    iopt[C.I_FINAL_METRIC] = int(options.final_metric)
    iopt[C.I_FULL_RESTART_EVERY] = options.full_restart_every
    iopt[C.I_TURN_RESTARTS] = int(options.turn_restarts)
    return fopt, iopt


def unpack_pass_log(log: npt.NDArray[np.float64], count: int) -> tuple[PassRecord, ...]:
    """Typed records from the first ``count`` rows the core filled."""
    rows = log[: min(count, log.shape[0])]
    return tuple(
        PassRecord(
            start=C.PASS_STARTS[int(r[C.L_START])],
            iterations=int(r[C.L_ITERS]),
            termination=C.TERMINATIONS[int(r[C.L_CODE])],
            f_start=float(r[C.L_F_START]),
            f_end=float(r[C.L_F_END]),
            goal=C.GOAL_STATUSES[int(r[C.L_GOAL])],
            action=C.ACTIONS[int(r[C.L_ACTION])],
            function_evals=int(r[C.L_NFEV]),
        )
        for r in rows
    )


def check_bounds(
    n: int, bounds: tuple[npt.ArrayLike, npt.ArrayLike] | None
) -> tuple[Vector, Vector]:
    """Validated (lower, upper) arrays of shape (n,); None means unbounded."""
    if bounds is None:
        return np.full(n, -math.inf), np.full(n, math.inf)
    lo = np.array(bounds[0], dtype=np.float64).reshape(-1)
    hi = np.array(bounds[1], dtype=np.float64).reshape(-1)
    if lo.shape != (n,) or hi.shape != (n,):
        raise DimensionMismatch(f"bounds must have shape ({n},), got {lo.shape} and {hi.shape}")
    if np.isnan(lo).any() or np.isnan(hi).any():
        raise InvalidProblem("bounds must not contain NaN")
    bad = np.flatnonzero(lo > hi)
    if bad.size:
        i = int(bad[0])
        raise InvalidProblem(f"lower > upper at index {i}: {lo[i]!r} > {hi[i]!r}")
    return lo, hi


def minimize(
    objective: Any,
    x0: npt.ArrayLike,
    *,
    bounds: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
    options: MinimizeOptions | None = None,
    policy: AnalyzerPolicy | None = None,
    data: tuple[Any, ...] = (),
    initial_inverse_hessian: Matrix | None = None,
    rng: np.random.Generator | None = None,
    record_steps: bool = False,
) -> MinimizeResult:
    """Minimize f over the box [lower, upper] with multi-pass BFGS under the analyzer.

    Args:
        objective: A numba-compiled (``@njit``) function ``fg(x, g, need_grad, data) -> f``
            that fills ``g`` (shape (n,)) with the gradient when ``need_grad`` is true
            and the gradient mode is analytic. With finite differences ``g`` is unused.
        x0: Start, shape (n,); projected into the box.
        bounds: (lower, upper), each shape (n,), +-inf allowed; None for no bounds.
        options: Optimizer settings; defaults to ``MinimizeOptions()``.
        policy: Analyzer table; defaults to ``AnalyzerPolicy.default()``.
        data: Extra argument passed to ``objective`` unchanged (arrays, tuples).
        initial_inverse_hessian: Initial H, shape (n, n), symmetric positive
            definite (for example the last solve's ``inverse_hessian``); default I.
        rng: Source of the random-restart seed; None uses a fixed seed (reproducible).
        record_steps: Record every accepted step (for tests of the line search).

    Returns:
        The best point found and how the solve ended; never raises for a solve that
        merely fails to converge.

    Raises:
        InvalidProblem: Non-finite x0, inconsistent bounds, bad H, uncompiled objective.
        DimensionMismatch: Shapes that do not match x0.
    """
    options = options or MinimizeOptions()
    policy = policy or AnalyzerPolicy.default()
    x = np.array(x0, dtype=np.float64).reshape(-1)
    n = x.shape[0]
    if n == 0:
        raise InvalidProblem("x0 must have at least one component")
    if not np.isfinite(x).all():
        raise InvalidProblem("x0 must be finite")
    lo, hi = check_bounds(n, bounds)
    if not isinstance(objective, CPUDispatcher) and not _jit_disabled():
        raise InvalidProblem(
            "objective must be a numba @njit function fg(x, g, need_grad, data) -> float"
        )
    h = _initial_h(n, initial_inverse_hessian)
    seed = 0 if rng is None else int(rng.integers(0, 2**31 - 1))
    fopt, iopt = pack_options(options, seed=seed)
    log = np.zeros((options.max_passes, C.N_LOG))
    out_x = np.empty(n)
    out_g = np.empty(n)
    trace = np.zeros((options.max_iter if record_steps else 0, 5))
    # A registered objective is bound at compile time (cached); others are passed in.
    fg = None if registered_for(objective) else objective
    core = run_solver(
        fg, data, x, h, lo, hi, fopt, iopt, policy.as_array(), log, trace, out_x, out_g
    )
    pass_log = unpack_pass_log(log, core.passes)
    return MinimizeResult(
        x=out_x,
        f=float(core.f),
        projected_gradient_norm=float(core.projected_gradient_norm),
        termination=C.TERMINATIONS[int(core.code)],
        goal=pass_log[-1].goal,
        iterations=int(core.iterations),
        function_evals=int(core.function_evals),
        gradient_evals=int(core.gradient_evals),
        passes=int(core.passes),
        restarts=int(core.restarts),
        skipped_updates=int(core.skipped_updates),
        pass_log=pass_log,
        elapsed_us=float(core.elapsed_s) * 1e6,
        inverse_hessian=h,
        steps=tuple(
            AcceptedStep(*(float(v) for v in row)) for row in trace[: int(core.iterations)]
        ),
    )


def _initial_h(n: int, h0: Matrix | None) -> Matrix:
    if h0 is None:
        return np.eye(n)
    h = np.array(h0, dtype=np.float64)
    if h.shape != (n, n):
        raise DimensionMismatch(
            f"initial_inverse_hessian must have shape ({n}, {n}), got {h.shape}"
        )
    if not np.isfinite(h).all() or not np.allclose(h, h.T, rtol=1e-10, atol=1e-12):
        raise InvalidProblem("initial_inverse_hessian must be finite and symmetric")
    try:
        np.linalg.cholesky(h)
    except np.linalg.LinAlgError:
        raise InvalidProblem("initial_inverse_hessian must be positive definite") from None
    return h


def _jit_disabled() -> bool:
    from numba.core import config

    return bool(getattr(config, "DISABLE_JIT", False))
