"""How settled each variable is, for partial restarts: the share of the effectors it
moves that are already on target (compiled; registered as the IK objective's
``restart_keep_fn``); and which variables are angles, for turn restarts
(``variable_periods``, its ``restart_period_fn``).

The optimizer knows no kinematics (``optim.restart``): it asks the objective how
settled each variable is at its best point, and a partial restart keeps the settled
ones there and re-draws the others. A variable on the path from the root to an
effector moves it; a limb's joints move only the effectors on that limb, a torso's
every effector above it. A limb whose effectors are all on target has share 1 and
is kept; a limb off target has share 0 and is re-drawn; the torso in between has a
share in (0, 1), kept by some partial restarts and re-drawn by others. With one
targeted effector, or all of them off target, every share is 0 and the restart is
the usual one over the whole box.
"""

from __future__ import annotations

import math

from .._jit import jit_leaf
from ..model.layout import (
    ED_ERR_P,
    ED_ERR_R,
    ED_TOL_P,
    ED_TOL_R,
    ED_WP,
    ED_WR,
    EI_ACTIVE,
    EI_MODE,
    EI_NODE,
    MODE_POSITION,
    ND_RATE,
    NI_DOF,
    NI_KIND,
    NI_PARENT,
    NODE_ROTATION,
)
from .kinematics import DD_GSCRATCH, DD_HI, DD_LO, effector_errors, is_last_point


@jit_leaf
def settled_variables(x, data, keep):  # type: ignore[no-untyped-def]
    """keep[i]: the share of the targeted effectors moved by variable i that are on
    target at x (1.0: it moves only effectors on target, or none; 0.0: only effectors
    off target); returns how many free variables (lower < upper) have a share above 0.

    "On target" is the goal measure's test per effector (``kinematics.goal_measure``):
    every judged part's error within its tolerance.
    """
    ni, nd, ei, ed, dd, misc = data
    if not is_last_point(x, dd):
        effector_errors(x, data)  # ED's errors at x (one FK)
    # Count per variable in two passes over the effectors' paths: keep[] first holds
    # the effectors off target a variable moves, then (as 1 / (1 + count), below)
    # the share; g_scratch the effectors on target it moves.
    on = dd[DD_GSCRATCH]
    for i in range(keep.shape[0]):
        keep[i] = 0.0
        on[i] = 0.0
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        off = False
        if ei[e, EI_MODE] == MODE_POSITION or ed[e, ED_WP] > 0.0:
            off = not ed[e, ED_ERR_P] <= ed[e, ED_TOL_P]  # NaN counts as off
        if ei[e, EI_MODE] != MODE_POSITION and ed[e, ED_WR] > 0.0:
            off = off or not ed[e, ED_ERR_R] <= ed[e, ED_TOL_R]
        k = ei[e, EI_NODE]
        while k >= 0:
            d = ni[k, NI_DOF]
            if d >= 0:
                if off:
                    keep[d] += 1.0
                else:
                    on[d] += 1.0
            k = ni[k, NI_PARENT]
    kept = 0
    for i in range(keep.shape[0]):
        moved = keep[i] + on[i]
        keep[i] = 1.0 if moved == 0.0 else on[i] / moved
        if keep[i] > 0.0 and dd[DD_LO, i] < dd[DD_HI, i]:
            kept += 1
    return kept


@jit_leaf
def variable_periods(data, period):  # type: ignore[no-untyped-def]
    """period[i]: 2 pi where every node that variable i drives is a rotation at a whole
    rate (a revolute or continuous joint, an axis of a rotational joint, and mimic
    followers at multiplier +-1, +-2, ...): the pose is the same a full turn on; 0.0
    where one is a translation or a fractional rate. Returns how many are 2 pi."""
    ni, nd, ei, ed, dd, misc = data
    for i in range(period.shape[0]):
        period[i] = -1.0  # not seen yet
    for k in range(ni.shape[0]):
        d = ni[k, NI_DOF]
        if d < 0:
            continue
        rate = nd[k, ND_RATE]
        whole = rate != 0.0 and rate == math.floor(rate)
        if ni[k, NI_KIND] == NODE_ROTATION and whole:
            if period[d] < 0.0:
                period[d] = 2.0 * math.pi
        else:
            period[d] = 0.0
    count = 0
    for i in range(period.shape[0]):
        if period[i] < 0.0:
            period[i] = 0.0
        elif period[i] > 0.0:
            count += 1
    return count
