"""The compiled core: multi-pass projected BFGS under the analyzer, the whole solve in
one call.

A solve is a sequence of passes. A pass iterates the stopping tests / the step
(direction, step cap, ``line_search``) / the H update (BFGS, or the objective's own
metric) until a test fires; then ``analyzer.decide`` turns the pass's termination code
into the next action (accept, reset H, random restart, stop) and the pass is logged.
The small helpers are inlined into ``solve_passes`` (numba IR inlining).

The stopping tests and the step stay written out in the loop, not in helpers: as
inlined helpers (a ``check_termination`` returning a code from six exits, a
``search_step`` taking a tuple of six work rows and returning four values) they made
LLVM allocate the loop's registers differently (more stack traffic in
``run_solver_leaf``, the only function whose machine code differed from the commit
before the layers; objective, kinematics and metric were byte for byte the same),
and a tracking frame (~2.5 us) took ~3-4% longer in ``bench.ab_core``.

Everything here runs inside numba (one implementation; with ``NUMBA_DISABLE_JIT=1``
the same code runs as plain Python for debugging and coverage). The objective is a
compiled function ``fg(x, g, need_grad, data) -> f``, either passed as an argument
or registered for the type of ``data`` (see ``objective``: only the registered
route keeps the IK core in numba's on-disk cache).

References:
    Dennis & Schnabel (1996), Numerical Methods for Unconstrained Optimization and
    Nonlinear Equations, SIAM: A6.3.1 (backtracking), A6.3.1mod (with the
    curvature condition), A9.4.2 (BFGS inverse update).
    Nocedal & Wright (2006), Numerical Optimization, 2nd ed.: eq. 6.17 (inverse
    BFGS update), eq. 6.20 (initial scaling), section 16.7 (projected methods).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from .._clock import now_s
from .._jit import jit, jit_inline, jit_leaf
from . import codes as C
from .analyzer import decide
from .bfgs import (
    bfgs_update,
    descent_direction,
    factor_direction,
    is_identity,
    metric_due,
    scale_initial_h,
    set_identity,
    step_vectors,
)
from .cholesky import inverse_from_cholesky
from .evaluate import all_finite, evaluate, project, projected_gradient_norm
from .line_search import line_search
from .objective import call_goal, call_metric, call_restart_keep, call_restart_period
from .restart import keep_values, random_point, turn_values

# What the core returns (a named tuple: numba builds and returns it like any tuple).
CoreResult = namedtuple(
    "CoreResult",
    [
        "f",  # f at the best point
        "goal_measure",  # the goal measure there (f itself without a registered goal)
        "projected_gradient_norm",
        "code",  # the last pass's termination (codes.* int)
        "iterations",
        "function_evals",
        "gradient_evals",
        "passes",
        "restarts",
        "skipped_updates",
        "elapsed_s",
    ],
)

# Rows of the work block the core's vectors live in (x, g, trial point and gradient,
# direction, s, y, ...; the last two: the curvature search's kept point).
WORK_ROWS = 12


@jit
def run_solver(  # type: ignore[no-untyped-def]
    fg, data, x0, h, lo, hi, fopt, iopt, policy, log, trace, out_x, out_g
):
    """The core for any objective (``minimize``: user objectives, MGH); see
    ``solve_passes``. Allocates its work arrays, so the objective may allocate too."""
    vectors = np.empty((WORK_ROWS, x0.shape[0]))
    ints = np.empty(3, dtype=np.int64)
    return solve_passes(
        fg, data, x0, h, lo, hi, fopt, iopt, policy, log, trace, out_x, out_g, vectors, ints
    )


@jit_leaf
def run_solver_leaf(  # type: ignore[no-untyped-def]
    fg, data, x0, h, lo, hi, fopt, iopt, policy, log, trace, out_x, out_g, vectors, ints
):
    """The same core compiled without reference counting (``jit_leaf``), for the IK
    objective, which allocates nothing: ~2.4x faster per iteration, same iterates.
    ``vectors`` is float64[WORK_ROWS, n] and ``ints`` int64[3], both the caller's."""
    return solve_passes(
        fg, data, x0, h, lo, hi, fopt, iopt, policy, log, trace, out_x, out_g, vectors, ints
    )


@jit_inline
def record_step(trace, row, f, f_trial, lam, g, x, x_new, lo, hi):  # type: ignore[no-untyped-def]
    """Row ``row`` of the step trace (``minimize(record_steps=True)``), while rows last."""
    if row >= trace.shape[0]:
        return
    slack = math.inf
    dec = 0.0
    for i in range(x.shape[0]):
        dec += g[i] * (x_new[i] - x[i])
        slack = min(slack, x_new[i] - lo[i], hi[i] - x_new[i])
    trace[row, 0] = f
    trace[row, 1] = f_trial
    trace[row, 2] = dec
    trace[row, 3] = lam
    trace[row, 4] = slack


@jit_inline
def better(f, m, f_best, m_best, has_goal, f_goal):  # type: ignore[no-untyped-def]
    """Order of points: meeting the goal first, then lower f."""
    if has_goal:
        met = m <= f_goal
        met_best = m_best <= f_goal
        if met != met_best:
            return met
    return f < f_best


@jit_inline
def copy_point(x, g, out_x, out_g):  # type: ignore[no-untyped-def]
    for i in range(x.shape[0]):
        out_x[i] = x[i]
        out_g[i] = g[i]


@jit_inline
def pass_goal(code, has_goal, m_best, f_goal):  # type: ignore[no-untyped-def]
    """The goal status a pass ended with (NO_GOAL, MET or MISSED). NONFINITE can only
    come from the current point, so the best point decides."""
    if code == C.GOAL_REACHED or (has_goal and m_best <= f_goal):
        return C.MET
    if has_goal:
        return C.MISSED
    return C.NO_GOAL


@jit_inline
def log_pass(log, row, start_kind, iterations, code, f_start, f_end, goal, action, nfev):  # type: ignore[no-untyped-def]
    """Row ``row`` of the pass log (columns ``codes.L_*``), while rows last."""
    if row >= log.shape[0]:
        return
    entry = log[row]
    entry[C.L_START] = start_kind
    entry[C.L_ITERS] = iterations
    entry[C.L_CODE] = code
    entry[C.L_F_START] = f_start
    entry[C.L_F_END] = f_end
    entry[C.L_GOAL] = goal
    entry[C.L_ACTION] = action
    entry[C.L_NFEV] = nfev


@jit_inline
def solve_passes(  # type: ignore[no-untyped-def]
    fg, data, x0, h, lo, hi, fopt, iopt, policy, log, trace, out_x, out_g, vectors, ints
):
    """Multi-pass projected BFGS under the analyzer; the whole solve in one call.

    Args:
        fg: Compiled objective ``fg(x, g, need_grad, data) -> f``, or None to use
            the objective registered for the type of ``data`` (``objective``). With
            fg None the goal measure registered with the objective, m(f, x, data),
            decides "goal met" (m <= f_goal); else f does. The IK registers its
            normalised pose error, so "goal met" means "IK succeeded" even when f
            carries posture terms.
        data: Passed through to ``fg`` untouched.
        x0: Start, shape (n,); projected into the box here.
        h: Inverse-Hessian approximation, shape (n, n): the initial H on entry
            (identity or the caller's), the final H on return.
        lo, hi: Bounds, shape (n,) each; +-inf allowed; lo <= hi checked by the
            caller.
        fopt, iopt, policy: The option vectors laid out as in ``codes`` (F_*, I_*;
            iopt[I_SEED] is written on return: the restart generator's state, as a
            seed) and the analyzer table int64[n_codes, 3].
        log, trace: The pass log float64[max_passes, N_LOG], filled row by row, and
            float64[rows, 5]: for each accepted step (while rows last) f before, f
            after, g.(x+ - x), lambda, and the smallest distance of x+ to a bound
            (negative would mean it left the box). Shape (0, 5) records nothing.
        out_x, out_g: Receive the best x and its gradient.
        vectors, ints: Work blocks float64[WORK_ROWS, n] and int64[3] (contents
            ignored): the caller's, so that this body allocates nothing.

    Returns:
        A ``CoreResult``.
    """
    t_start = now_s()
    max_iter = iopt[C.I_MAX_ITER]
    max_fev = iopt[C.I_MAX_FEV]
    stall_window = iopt[C.I_STALL_WINDOW]
    grad_mode = iopt[C.I_GRAD_MODE]
    max_restarts = iopt[C.I_MAX_RESTARTS]
    has_goal = iopt[C.I_HAS_GOAL] != 0
    scale_h0 = iopt[C.I_SCALE_H0] != 0
    max_passes = min(iopt[C.I_MAX_PASSES], log.shape[0])
    metric_every = iopt[C.I_METRIC_EVERY]
    metric_until = iopt[C.I_METRIC_UNTIL]
    final_metric = iopt[C.I_FINAL_METRIC] != 0
    full_restart_every = iopt[C.I_FULL_RESTART_EVERY]
    turn_restarts = iopt[C.I_TURN_RESTARTS] != 0
    gtol = fopt[C.F_GTOL]
    max_step = fopt[C.F_MAX_STEP]
    xtol = fopt[C.F_XTOL]
    ftol = fopt[C.F_FTOL]
    f_goal = fopt[C.F_F_GOAL]
    # The clock starts inside the compiled code, so a first call that compiles (or
    # loads the cache) does not eat the caller's budget.
    deadline = t_start + fopt[C.F_BUDGET]
    eps_curv = fopt[C.F_CURVATURE_EPS]
    # One block for the work vectors and one for the integer state, from the caller:
    # an allocation costs about as much as a solver iteration's bookkeeping, and the
    # reference-count-free build (run_solver_leaf) cannot allocate at all.
    ints[0] = 0
    ints[1] = 0
    counters = ints[0:2]  # nfev, ngev
    rng_state = ints[2:3]
    rng_state[0] = iopt[C.I_SEED] % 2147483646 + 1
    x = vectors[0]
    g = vectors[1]
    x_new = vectors[2]
    g_new = vectors[3]
    s = vectors[6]
    y = vectors[7]
    hy = vectors[8]
    scratch = vectors[9]
    d = vectors[4]  # the search direction
    gm = vectors[5]  # the gradient with held variables zeroed
    keep = vectors[10:12]  # the curvature phase's kept point and gradient
    n = x0.shape[0]

    project(x0, lo, hi, x)
    f = evaluate(fg, data, x, g, True, grad_mode, lo, hi, scratch, counters)
    f_best = f
    m = call_goal(fg, f, x, data) if has_goal else f
    m_best = m
    copy_point(x, g, out_x, out_g)

    nit = 0
    n_passes = 0
    n_restarts = 0
    n_skipped = 0
    final_code = C.NONFINITE
    start_kind = C.START_INITIAL
    h_is_identity = is_identity(h)
    f_turned = math.nan  # f_best when a turn restart was last tried (NaN: never)
    # "Fresh": H = I or the objective's own metric, i.e. no curvature learnt yet
    # (a caller's H carried from a previous solve is not fresh).
    h_fresh = h_is_identity
    # H may hold the Cholesky factor of its inverse instead (a metric's METRIC_FACTOR):
    # the direction solves with it, and H itself is completed only where it is read
    # (a BFGS update, the H handed back).
    h_factored = False
    if h_is_identity:
        kind = call_metric(fg, x, g, lo, hi, data, h)
        if kind != C.METRIC_NONE:
            h_is_identity = False
            h_factored = kind == C.METRIC_FACTOR

    while True:
        # ---- one pass -------------------------------------------------------
        pass_iters = 0
        f_pass_start = f
        nfev_pass_start = counters[0]
        began_fresh = h_fresh
        stall_count = 0
        code = C.RUNNING
        while code == C.RUNNING:
            # The stopping tests. Order matters: a non-finite point is never judged
            # further, and a met goal wins over the budgets.
            if not (math.isfinite(f) and all_finite(g)):
                code = C.NONFINITE
                break
            if has_goal and m <= f_goal:
                code = C.GOAL_REACHED
                break
            if projected_gradient_norm(x, g, lo, hi) <= gtol:
                code = C.GTOL
                break
            if nit >= max_iter:
                code = C.MAX_ITER
                break
            if counters[0] >= max_fev:
                code = C.MAX_FEV
                break
            if now_s() >= deadline:
                code = C.DEADLINE
                break
            # The step: the projected descent direction, capped, and the line search.
            if h_factored:
                slope = factor_direction(h, g, x, lo, hi, d, gm)
            else:
                slope = descent_direction(h, g, x, lo, hi, d, gm)
            if not (slope < 0.0):
                # H lost positive definiteness numerically: fall back to steepest descent.
                set_identity(h)
                h_is_identity = True
                h_factored = False
                slope = descent_direction(h, g, x, lo, hi, d, gm)
            big = 0.0
            for i in range(n):
                if abs(d[i]) > big:
                    big = abs(d[i])
            if big > max_step:
                # Step cap (inf-norm: per variable, e.g. radians per joint).
                scale = max_step / big
                for i in range(n):
                    d[i] *= scale
            status, f_trial, lam = line_search(
                fg, data, x, f, g, d, lo, hi, fopt, iopt, x_new, g_new, scratch, counters, keep
            )
            if status == C.LS_BUDGET_SPENT:
                code = C.MAX_FEV
                break
            if status != C.LS_ACCEPTED:
                code = C.LINE_SEARCH_FAILED
                break
            if grad_mode != C.GRAD_ANALYTIC and iopt[C.I_CURVATURE] == 0:
                # The search evaluated f only (finite differences without the
                # curvature phase): x+ needs its gradient.
                f_trial = evaluate(
                    fg, data, x_new, g_new, True, grad_mode, lo, hi, scratch, counters
                )
            record_step(trace, nit, f, f_trial, lam, g, x, x_new, lo, hi)
            nit += 1
            pass_iters += 1
            step_rel = step_vectors(x, x_new, g, g_new, s, y)
            if pass_iters == 1 and scale_h0 and h_is_identity:
                scale_initial_h(h, s, y)
            # The goal at the new point first: it decides whether a metric is due.
            m_new = call_goal(fg, f_trial, x_new, data) if has_goal else f_trial
            goal_met = has_goal and m_new <= f_goal
            kind = C.METRIC_NONE
            if metric_due(metric_every, metric_until, final_metric, pass_iters, goal_met):
                kind = call_metric(fg, x_new, g_new, lo, hi, data, h)
            if kind != C.METRIC_NONE:
                # Re-seed H from the objective's metric (every step: damped Gauss-Newton).
                h_is_identity = False
                h_factored = kind == C.METRIC_FACTOR
            else:
                if h_factored:
                    inverse_from_cholesky(h)
                    h_factored = False
                if bfgs_update(h, s, y, hy, eps_curv):
                    h_is_identity = False
                    h_fresh = False
                else:
                    n_skipped += 1
            improvement = f - f_trial
            f = f_trial
            copy_point(x_new, g_new, x, g)
            m = m_new
            if better(f, m, f_best, m_best, has_goal, f_goal):
                f_best = f
                m_best = m
                copy_point(x, g, out_x, out_g)
            if step_rel <= xtol:
                code = C.STEP_SMALL
                break
            if stall_window > 0:
                if improvement <= ftol * max(abs(f), 1e-300):
                    stall_count += 1
                    if stall_count >= stall_window:
                        code = C.STALLED
                        break
                else:
                    stall_count = 0
        # ---- the analyzer ---------------------------------------------------
        goal = pass_goal(code, has_goal, m_best, f_goal)
        budget_left = nit < max_iter and counters[0] < max_fev and now_s() < deadline
        action = decide(
            policy,
            code,
            goal,
            max_restarts - n_restarts,
            budget_left and n_passes + 1 < max_passes,
            began_fresh,
            f < f_pass_start,
            start_kind == C.START_RESET_H,
            # A reset rebuilds this pass's H only where the metric re-seeded it at every
            # iteration (no BFGS update came between) and would go on doing so: no
            # metric_until phase that a reset would begin again.
            h_fresh and metric_every == 1 and metric_until == 0,
        )
        log_pass(
            log,
            n_passes,
            start_kind,
            pass_iters,
            code,
            f_pass_start,
            f,
            goal,
            action,
            counters[0] - nfev_pass_start,
        )
        n_passes += 1
        final_code = code
        if action == C.ACCEPT or action == C.STOP:
            break
        if action == C.RESET_H:
            # Continue from where the pass ended (its best point: f never rises in a pass).
            start_kind = C.START_RESET_H
        else:  # RESTART_RANDOM
            start_kind = C.START_RESTART
            n_restarts += 1
            random_point(x0, lo, hi, fopt[C.F_RESTART_RADIUS], rng_state, x)
            turned = 0
            if turn_restarts and f_best != f_turned:
                # A turn restart (``restart``), once per best point: from the best
                # point, the unsettled periodic variables that a bound stops turned
                # the other way round. hy is free between passes: the periods.
                f_turned = f_best
                if call_restart_period(fg, data, hy) > 0:
                    if call_restart_keep(fg, out_x, data, scratch) == 0:
                        for i in range(n):
                            scratch[i] = 0.0
                    turned = turn_values(
                        out_x, out_g, hy, scratch, lo, hi, x0, fopt[C.F_RESTART_RADIUS], x
                    )
                    if turned > 0:
                        start_kind = C.START_RESTART_TURN
            if turned == 0 and (
                full_restart_every != 1
                and (full_restart_every == 0 or n_restarts % full_restart_every != 0)
            ):
                # A partial restart (``restart``): the variables the objective calls
                # settled at the best point keep their values there; odd ones keep
                # every variable with a settled share, even ones only wholly settled.
                # Where that would keep every free variable (or none), the odd one
                # falls back to the wholly settled, then to the whole-box draw.
                if call_restart_keep(fg, out_x, data, scratch) > 0:
                    whole = n_restarts % 2 == 0
                    kept = keep_values(scratch, out_x, x, whole, lo, hi)
                    if kept == 0 and not whole:
                        kept = keep_values(scratch, out_x, x, True, lo, hi)
                    if kept > 0:
                        start_kind = C.START_RESTART_PARTIAL
            f = evaluate(fg, data, x, g, True, grad_mode, lo, hi, scratch, counters)
            if has_goal:
                m = call_goal(fg, f, x, data)
            if better(f, m, f_best, m_best, has_goal, f_goal):
                f_best = f
                m_best = m
                copy_point(x, g, out_x, out_g)
        h_fresh = True
        kind = call_metric(fg, x, g, lo, hi, data, h)
        if kind != C.METRIC_NONE:
            h_is_identity = False
            h_factored = kind == C.METRIC_FACTOR
        else:
            set_identity(h)
            h_is_identity = True
            h_factored = False

    if h_factored:  # the caller reads H itself
        inverse_from_cholesky(h)

    pg = projected_gradient_norm(out_x, out_g, lo, hi)
    elapsed = now_s() - t_start
    # Hand the generator's state back: a caller that keeps iopt (IKSolver does, per
    # options) continues the same stream on its next call with no new seed to draw.
    iopt[C.I_SEED] = rng_state[0] - 1
    return CoreResult(
        f_best,
        m_best,
        pg,
        final_code,
        nit,
        counters[0],
        counters[1],
        n_passes,
        n_restarts,
        n_skipped,
        elapsed,
    )
