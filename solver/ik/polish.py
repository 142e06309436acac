"""A bounded Levenberg-Marquardt polish of a frame that ended just short of its goal
(compiled).

Why. A redundant chain stretched to the edge of its workspace against a limit (the
40-DOF tail of bench/tracking.py, smallest singular value ~2e-3) can end a solve a
hair over the tolerance: the BFGS line search crawls along a narrow valley whose floor
the objective's damping (a stream's ``damping`` floor, there to keep steps smooth near
singularities) flattens, and every restart near the last answer crawls in the same
valley until the iterations or the time run out (0.28% of tail40's pose frames,
``max_iter`` after 5000 iterations at 1.01-1.17 tolerances). A few Gauss-Newton steps
on the goal's own residuals, each scaled by its tolerance, undamped but for
Levenberg-Marquardt's adaptive mu, cross it in 1-15 steps
(bench/history/2026-11-29-tail40-lm-polish-probe.md).

It runs only after the optimizer (the article's method, untouched) has finished, only
on an answer within ``POLISH_WITHIN`` tolerances of the goal and within the time
budget (of which the optimizer leaves it ``POLISH_RESERVE``), for at most
``IKOptions.polish_steps`` steps, each moving no variable more than the solve's
``max_step_rad`` and staying within the bounds (a SMOOTH frame's step box included);
it keeps a step only if it lowers the sum of squared scaled residuals, and its answer
only if it meets the goal: a frame it cannot finish is returned as the optimizer left
it.
"""

from __future__ import annotations

import math

from .._clock import now_s
from .._jit import jit_leaf
from ..model.layout import ED_TOL_P, ED_TOL_R, ED_WP, ED_WR, EI_MODE, MODE_POSITION
from .kinematics import DD_HI, DD_LO, DD_XLAST, MISC_GOAL, MISC_LIMIT, MISC_POSTURE, ik_objective
from .metric import damped_metric_inverse, is_held

# The polish is tried on answers at most this many tolerances from the goal (the goal
# measure): a target well out of reach (a game character's hand past arm's length,
# every frame) ends far beyond it and costs no polish; one just out of reach costs the
# steps until MAX_REFUSED or the time budget (~20-30 us on a 7-DOF arm).
POLISH_WITHIN = 10.0
# The share of a finite time budget the optimizer leaves for the polish (its deadline
# comes that much earlier): 0.5 ms of a session's 5 ms, tens of tail40 steps.
POLISH_RESERVE = 0.1
# Times a step is solved again with the variables it would push past a bound held.
PIN_ROUNDS = 4
# Steps refused in a row after which the polish gives up. Finishing a tail40 frame
# took up to 4-5 refusals in a row (mu x 1e4) before a step was accepted.
MAX_REFUSED = 6


@jit_leaf
def polish(data, q, max_steps, max_step, deadline, g, trial, g_trial, h, saved, start, free):  # type: ignore[no-untyped-def]
    """Up to ``max_steps`` Levenberg-Marquardt steps from q towards the goal, none
    begun after ``deadline`` (``_clock.now_s`` seconds); q is updated in place only if
    they meet the goal. Returns (steps tried, accepted or not; objective evaluations).

    The residuals are the goal measure's (``kinematics.goal_measure``): each effector's
    position error over its position tolerance and rotation (or aim) error over its
    rotation tolerance, so that the least-squares sum is small exactly when the goal is
    met. The weights are swapped in for the effectors' own (which are restored), the
    posture and limit preferences are off, as on the exact retry (``frame``). A
    variable on a bound with the gradient pushing outward is held, as the optimizer's
    projected metric holds it, and so is one the step would push past its bound (the
    step is solved again without it, up to ``PIN_ROUNDS`` times, then clipped). mu
    starts at Sugihara's f (the sum itself), falls by 10 after a step that lowers the
    sum and rises by 10 after one that does not.

    Steps that do not meet the goal are undone (q is put back): on a frame left
    unsolved, the optimizer's answer is the weighted compromise the client asked for
    (effector weights, posture and limit preferences) that the polish's tolerance
    weights would trade for another. The steps also end after ``MAX_REFUSED`` refused
    in a row (mu a million times larger: the steps are too small to matter).

    ``g``, ``trial``, ``g_trial``, ``start``, ``free`` (n), ``h`` (n x n) and ``saved``
    (2m) are work space.
    On return DD_XLAST is marked stale (its cached f was the swapped objective's).
    """
    ni, nd, ei, ed, dd, misc = data
    n = q.shape[0]
    m = ei.shape[0]
    lo = dd[DD_LO]
    hi = dd[DD_HI]
    for e in range(m):
        saved[2 * e] = ed[e, ED_WP]
        saved[2 * e + 1] = ed[e, ED_WR]
        position = ei[e, EI_MODE] == MODE_POSITION or ed[e, ED_WP] > 0.0
        rotation = ei[e, EI_MODE] != MODE_POSITION and ed[e, ED_WR] > 0.0
        ed[e, ED_WP] = 1.0 / ed[e, ED_TOL_P] ** 2 if position else 0.0
        ed[e, ED_WR] = 1.0 / ed[e, ED_TOL_R] ** 2 if rotation else 0.0
    w_posture = misc[MISC_POSTURE]
    w_limit = misc[MISC_LIMIT]
    misc[MISC_POSTURE] = 0.0
    misc[MISC_LIMIT] = 0.0
    f = ik_objective(q, g, True, data)
    evaluations = 1
    measure = misc[MISC_GOAL]
    for i in range(n):
        start[i] = q[i]
    mu = f
    steps = 0
    refused = 0
    while (
        measure > 1.0
        and steps < max_steps
        and refused < MAX_REFUSED
        and math.isfinite(f)
        and now_s() < deadline
    ):
        steps += 1
        for i in range(n):
            free[i] = 0.0 if is_held(q[i], g[i], lo[i], hi[i]) else 1.0
        # The active set: a free variable whose step would cross its bound is held
        # where it is and the step solved again without it. Clipping it instead bends
        # the step, and bent steps get refused: on one stalled tail40 frame (stream 31
        # frame 322) 5 steps finished it this way, 16 with clipping; on the hardest
        # frames neither does within 60 (bench/RESULTS.md, tracking bars).
        solved = False
        for _ in range(PIN_ROUNDS):
            if not damped_metric_inverse(q, free, lo, hi, data, h, mu):
                break
            for i in range(n):
                step = 0.0
                if free[i] != 0.0:
                    for j in range(n):
                        if free[j] != 0.0:
                            step -= h[i, j] * g[j]
                trial[i] = step
            crossing = False  # marked after the whole step: it was solved on this set
            for i in range(n):
                v = q[i] + trial[i]
                if free[i] != 0.0 and (v < lo[i] or v > hi[i]):
                    free[i] = 0.0
                    crossing = True
            solved = True
            if not crossing:
                break
        if not solved:
            break
        big = 0.0
        for i in range(n):
            big = max(big, abs(trial[i]))
        scale = 1.0 if big <= max_step else max_step / big
        for i in range(n):
            trial[i] = min(hi[i], max(lo[i], q[i] + scale * trial[i]))
        f_trial = ik_objective(trial, g_trial, True, data)
        evaluations += 1
        if f_trial < f:
            for i in range(n):
                q[i] = trial[i]
                g[i] = g_trial[i]
            f = f_trial
            measure = misc[MISC_GOAL]
            mu = max(mu * 0.1, 1e-12)
            refused = 0
        else:
            mu *= 10.0
            refused += 1
    if measure > 1.0:
        for i in range(n):
            q[i] = start[i]
    for e in range(m):
        ed[e, ED_WP] = saved[2 * e]
        ed[e, ED_WR] = saved[2 * e + 1]
    misc[MISC_POSTURE] = w_posture
    misc[MISC_LIMIT] = w_limit
    if n > 0:
        dd[DD_XLAST, 0] = math.nan
    return steps, evaluations
