"""The compiled core: projected BFGS passes, Dennis-Schnabel line search, analyzer loop.

Everything here runs inside numba (one implementation; with ``NUMBA_DISABLE_JIT=1``
the same code runs as plain Python for debugging and coverage). The objective is a
compiled function ``fg(x, g, need_grad, data) -> f``, either passed as an argument
or registered for the type of ``data`` (see ``_dispatch``: only the registered
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

import numpy as np

from . import _codes as C
from ._clock import now_s
from ._dispatch import call_goal, call_metric, call_objective
from ._jit import jit, jit_inline, jit_leaf
from .analyzer import decide

_EPS = 2.220446049250313e-16
_SQRT_EPS = 1.4901161193847656e-08
_CBRT_EPS = 6.055454452393343e-06


@jit_inline
def _project(x, lo, hi, out):  # type: ignore[no-untyped-def]
    for i in range(x.shape[0]):
        v = x[i]
        if v < lo[i]:
            v = lo[i]
        elif v > hi[i]:
            v = hi[i]
        out[i] = v


@jit_inline
def _projected_gradient_norm(x, g, lo, hi):  # type: ignore[no-untyped-def]
    """inf-norm of P(x - g) - x: zero exactly at a KKT point of the box problem."""
    worst = 0.0
    for i in range(x.shape[0]):
        v = x[i] - g[i]
        if v < lo[i]:
            v = lo[i]
        elif v > hi[i]:
            v = hi[i]
        d = abs(v - x[i])
        if d > worst:
            worst = d
    return worst


@jit_inline
def _all_finite(v):  # type: ignore[no-untyped-def]
    for i in range(v.shape[0]):
        if not math.isfinite(v[i]):
            return False
    return True


@jit_inline
def _evaluate(fg, data, x, g, need_grad, grad_mode, lo, hi, work, counters):  # type: ignore[no-untyped-def]
    """f(x) and, if asked, g(x); counters = [nfev, ngev].

    Finite differences follow Dennis & Schnabel A5.6.3/A5.6.4 with typx = 1:
    forward steps sqrt(eps) * max(|x_i|, 1); central steps eps^(1/3) * max(|x_i|, 1)
    (the article used sqrt(eps) for both; the cube root balances truncation O(h^2)
    against rounding O(eps/h) and gives about 10 correct digits instead of 8). A step
    that would leave the box is taken the other way, so f is never evaluated outside.
    """
    if grad_mode == C.GRAD_ANALYTIC:
        f = call_objective(fg, x, g, need_grad, data)
        counters[0] += 1
        if need_grad:
            counters[1] += 1
        return f
    f = call_objective(fg, x, work, False, data)
    counters[0] += 1
    if not need_grad:
        return f
    counters[1] += 1
    n = x.shape[0]
    for i in range(n):
        xi = x[i]
        scale = max(abs(xi), 1.0)
        if grad_mode == C.GRAD_FORWARD:
            h = _SQRT_EPS * scale
            if xi + h > hi[i]:
                h = -h
            x[i] = xi + h
            h = x[i] - xi  # the step actually represented in floating point
            fp = call_objective(fg, x, work, False, data)
            counters[0] += 1
            g[i] = (fp - f) / h
        else:
            h = _CBRT_EPS * scale
            up = min(xi + h, hi[i])
            down = max(xi - h, lo[i])
            x[i] = up
            fp = call_objective(fg, x, work, False, data)
            x[i] = down
            fm = call_objective(fg, x, work, False, data)
            counters[0] += 2
            g[i] = (fp - fm) / (up - down) if up > down else 0.0
        x[i] = xi
    return f


@jit_inline
def _line_search(  # type: ignore[no-untyped-def]
    fg, data, x, f, g, d, lo, hi, fopt, iopt, x_new, g_new, work, counters, keep
):
    """Projected backtracking along d; returns (status, f_new, lambda).

    status 0: accepted; 1: minimum step length reached (LINE_SEARCH_FAILED);
    2: non-finite values only; 3: evaluation budget spent.
    The trial point is P(x + lambda d) and sufficient decrease is measured on the
    displacement actually taken, f(x+) <= f + c1 g.(x+ - x), which reduces to
    Armijo's f + c1 lambda g.d when no bound interferes. Interpolation uses the
    slope g.d of the unprojected ray (Dennis & Schnabel A6.3.1).
    """
    n = x.shape[0]
    grad_mode = iopt[C.I_GRAD_MODE]
    curvature = iopt[C.I_CURVATURE] != 0
    max_fev = iopt[C.I_MAX_FEV]
    c1 = fopt[C.F_C1]
    # With analytic gradients g comes almost free with f (the IK Jacobian), so trial
    # points get both and the accepted point needs no second evaluation.
    trial_grad = grad_mode == C.GRAD_ANALYTIC or curvature
    slope = 0.0
    rel = 0.0
    for i in range(n):
        slope += g[i] * d[i]
        r = abs(d[i]) / max(abs(x[i]), 1.0)
        if r > rel:
            rel = r
    if rel == 0.0:
        return 1, f, 0.0
    min_lambda = fopt[C.F_STEPTOL] / rel
    lam = 1.0
    lam_prev = 0.0
    f_prev = 0.0
    first = True
    while True:
        for i in range(n):
            v = x[i] + lam * d[i]
            x_new[i] = lo[i] if v < lo[i] else (hi[i] if v > hi[i] else v)
        f_new = _evaluate(fg, data, x_new, g_new, trial_grad, grad_mode, lo, hi, work, counters)
        decrease = 0.0
        for i in range(n):
            decrease += g[i] * (x_new[i] - x[i])
        if math.isfinite(f_new) and f_new <= f + c1 * decrease:
            if not curvature:
                return 0, f_new, lam
            return _curvature_phase(
                fg,
                data,
                x,
                f,
                g,
                d,
                lo,
                hi,
                fopt,
                iopt,
                x_new,
                g_new,
                work,
                counters,
                lam,
                f_new,
                slope,
                first,
                min_lambda,
                keep,
            )
        if counters[0] >= max_fev:
            return 3, f_new, lam
        if lam < min_lambda:
            return 1, f_new, lam
        if not math.isfinite(f_new):
            # No model of f through a non-finite value: shrink hard and try again.
            lam_prev = 0.0
            lam *= 0.1
            first = True
            continue
        if first:
            # Minimiser of the quadratic through f(0), f'(0) and f(lam) = f(1).
            lam_t = -slope / (2.0 * (f_new - f - slope))
            first = False
        else:
            # Minimiser of the cubic through f(0), f'(0), f(lam) and f(lam_prev).
            rhs1 = f_new - f - lam * slope
            rhs2 = f_prev - f - lam_prev * slope
            a = (rhs1 / (lam * lam) - rhs2 / (lam_prev * lam_prev)) / (lam - lam_prev)
            b = (-lam_prev * rhs1 / (lam * lam) + lam * rhs2 / (lam_prev * lam_prev)) / (
                lam - lam_prev
            )
            if a == 0.0:
                lam_t = -slope / (2.0 * b) if b != 0.0 else 0.5 * lam
            else:
                disc = b * b - 3.0 * a * slope
                if disc < 0.0:
                    lam_t = 0.5 * lam
                elif b <= 0.0:
                    lam_t = (-b + math.sqrt(disc)) / (3.0 * a)
                else:
                    lam_t = -slope / (b + math.sqrt(disc))
            if not math.isfinite(lam_t) or lam_t > 0.5 * lam:
                lam_t = 0.5 * lam
        lam_prev = lam
        f_prev = f_new
        lam = lam_t if lam_t > 0.1 * lam else 0.1 * lam


# Not jit_leaf: it calls the objective, and minimize()'s objectives may allocate (a
# leaf build would be inherited by them). It allocates nothing itself (its kept point
# is the caller's), so the IK path's leaf core may call it either way.
@jit
def _curvature_phase(  # type: ignore[no-untyped-def]
    fg,
    data,
    x,
    f,
    g,
    d,
    lo,
    hi,
    fopt,
    iopt,
    x_new,
    g_new,
    work,
    counters,
    lam,
    f_new,
    slope,
    untouched,
    min_lambda,
    keep,
):
    """The article's modified search: also ask g(x+).d >= c2 g.d (Dennis & Schnabel A6.3.1mod).

    Entered with x_new = P(x + lam d) satisfying Armijo (g_new holds its gradient). If
    the slope there is still steep and lambda was never cut, lambda doubles (up to the
    step cap, which d already respects via max_step) while Armijo holds; if an expansion
    overshoots, the bracket [lo, hi] is narrowed by quadratic interpolation. The best
    Armijo point found is returned whether or not curvature is met (DS do the same).
    """
    n = x.shape[0]
    grad_mode = iopt[C.I_GRAD_MODE]
    max_fev = iopt[C.I_MAX_FEV]
    c1 = fopt[C.F_C1]
    c2 = fopt[C.F_C2]
    new_slope = 0.0
    for i in range(n):
        new_slope += g_new[i] * d[i]
    if new_slope >= c2 * slope:
        return 0, f_new, lam
    # The last point that satisfied Armijo, kept apart from x_new (the trial buffer).
    x_keep = keep[0]
    g_keep = keep[1]
    for i in range(n):
        x_keep[i] = x_new[i]
        g_keep[i] = g_new[i]
    f_keep = f_new
    lam_keep = lam
    slope_keep = new_slope
    if untouched:
        lam_hi = 0.0
        f_hi = 0.0
        while True:
            lam_try = 2.0 * lam_keep
            moved = False
            for i in range(n):
                v = x[i] + lam_try * d[i]
                v = lo[i] if v < lo[i] else (hi[i] if v > hi[i] else v)
                x_new[i] = v
                if v != x_keep[i]:
                    moved = True
            if not moved or counters[0] >= max_fev:
                break  # pinned by the bounds: expanding further changes nothing
            f_try = _evaluate(fg, data, x_new, g_new, True, grad_mode, lo, hi, work, counters)
            decrease = 0.0
            s_try = 0.0
            for i in range(n):
                decrease += g[i] * (x_new[i] - x[i])
                s_try += g_new[i] * d[i]
            if not (math.isfinite(f_try) and f_try <= f + c1 * decrease):
                lam_hi = lam_try
                f_hi = f_try
                break
            for i in range(n):
                x_keep[i] = x_new[i]
                g_keep[i] = g_new[i]
            f_keep = f_try
            lam_keep = lam_try
            slope_keep = s_try
            if s_try >= c2 * slope or lam_try > 1e8:
                break
        if lam_hi > 0.0 and math.isfinite(f_hi) and slope_keep < c2 * slope:
            # Zoom between lam_keep (Armijo, too steep) and lam_hi (no Armijo).
            lam_lo = lam_keep
            f_lo = f_keep
            for _ in range(10):
                diff = lam_hi - lam_lo
                if diff < min_lambda or counters[0] >= max_fev:
                    break
                denom = 2.0 * (f_hi - (f_lo + slope_keep * diff))
                incr = -slope_keep * diff * diff / denom if denom > 0.0 else 0.5 * diff
                if not (incr >= 0.2 * diff):
                    incr = 0.2 * diff
                if incr > 0.8 * diff:
                    incr = 0.8 * diff
                lam_try = lam_lo + incr
                for i in range(n):
                    v = x[i] + lam_try * d[i]
                    x_new[i] = lo[i] if v < lo[i] else (hi[i] if v > hi[i] else v)
                f_try = _evaluate(fg, data, x_new, g_new, True, grad_mode, lo, hi, work, counters)
                decrease = 0.0
                s_try = 0.0
                for i in range(n):
                    decrease += g[i] * (x_new[i] - x[i])
                    s_try += g_new[i] * d[i]
                if not (math.isfinite(f_try) and f_try <= f + c1 * decrease):
                    lam_hi = lam_try
                    f_hi = f_try
                    continue
                lam_lo = lam_try
                f_lo = f_try
                for i in range(n):
                    x_keep[i] = x_new[i]
                    g_keep[i] = g_new[i]
                f_keep = f_try
                lam_keep = lam_try
                slope_keep = s_try
                if s_try >= c2 * slope:
                    break
    for i in range(n):
        x_new[i] = x_keep[i]
        g_new[i] = g_keep[i]
    return 0, f_keep, lam_keep


@jit_leaf
def _uniform(state):  # type: ignore[no-untyped-def]
    """Park-Miller minimal standard generator (product < 2^47: no int64 overflow).

    The restart generator lives in the state array rather than numba's global
    np.random so that a solve is reproducible from its seed alone and never shares
    state with another thread's or session's solves. ``run_solver`` writes the final
    state back into iopt[I_SEED], so a caller that keeps its option vector (an
    IKSolver) continues one stream across its own solves.
    """
    state[0] = (state[0] * 48271) % 2147483647
    return (state[0] - 1) / 2147483646.0


@jit_leaf
def _random_point(x_center, lo, hi, radius, rng_state, out):  # type: ignore[no-untyped-def]
    """Uniform in the box intersected with [center - radius, center + radius].

    radius = inf samples the whole box (global restarts, TRAC-IK style); a finite
    radius keeps restarts near the start (streams: no popping). A side that is
    still infinite falls back to center +- 10 max(|center_i|, 1).
    """
    for i in range(x_center.shape[0]):
        c = x_center[i]
        fallback = 10.0 * max(abs(c), 1.0)
        a = max(lo[i], c - radius)
        b = min(hi[i], c + radius)
        if not math.isfinite(a):
            a = c - fallback
        if not math.isfinite(b):
            b = c + fallback
        v = a + (b - a) * _uniform(rng_state)
        out[i] = lo[i] if v < lo[i] else (hi[i] if v > hi[i] else v)


@jit_inline
def _descent_direction(h, g, x, lo, hi, d, gm):  # type: ignore[no-untyped-def]
    """d = -H_FF g_F on the free variables, 0 on those held at a bound.

    A variable is held when it sits on a bound and the gradient pushes it outward;
    zeroing its gradient entry and its direction entry is the same as using the
    principal submatrix of H, which stays positive definite.
    """
    n = x.shape[0]
    for i in range(n):
        held = (x[i] <= lo[i] and g[i] > 0.0) or (x[i] >= hi[i] and g[i] < 0.0)
        gm[i] = 0.0 if held else g[i]
    for i in range(n):
        s = 0.0
        for j in range(n):
            s -= h[i, j] * gm[j]
        d[i] = s
    slope = 0.0
    for i in range(n):
        if gm[i] == 0.0 and g[i] != 0.0:
            d[i] = 0.0
        slope += g[i] * d[i]
    return slope


@jit_inline
def _set_identity(h):  # type: ignore[no-untyped-def]
    n = h.shape[0]
    for i in range(n):
        for j in range(n):
            h[i, j] = 1.0 if i == j else 0.0


@jit_inline
def _bfgs_update(h, s, y, hy, eps_curv):  # type: ignore[no-untyped-def]
    """Inverse BFGS update (Nocedal & Wright eq. 6.17); False when skipped.

    Skipped unless y.s > eps_curv * |s| |y|: without safely positive curvature the
    update would destroy positive definiteness (scipy's BFGS skips the same way).
    """
    n = s.shape[0]
    sy = 0.0
    ss = 0.0
    yy = 0.0
    for i in range(n):
        sy += s[i] * y[i]
        ss += s[i] * s[i]
        yy += y[i] * y[i]
    if not (sy > eps_curv * math.sqrt(ss * yy)) or not math.isfinite(sy):
        return False
    rho = 1.0 / sy
    yhy = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += h[i, j] * y[j]
        hy[i] = acc
        yhy += y[i] * acc
    # H+ = H - rho (Hy s' + s y'H) + (rho^2 y'Hy + rho) s s'   (H symmetric)
    coef = rho * rho * yhy + rho
    for i in range(n):
        for j in range(n):
            h[i, j] += -rho * (hy[i] * s[j] + s[i] * hy[j]) + coef * s[i] * s[j]
    return True


@jit_inline
def _better(f, m, f_best, m_best, has_goal, f_goal):  # type: ignore[no-untyped-def]
    """Order of points: meeting the goal first, then lower f."""
    if has_goal:
        met = m <= f_goal
        met_best = m_best <= f_goal
        if met != met_best:
            return met
    return f < f_best


# Rows of the work block the core's vectors live in (x, g, trial point and gradient,
# direction, s, y, ...; the last two: the curvature search's kept point).
WORK_ROWS = 12


@jit
def run_solver(fg, goal_fn, data, x0, lo, hi, h, fopt, iopt, policy, log, trace, out_x, out_g):  # type: ignore[no-untyped-def]
    """The core for any objective (``minimize``: user objectives, MGH); see
    ``_run_solver``. Allocates its work arrays, so the objective may allocate too."""
    work = np.empty((WORK_ROWS, x0.shape[0]))
    ints = np.empty(3, dtype=np.int64)
    return _run_solver(
        fg, goal_fn, data, x0, lo, hi, h, fopt, iopt, policy, log, trace, out_x, out_g, work, ints
    )


@jit_leaf
def run_solver_leaf(  # type: ignore[no-untyped-def]
    fg, goal_fn, data, x0, lo, hi, h, fopt, iopt, policy, log, trace, out_x, out_g, work, ints
):
    """The same core compiled without reference counting (``jit_leaf``), for the IK
    objective, which allocates nothing: ~2.4x faster per iteration, same iterates.
    ``work`` is float64[WORK_ROWS, n] and ``ints`` int64[3], both the caller's."""
    return _run_solver(
        fg, goal_fn, data, x0, lo, hi, h, fopt, iopt, policy, log, trace, out_x, out_g, work, ints
    )


@jit_inline
def _run_solver(  # type: ignore[no-untyped-def]
    fg, goal_fn, data, x0, lo, hi, h, fopt, iopt, policy, log, trace, out_x, out_g, vectors, ints
):
    """Multi-pass projected BFGS under the analyzer; the whole solve in one call.

    Args:
        fg: Compiled objective ``fg(x, g, need_grad, data) -> f``, or None to use
            the objective registered for the type of ``data`` (``_dispatch``).
        goal_fn: Kept None. With fg None the goal measure registered with the
            objective, m(f, x, data), decides "goal met" (m <= f_goal); else f
            does. The IK registers its normalised pose error, so "goal met" means
            "IK succeeded" even when f carries posture terms.
        data: Passed through to ``fg`` untouched.
        x0: Start, shape (n,); projected into the box here.
        lo, hi: Bounds, shape (n,); +-inf allowed; lo <= hi checked by the caller.
        h: Inverse-Hessian approximation, shape (n, n): the initial H on entry
            (identity or the caller's), the final H on return.
        fopt, iopt: Option vectors laid out as in ``_codes`` (F_*, I_*); iopt[I_SEED]
            is written on return (the restart generator's state, as a seed).
        policy: Analyzer table int64[n_codes, 3].
        log: float64[max_passes, N_LOG] pass log, filled row by row.
        trace: float64[rows, 5]: for each accepted step (while rows last) f before,
            f after, g.(x+ - x), lambda, and the smallest distance of x+ to a bound
            (negative would mean it left the box). Shape (0, 5) records nothing.
        out_x, out_g: Receive the best x and its gradient.
        vectors, ints: Work blocks, float64[WORK_ROWS, n] and int64[3] (contents
            ignored): the caller's, so that this body allocates nothing.

    Returns:
        (f_best, goal_measure_best, pg_norm, code, nit, nfev, ngev, n_passes,
        n_restarts, n_skipped, elapsed_s)
    """
    t_start = now_s()
    n = x0.shape[0]
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
    gtol = fopt[C.F_GTOL]
    xtol = fopt[C.F_XTOL]
    ftol = fopt[C.F_FTOL]
    f_goal = fopt[C.F_F_GOAL]
    max_step = fopt[C.F_MAX_STEP]
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
    d = vectors[4]
    gm = vectors[5]
    s = vectors[6]
    y = vectors[7]
    hy = vectors[8]
    work = vectors[9]
    keep = vectors[10:12]

    _project(x0, lo, hi, x)
    f = _evaluate(fg, data, x, g, True, grad_mode, lo, hi, work, counters)
    f_best = f
    m = call_goal(goal_fn, fg, f, x, data) if has_goal else f
    m_best = m
    for i in range(n):
        out_x[i] = x[i]
        out_g[i] = g[i]

    nit = 0
    n_passes = 0
    n_restarts = 0
    n_skipped = 0
    final_code = C.NONFINITE
    start_kind = C.START_INITIAL
    h_is_identity = True
    for i in range(n):
        for j in range(n):
            if h[i, j] != (1.0 if i == j else 0.0):
                h_is_identity = False
    # "Fresh": H = I or the objective's own metric, i.e. no curvature learnt yet
    # (a caller's H carried from a previous solve is not fresh).
    h_fresh = h_is_identity
    if h_is_identity and call_metric(fg, x, g, lo, hi, data, h):
        h_is_identity = False

    while True:
        # ---- one pass -------------------------------------------------------
        pass_iters = 0
        f_pass_start = f
        nfev_pass_start = counters[0]
        began_fresh = h_fresh
        first_step = True
        stall_count = 0
        code = C.RUNNING
        while code == C.RUNNING:
            if not (math.isfinite(f) and _all_finite(g)):
                code = C.NONFINITE
                break
            if has_goal and m <= f_goal:
                code = C.GOAL_REACHED
                break
            if _projected_gradient_norm(x, g, lo, hi) <= gtol:
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
            slope = _descent_direction(h, g, x, lo, hi, d, gm)
            if not (slope < 0.0):
                # H lost positive definiteness numerically: fall back to steepest descent.
                _set_identity(h)
                h_is_identity = True
                slope = _descent_direction(h, g, x, lo, hi, d, gm)
            big = 0.0
            for i in range(n):
                if abs(d[i]) > big:
                    big = abs(d[i])
            if big > max_step:
                # Step cap (inf-norm: per variable, e.g. radians per joint).
                scale = max_step / big
                for i in range(n):
                    d[i] *= scale
            status, f_trial, lam = _line_search(
                fg, data, x, f, g, d, lo, hi, fopt, iopt, x_new, g_new, work, counters, keep
            )
            if status == 3:
                code = C.MAX_FEV
                break
            if status != 0:
                code = C.LINE_SEARCH_FAILED
                break
            if grad_mode != C.GRAD_ANALYTIC and iopt[C.I_CURVATURE] == 0:
                f_trial = _evaluate(fg, data, x_new, g_new, True, grad_mode, lo, hi, work, counters)
            if nit < trace.shape[0]:
                slack = math.inf
                dec = 0.0
                for i in range(n):
                    dec += g[i] * (x_new[i] - x[i])
                    slack = min(slack, x_new[i] - lo[i], hi[i] - x_new[i])
                trace[nit, 0] = f
                trace[nit, 1] = f_trial
                trace[nit, 2] = dec
                trace[nit, 3] = lam
                trace[nit, 4] = slack
            nit += 1
            pass_iters += 1
            step_rel = 0.0
            for i in range(n):
                s[i] = x_new[i] - x[i]
                y[i] = g_new[i] - g[i]
                r = abs(s[i]) / max(abs(x_new[i]), 1.0)
                if r > step_rel:
                    step_rel = r
            if first_step and scale_h0 and h_is_identity:
                # Nocedal & Wright eq. 6.20: scale H0 to the curvature seen in the first step.
                sy = 0.0
                yy = 0.0
                for i in range(n):
                    sy += s[i] * y[i]
                    yy += y[i] * y[i]
                if sy > 0.0 and yy > 0.0:
                    for i in range(n):
                        h[i, i] = sy / yy
            first_step = False
            # The goal at the new point first: when it is met the pass ends at the top
            # of the loop, and a metric for a step never taken would be wasted (a
            # third of a warm-started stream frame's work) unless the caller carries
            # this H to its next solve (final_metric).
            m_new = call_goal(goal_fn, fg, f_trial, x_new, data) if has_goal else f_trial
            if (
                metric_every > 0
                and pass_iters % metric_every == 0
                and (metric_until == 0 or pass_iters < metric_until)
                and (final_metric or not (has_goal and m_new <= f_goal))
                and call_metric(fg, x_new, g_new, lo, hi, data, h)
            ):
                # Re-seed H from the objective's metric (every step: damped Gauss-Newton).
                h_is_identity = False
            elif _bfgs_update(h, s, y, hy, eps_curv):
                h_is_identity = False
                h_fresh = False
            else:
                n_skipped += 1
            improvement = f - f_trial
            f = f_trial
            for i in range(n):
                x[i] = x_new[i]
                g[i] = g_new[i]
            m = m_new
            if _better(f, m, f_best, m_best, has_goal, f_goal):
                f_best = f
                m_best = m
                for i in range(n):
                    out_x[i] = x[i]
                    out_g[i] = g[i]
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
        # NONFINITE can only come from the current point; never treat it as best.
        if code == C.GOAL_REACHED or (has_goal and m_best <= f_goal):
            goal = C.MET
        elif has_goal:
            goal = C.MISSED
        else:
            goal = C.NO_GOAL
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
        )
        if n_passes < log.shape[0]:
            row = log[n_passes]
            row[C.L_START] = start_kind
            row[C.L_ITERS] = pass_iters
            row[C.L_CODE] = code
            row[C.L_F_START] = f_pass_start
            row[C.L_F_END] = f
            row[C.L_GOAL] = goal
            row[C.L_ACTION] = action
            row[C.L_NFEV] = counters[0] - nfev_pass_start
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
            _random_point(x0, lo, hi, fopt[C.F_RESTART_RADIUS], rng_state, x)
            f = _evaluate(fg, data, x, g, True, grad_mode, lo, hi, work, counters)
            if has_goal:
                m = call_goal(goal_fn, fg, f, x, data)
            if _better(f, m, f_best, m_best, has_goal, f_goal):
                f_best = f
                m_best = m
                for i in range(n):
                    out_x[i] = x[i]
                    out_g[i] = g[i]
        h_fresh = True
        if call_metric(fg, x, g, lo, hi, data, h):
            h_is_identity = False
        else:
            _set_identity(h)
            h_is_identity = True

    pg = _projected_gradient_norm(out_x, out_g, lo, hi)
    elapsed = now_s() - t_start
    # Hand the generator's state back: a caller that keeps iopt (IKSolver does, per
    # options) continues the same stream on its next call with no new seed to draw.
    iopt[C.I_SEED] = rng_state[0] - 1
    return (
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
