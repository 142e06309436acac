"""f and g at a point, with the analytic gradient or finite differences; box helpers.

Compiled (numba) and inlined into the loop (``_jit.jit_inline``).
"""

from __future__ import annotations

import math

from .._jit import jit_inline
from . import codes as C
from .objective import call_objective

_SQRT_EPS = 1.4901161193847656e-08
_CBRT_EPS = 6.055454452393343e-06


@jit_inline
def project(x, lo, hi, out):  # type: ignore[no-untyped-def]
    """out = P(x): x clipped into the box [lo, hi]."""
    for i in range(x.shape[0]):
        v = x[i]
        if v < lo[i]:
            v = lo[i]
        elif v > hi[i]:
            v = hi[i]
        out[i] = v


@jit_inline
def projected_gradient_norm(x, g, lo, hi):  # type: ignore[no-untyped-def]
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
def all_finite(v):  # type: ignore[no-untyped-def]
    for i in range(v.shape[0]):
        if not math.isfinite(v[i]):
            return False
    return True


@jit_inline
def evaluate(fg, data, x, g, need_grad, grad_mode, lo, hi, work, counters):  # type: ignore[no-untyped-def]
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
