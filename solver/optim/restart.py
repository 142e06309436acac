"""Random restarts: a seeded generator that lives in the solve's state, and the point
it draws (the analyzer's RESTART_RANDOM).

A restart draws every variable (``random_point``). With an objective that can say
how settled each variable is (``register_objective``'s ``restart_keep_fn``: for the
IK, the share of the effectors a variable moves that are already on target), most
restarts then put the settled variables back at their values in the best point
(``keep_values``): a partial restart, logged as ``PassStart.RESTART_PARTIAL``.
Re-drawing everything lands each part of the problem in its solution's basin again
at random, so with several independent parts (a robot's limbs) the chance that all
of them land at once shrinks with every part; keeping the parts that are done
leaves only the others to chance.

Partial restarts alternate between keeping every variable with a settled share
(odd restarts: a limb off target is re-drawn, the torso it shares with limbs on
target is kept) and keeping only the wholly settled ones (even restarts: the torso
is re-drawn too, in case it is what keeps the limb off); every
``full_restart_every``-th restart re-draws everything, in case the settled values
themselves are what blocks the rest. The generator draws every variable either
way, so the sequence of draws does not depend on what is kept.

A turn restart (``turn_values``) goes first, once per best point, where the objective
says which variables are periodic (``register_objective``'s ``restart_period_fn``: for
the IK, the angle of a revolute joint, period 2 pi). At a local minimum a bound
often holds an angle whose best value lies just past it: the joint would have to
turn the short way, through the gap its limits forbid, and no descent from inside
the box gets there. Turning the variable the other way round by a period lands it
at that angle from the other side (a range of a full turn: the same pose), or at the
opposite bound, short of it by the gap (a range within a quarter turn of a full
one); the descent then approaches it from the side the limits allow. It starts from
the best point with only those variables moved, which a random draw almost never
does (on Baxter, 22 of 35 misses had such a joint).

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


@jit_leaf
def keep_values(keep, source, out, only_whole, lo, hi):  # type: ignore[no-untyped-def]
    """out[i] = source[i] for each variable a partial restart keeps: keep[i] >= 1
    (wholly settled) with ``only_whole``, else keep[i] > 0 (a settled share).

    Returns how many free variables (lo < hi) it kept; 0, writing nothing, when it
    would keep none or every one of them: keeping every free variable would start the
    "restart" at the best point, a pass spent on nothing (two effectors on one link,
    one on target and one off, give every variable a share).
    """
    kept = 0
    free = 0
    for i in range(out.shape[0]):
        if lo[i] < hi[i]:
            free += 1
            if keep[i] >= 1.0 if only_whole else keep[i] > 0.0:
                kept += 1
    if kept == 0 or kept == free:
        return 0
    for i in range(out.shape[0]):
        if keep[i] >= 1.0 if only_whole else keep[i] > 0.0:
            out[i] = source[i]
    return kept


@jit_leaf
def turn_values(x, g, period, keep, lo, hi, x_center, radius, out):  # type: ignore[no-untyped-def]
    """out = x with each variable that a bound stops turned the other way round by its
    period, clamped into the box; returns how many it turned (0: out is untouched).

    Variable i turns when it is periodic (period[i] > 0) and not settled
    (keep[i] < 1: it moves something still off target), sits on a bound (within
    1e-9 of its range) that the gradient pushes it against (the bound is active with
    a positive multiplier: g[i] < 0 at the upper bound, > 0 at the lower), and its
    range is over three quarters of a period: the gap the bounds forbid is then under
    a quarter period, so the turned value lies within a quarter period of every value
    in the gap, the best one included, where a periodic error (1 - cos of the angle
    to the best, for a point turning on a circle) is still convex. A wider gap would
    land it no nearer the best value than a random draw (on g1, turning its +-1.9 rad
    shoulder rolls too took more iterations: median 108 against 84 with the quarter).
    Like a random restart, the turned value stays within ``radius`` of ``x_center``
    (a stream's local restarts turn nothing across a range).
    """
    turned = 0
    for i in range(x.shape[0]):
        p = period[i]
        width = hi[i] - lo[i]
        if not (p > 0.0 and keep[i] < 1.0 and 4.0 * width > 3.0 * p and math.isfinite(width)):
            continue
        tol = 1e-9 * width
        if x[i] >= hi[i] - tol and g[i] < 0.0:
            v = x[i] - p
        elif x[i] <= lo[i] + tol and g[i] > 0.0:
            v = x[i] + p
        else:
            continue
        v = lo[i] if v < lo[i] else (hi[i] if v > hi[i] else v)
        if abs(v - x_center[i]) > radius:
            continue
        if turned == 0:
            for j in range(x.shape[0]):
                out[j] = x[j]
        out[i] = v
        turned += 1
    return turned
