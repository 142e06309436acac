"""The Dennis-Schnabel line search: the cubic backtrack, and the article's curvature phase.

``line_search`` is the backtracking search the article describes (Dennis & Schnabel
A6.3.1): lambda = 1, then the minimiser of the quadratic through f(0), f'(0) and f(1),
then of the cubic through the last two trial values, each clamped to [0.1, 0.5] x the
last lambda. ``curvature_phase`` is the article's modification (A6.3.1mod): once
Armijo holds, also ask for a flatter slope, expanding and zooming as needed.

Compiled (numba); the statuses are ``codes.LineSearchStatus`` values as plain ints.
"""

from __future__ import annotations

import math

from .._jit import jit, jit_inline
from . import codes as C
from .evaluate import evaluate


@jit_inline
def line_search(  # type: ignore[no-untyped-def]
    fg, data, x, f, g, d, lo, hi, fopt, iopt, x_new, g_new, work, counters, keep
):
    """Projected backtracking along d; returns (status, f_new, lambda), status a
    ``LineSearchStatus`` value (``codes.LS_*``).

    On ACCEPTED, x_new and g_new hold the accepted point (g_new: its gradient when
    trial points get one, see below).
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
        return C.LS_STEP_TOO_SMALL, f, 0.0
    min_lambda = fopt[C.F_STEPTOL] / rel
    lam = 1.0
    lam_prev = 0.0
    f_prev = 0.0
    first = True
    while True:
        for i in range(n):
            v = x[i] + lam * d[i]
            x_new[i] = lo[i] if v < lo[i] else (hi[i] if v > hi[i] else v)
        f_new = evaluate(fg, data, x_new, g_new, trial_grad, grad_mode, lo, hi, work, counters)
        decrease = 0.0
        for i in range(n):
            decrease += g[i] * (x_new[i] - x[i])
        if math.isfinite(f_new) and f_new <= f + c1 * decrease:
            if not curvature:
                return C.LS_ACCEPTED, f_new, lam
            return curvature_phase(
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
            return C.LS_BUDGET_SPENT, f_new, lam
        if lam < min_lambda:
            return C.LS_STEP_TOO_SMALL, f_new, lam
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
def curvature_phase(  # type: ignore[no-untyped-def]
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
        return C.LS_ACCEPTED, f_new, lam
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
            f_try = evaluate(fg, data, x_new, g_new, True, grad_mode, lo, hi, work, counters)
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
                f_try = evaluate(fg, data, x_new, g_new, True, grad_mode, lo, hi, work, counters)
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
    return C.LS_ACCEPTED, f_keep, lam_keep
