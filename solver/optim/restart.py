"""Random restarts: a seeded generator that lives in the solve's state, and the point
it draws (the analyzer's RESTART_RANDOM).

Compiled (numba).
"""

from __future__ import annotations

import math

from .._jit import jit_leaf


@jit_leaf
def uniform(state):  # type: ignore[no-untyped-def]
    """Park-Miller minimal standard generator (product < 2^47: no int64 overflow).

    The restart generator lives in the state array rather than numba's global
    np.random so that a solve is reproducible from its seed alone and never shares
    state with another thread's or session's solves. ``loop.run_solver`` writes the
    final state back into iopt[I_SEED], so a caller that keeps its option vector (an
    IKSolver) continues one stream across its own solves.
    """
    state[0] = (state[0] * 48271) % 2147483647
    return (state[0] - 1) / 2147483646.0


@jit_leaf
def random_point(x_center, lo, hi, radius, rng_state, out):  # type: ignore[no-untyped-def]
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
        v = a + (b - a) * uniform(rng_state)
        out[i] = lo[i] if v < lo[i] else (hi[i] if v > hi[i] else v)
