"""The quasi-Newton part: the inverse BFGS update, its initial scaling, and the
projected descent direction d = -H g on the variables not held at a bound (from H,
or from the Cholesky factor of H's inverse that a metric may give instead), and the
loop's small H helpers (is H the identity, the step's s and y, is a metric due).

References: Nocedal & Wright (2006), Numerical Optimization, 2nd ed.: eq. 6.17
(inverse BFGS update), eq. 6.20 (initial scaling), section 16.7 (projected methods);
Dennis & Schnabel (1996) A9.4.2. Compiled (numba) and inlined into the loop.
"""

from __future__ import annotations

import math

from .._jit import jit_inline
from .cholesky import cholesky_solve


@jit_inline
def descent_direction(h, g, x, lo, hi, d, gm):  # type: ignore[no-untyped-def]
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
def factor_direction(l_factor, g, x, lo, hi, d, gm):  # type: ignore[no-untyped-def]
    """``descent_direction`` where H is given as the Cholesky factor L of its inverse
    (``codes.METRIC_FACTOR``): d = -(L L^T)^-1 g_F by two triangular solves. The
    metric that wrote L left the held variables out of the coupling (a row of its
    own), so they get d = 0 from the zeroed gradient, as the principal submatrix."""
    n = x.shape[0]
    for i in range(n):
        held = (x[i] <= lo[i] and g[i] > 0.0) or (x[i] >= hi[i] and g[i] < 0.0)
        gm[i] = 0.0 if held else g[i]
    cholesky_solve(l_factor, gm, d)
    slope = 0.0
    for i in range(n):
        d[i] = -d[i]
        if gm[i] == 0.0 and g[i] != 0.0:
            d[i] = 0.0
        slope += g[i] * d[i]
    return slope


@jit_inline
def set_identity(h):  # type: ignore[no-untyped-def]
    n = h.shape[0]
    for i in range(n):
        for j in range(n):
            h[i, j] = 1.0 if i == j else 0.0


@jit_inline
def bfgs_update(h, s, y, hy, eps_curv):  # type: ignore[no-untyped-def]
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
def scale_initial_h(h, s, y):  # type: ignore[no-untyped-def]
    """Nocedal & Wright eq. 6.20: scale H0 = I to the curvature seen in the first step."""
    n = s.shape[0]
    sy = 0.0
    yy = 0.0
    for i in range(n):
        sy += s[i] * y[i]
        yy += y[i] * y[i]
    if sy > 0.0 and yy > 0.0:
        for i in range(n):
            h[i, i] = sy / yy


@jit_inline
def is_identity(h):  # type: ignore[no-untyped-def]
    n = h.shape[0]
    for i in range(n):
        for j in range(n):
            if h[i, j] != (1.0 if i == j else 0.0):
                return False
    return True


@jit_inline
def step_vectors(x, x_new, g, g_new, s, y):  # type: ignore[no-untyped-def]
    """s = x+ - x and y = g+ - g for the H update; returns the step's largest
    component relative to max(|x+_i|, 1) (the xtol test)."""
    step_rel = 0.0
    for i in range(x.shape[0]):
        s[i] = x_new[i] - x[i]
        y[i] = g_new[i] - g[i]
        r = abs(s[i]) / max(abs(x_new[i]), 1.0)
        if r > step_rel:
            step_rel = r
    return step_rel


@jit_inline
def metric_due(every, until, final_metric, pass_iters, goal_met):  # type: ignore[no-untyped-def]
    """Whether this iteration re-seeds H from the objective's metric (if it has one)
    instead of the BFGS update: every ``every`` iterations of a pass, during its first
    ``until`` (0: always). Not at a point that meets the goal: the pass ends there,
    and a metric for a step never taken would be wasted (a third of a warm-started
    stream frame's work) unless the caller carries this H to its next solve
    (``final_metric``)."""
    return (
        every > 0
        and pass_iters % every == 0
        and (until == 0 or pass_iters < until)
        and (final_metric or not goal_met)
    )
