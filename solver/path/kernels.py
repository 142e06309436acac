"""Compiled pieces of the path planner (``planner``, ``programme``, ``keyframes``).

- ``_task_system``: the targeted rows' residual and Jacobian at q (sqrt(W)-weighted, as
  the solver's metric weighs them), after the errors the solver itself reports.
- ``_project``: damped Gauss-Newton from a pose onto the frame's targets, minimum-norm
  (the nearest answer), inside the limits.
- ``frame_nodes``: the answers of one frame the planner chooses from: anchors carried
  onto the frame's targets and, for a task with one free direction, the whole
  self-motion through each of them, walked at a fixed spacing.
- ``dp_step``: one frame of the dynamic programme that picks the path with the smallest
  largest joint step (ties: the smallest sum of squared steps).

They allocate, so they are plain ``jit`` functions (numba's reference counting on),
not ``jit_leaf``; the kinematics they call are shared with the solve and compiled as
their own functions.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import jit, jit_inline
from ..ik.kinematics import (
    DD_GSCRATCH,
    DD_J,
    DD_XLAST,
    effector_terms,
    goal_measure,
    pose_rotation_error,
)
from ..ik.metric import weighted_jacobian
from ..ik.spd import cholesky_in_place
from ..model.forward import effector_frame
from ..model.layout import (
    ED_AIM,
    ED_TDIR,
    ED_TPOS,
    ED_WP,
    ED_WR,
    EI_ACTIVE,
    EI_MODE,
    MODE_AIM,
    MODE_POSE,
    MODE_POSITION,
)

# A node closer than this to a node already found is the same answer (projections of
# two anchors onto a discrete solution land within the Gauss-Newton's accuracy).
SAME_ANSWER = 1e-4
# Largest change of any variable per Gauss-Newton step: keeps a projection from
# leaping across the range near a singularity.
MAX_STEP = 0.3
# Projections stop once every error is below this fraction of its tolerance (the
# next walk step corrects what is left; answers are judged at the tolerance).
TIGHT = 0.05


@jit_inline
def _task_system(q, data, free, r, jac):  # type: ignore[no-untyped-def]
    """Errors at q into ED (the solver's own measure) and the targeted rows' weighted
    residual r and Jacobian jac; returns the number of rows. A position row counts
    when its weight is positive, an orientation (pose) or aim row when the rotation
    weight is; variables that are not free (``free[i] == 0``: locked, or outside every
    targeted chain) get zero columns."""
    ni, nd, ei, ed, dd, misc = data
    effector_terms(q, dd[DD_GSCRATCH], False, ni, nd, ei, ed)
    if q.shape[0] > 0:
        # ND and ED now describe q, not the solver's last point: mark it stale, as
        # effector_errors does.
        dd[DD_XLAST, 0] = math.nan
    n = q.shape[0]
    rows = 0
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = effector_frame(e, ei, ed, nd)
        mode = ei[e, EI_MODE]
        sp = math.sqrt(ed[e, ED_WP])
        sr = math.sqrt(ed[e, ED_WR]) if mode != MODE_POSITION else 0.0
        p0 = rows
        if sp > 0.0:
            r[rows] = sp * (px - ed[e, ED_TPOS])
            r[rows + 1] = sp * (py - ed[e, ED_TPOS + 1])
            r[rows + 2] = sp * (pz - ed[e, ED_TPOS + 2])
            rows += 3
        o0 = rows
        if sr > 0.0 and mode == MODE_POSE:
            ox, oy, oz, _ = pose_rotation_error(ed, e, r00, r01, r02, r10, r11, r12, r20, r21, r22)
            r[rows] = sr * ox
            r[rows + 1] = sr * oy
            r[rows + 2] = sr * oz
            rows += 3
        elif sr > 0.0 and mode == MODE_AIM:
            a = ED_AIM
            ax = r00 * ed[e, a] + r01 * ed[e, a + 1] + r02 * ed[e, a + 2]
            ay = r10 * ed[e, a] + r11 * ed[e, a + 1] + r12 * ed[e, a + 2]
            az = r20 * ed[e, a] + r21 * ed[e, a + 1] + r22 * ed[e, a + 2]
            r[rows] = sr * (ax - ed[e, ED_TDIR])
            r[rows + 1] = sr * (ay - ed[e, ED_TDIR + 1])
            r[rows + 2] = sr * (az - ed[e, ED_TDIR + 2])
            rows += 3
        # The Jacobian as the solver's metric weighs it (DD's Jacobian rows are scratch).
        weighted_jacobian(e, ni, nd, ei, ed, dd)
        for i in range(n):
            if o0 > p0:
                for row in range(3):
                    jac[p0 + row, i] = dd[DD_J + row, i]
            if rows > o0:
                for row in range(3):
                    jac[o0 + row, i] = dd[DD_J + 3 + row, i]
    for i in range(n):
        if free[i] == 0.0:
            for row in range(rows):
                jac[row, i] = 0.0
    return rows


@jit_inline
def _gram_solve(jac, rows, v, gram, y):  # type: ignore[no-untyped-def]
    """y <- (J J^T + lam I)^-1 v for the first ``rows`` rows of J (Cholesky in
    ``gram``, allocation-free: this runs several times per node), with a damping lam
    relative to J's scale (an aim target's 3 rows have rank 2, a singular pose less
    than 6). False if the matrix is not positive definite (non-finite J)."""
    n = jac.shape[1]
    scale = 0.0
    for a in range(rows):
        for b in range(a + 1):
            acc = 0.0
            for i in range(n):
                acc += jac[a, i] * jac[b, i]
            gram[a, b] = acc
        scale = max(scale, gram[a, a])
    lam = 1e-10 * scale + 1e-14
    for a in range(rows):
        gram[a, a] += lam
    if not cholesky_in_place(gram, rows):
        return False
    for a in range(rows):  # L z = v
        s = v[a]
        for k in range(a):
            s -= gram[a, k] * y[k]
        y[a] = s / gram[a, a]
    for a in range(rows - 1, -1, -1):  # L^T y = z
        s = y[a]
        for k in range(a + 1, rows):
            s -= gram[k, a] * y[k]
        y[a] = s / gram[a, a]
    return True


def workspace(rows, n):  # type: ignore[no-untyped-def]
    """Scratch arrays of the kernels below for ``rows`` target rows and n variables:
    residual, Jacobian, Cholesky factor, a rows-vector and two n-vectors."""
    return (
        np.empty(rows),
        np.empty((rows, n)),
        np.empty((rows, rows)),
        np.empty(rows),
        np.empty(n),
        np.empty(n),
    )


_workspace = jit(workspace)


@jit_inline
def _project(q, data, ws, box, max_iter):  # type: ignore[no-untyped-def]
    """Damped Gauss-Newton from q (changed in place) onto the loaded targets: each step
    is the minimum-norm one over the free variables, so q moves to the nearest answer,
    inside the limits (``box``: lower, upper, free). Returns the goal measure at the
    final q (max error / tolerance; <= 1: within tolerance); errors stay in ED, and
    ``ws`` holds the residual and Jacobian at the final q."""
    r, jac, gram, y, dq, _ = ws
    lower, upper, free = box
    n = q.shape[0]
    prev = math.inf
    goal = math.inf
    for it in range(max_iter + 1):
        rows = _task_system(q, data, free, r, jac)
        goal = goal_measure(data[2], data[3])
        if not math.isfinite(goal):
            return math.inf
        # Done when tight, or when within tolerance and no longer improving quickly.
        if goal <= TIGHT or it == max_iter or (goal <= 1.0 and goal > 0.5 * prev):
            return goal
        prev = goal
        if rows == 0 or not _gram_solve(jac, rows, r, gram, y):
            return goal
        big = 0.0
        for i in range(n):
            acc = 0.0
            for a in range(rows):
                acc += jac[a, i] * y[a]
            dq[i] = acc
            big = max(big, abs(acc))
        s = 1.0 if big <= MAX_STEP else MAX_STEP / big
        for i in range(n):
            if free[i] != 0.0:
                q[i] = min(upper[i], max(lower[i], q[i] - s * dq[i]))
    return goal


@jit_inline
def _null_direction(ws, rows, prev, free, out):  # type: ignore[no-untyped-def]
    """The component of ``prev`` in J's null space (J as ``_task_system`` left it in
    ``ws``), scaled to largest entry 1, into ``out``; returns its largest entry before
    scaling (0: none). For a task with one free direction this is the self-motion's
    tangent, oriented as ``prev``. ``out`` may be ``prev`` itself: each entry of prev
    is read before the same entry of out is written, and never after."""
    _, jac, gram, y, _, _ = ws
    jv = ws[0]  # the residual's slot is free here: the caller has used it
    n = prev.shape[0]
    for i in range(n):
        out[i] = prev[i] if free[i] != 0.0 else 0.0
    if rows > 0:
        for a in range(rows):
            acc = 0.0
            for i in range(n):
                acc += jac[a, i] * out[i]
            jv[a] = acc
        if not _gram_solve(jac, rows, jv, gram, y):
            return 0.0
        for i in range(n):
            acc = 0.0
            for a in range(rows):
                acc += jac[a, i] * y[a]
            out[i] -= acc
    big = 0.0
    for i in range(n):
        big = max(big, abs(out[i]))
    if big > 1e-9:
        for i in range(n):
            out[i] /= big
    return big


@jit_inline
def _seed_direction(ws, rows, free, out):  # type: ignore[no-untyped-def]
    """A null direction with no previous one to follow: that of the unit vector with
    the largest null component. False if J has no null space."""
    n = out.shape[0]
    best = 1e-9
    e = np.zeros(n)
    pick = np.zeros(n)
    for i in range(n):
        e[:] = 0.0
        e[i] = 1.0
        size = _null_direction(ws, rows, e, free, pick)
        if size > best:
            best = size
            out[:] = pick
    return best > 1e-9


@jit_inline
def _walk(q0, data, ws, box, spacing, limit, nodes, count):  # type: ignore[no-untyped-def]
    """Append the self-motion through q0 (an answer) to ``nodes`` from ``count``,
    walked ``spacing`` apart (largest variable) on both sides of q0 in turn, each side
    until a limit, a branch point or the loop's closure, and both within ``limit``
    nodes in all: a walk cut short keeps the stretch around q0. Returns the new count.
    """
    r, jac = ws[0], ws[1]
    lo, hi, free = box
    n = q0.shape[0]
    rows = _task_system(q0.copy(), data, free, r, jac)
    first = np.zeros(n)
    if not _seed_direction(ws, rows, free, first):
        nodes[count] = q0
        return count + 1
    room = limit - count - 1
    if room < 0:
        return count
    sides = np.empty((2, room, n))
    counts = np.zeros(2, dtype=np.int64)
    at = np.empty((2, n))  # each side's last node
    tangent = np.empty((2, n))  # and the self-motion's direction there
    active = np.ones(2, dtype=np.bool_)
    for side in range(2):
        at[side] = q0
        tangent[side] = first if side == 0 else -first
    qt = np.empty(n)
    while (active[0] or active[1]) and counts[0] + counts[1] < room:
        for side in range(2):
            if not active[side] or counts[0] + counts[1] >= room:
                continue
            q = at[side]
            v = tangent[side]
            inside = True
            for i in range(n):
                qt[i] = q[i] + spacing * v[i]
                if qt[i] < lo[i] or qt[i] > hi[i]:
                    inside = False
            if not inside or _project(qt, data, ws, box, 12) > 1.0:
                active[side] = False
                continue
            moved = 0.0
            home = 0.0
            for i in range(n):
                moved = max(moved, abs(qt[i] - q[i]))
                home = max(home, abs(qt[i] - q0[i]))
            if moved > 3.0 * spacing or moved < 0.25 * spacing:
                active[side] = False  # jumped to another branch, or stuck at a limit
                continue
            sides[side, counts[side]] = qt
            counts[side] += 1
            at[side] = qt
            if counts[side] > 8 and home < 0.75 * spacing:
                active[:] = False  # went round the loop
                continue
            if counts[0] > 4 and counts[1] > 4:
                meet = 0.0
                for i in range(n):
                    meet = max(meet, abs(at[0, i] - at[1, i]))
                if meet < 1.5 * spacing:
                    active[:] = False  # the two sides met: the loop is closed
                    continue
            # _project's last evaluation was at qt: its Jacobian gives the next tangent.
            if not _null_direction(ws, rows, v, free, tangent[side]) > 1e-9:
                active[side] = False
    for k in range(counts[1] - 1, -1, -1):
        nodes[count] = sides[1, k]
        count += 1
    nodes[count] = q0
    count += 1
    for k in range(counts[0]):
        nodes[count] = sides[0, k]
        count += 1
    return count


@jit
def frame_nodes(anchors, data, box, walk, spacing, limit):  # type: ignore[no-untyped-def]
    """The answers of the loaded targets the planner chooses from: each anchor carried
    onto the targets (Gauss-Newton, minimum-norm) and kept if within tolerance, and
    with ``walk`` (one free direction) the self-motion through it, unless an earlier
    walk already passed within two spacings of it. At most ``limit`` nodes. ``box``:
    (lower, upper, free) — limits, and 1.0 for each variable the targets may move."""
    n = anchors.shape[1]
    nodes = np.empty((limit, n))
    ws = _workspace(6 * data[2].shape[0], n)
    count = 0
    near = 2.0 * spacing if walk else SAME_ANSWER
    for a in range(anchors.shape[0]):
        if count >= limit:
            break
        q = anchors[a].copy()
        if _project(q, data, ws, box, 30) > 1.0:
            continue
        seen = False
        for k in range(count):
            d = 0.0
            for i in range(n):
                d = max(d, abs(nodes[k, i] - q[i]))
            if d < near:
                seen = True
                break
        if seen:
            continue
        if walk:
            count = _walk(q, data, ws, box, spacing, limit, nodes, count)
        else:
            nodes[count] = q
            count += 1
    return nodes[:count].copy()


@jit
def project_onto(q, data, box, max_iter):  # type: ignore[no-untyped-def]
    """``_project`` from Python: q changed in place; returns the goal measure."""
    ws = _workspace(6 * data[2].shape[0], q.shape[0])
    return _project(q, data, ws, box, max_iter)


@jit_inline
def _dp_scan(  # type: ignore[no-untyped-def]
    j, x, reach, keys, order, prev_nodes, prev_worst, prev_sum, nodes, worst, total, back
):
    """``dp_step`` for node j over the previous nodes within ``reach`` along the
    ordering variable (x: node j's value of it)."""
    a = keys.shape[0]
    n = nodes.shape[1]
    below = np.searchsorted(keys, x) - 1
    above = below + 1
    while below >= 0 or above < a:
        gap_below = x - keys[below] if below >= 0 else np.inf
        gap_above = keys[above] - x if above < a else np.inf
        if gap_below <= gap_above:
            i = order[below]
            gap = gap_below
            below -= 1
        else:
            i = order[above]
            gap = gap_above
            above += 1
        if gap > worst[j] or gap > reach:
            break
        w0 = prev_worst[i]
        if w0 > worst[j]:
            continue
        d = 0.0
        for t in range(n):
            dx = abs(nodes[j, t] - prev_nodes[i, t])
            if dx > d:
                d = dx
                if d > worst[j]:
                    break
        w = max(w0, d)
        s = prev_sum[i] + d * d
        if w < worst[j] or (w == worst[j] and s < total[j]):
            worst[j] = w
            total[j] = s
            back[j] = i


@jit
def dp_step(prev_nodes, prev_worst, prev_sum, nodes, window):  # type: ignore[no-untyped-def]
    """For each node of this frame, the best path to it through the previous frame's:
    the smallest largest step (largest change of any variable between consecutive
    frames), then the smallest sum of squared steps. Returns (worst, sum, back).

    The previous nodes are visited in order of their distance along one variable (the
    one that spreads most), nearest first: once that distance alone exceeds the best
    largest step found, no later node can do better, so each node looks at a narrow
    window instead of every previous node. ``window`` narrows it further: a first scan
    stops at that distance, and only a node whose best so far is longer than
    ``window`` is scanned again without it (any better step is longer than
    ``window``, and the scan stops at the best). The largest steps are exact; the
    sum of squares only breaks ties between paths of equal largest step, per node
    (a heuristic: a prefix with a larger largest step but a smaller sum is dropped).
    """
    a = prev_nodes.shape[0]
    b = nodes.shape[0]
    n = nodes.shape[1]
    worst = np.full(b, np.inf)
    total = np.full(b, np.inf)
    back = np.full(b, -1, dtype=np.int64)
    if a == 0 or n == 0:
        return worst, total, back
    axis = 0
    spread = -1.0
    for t in range(n):
        s = prev_nodes[:, t].max() - prev_nodes[:, t].min()
        if s > spread:
            spread = s
            axis = t
    order = np.argsort(prev_nodes[:, axis])
    keys = prev_nodes[order, axis]
    for j in range(b):
        x = nodes[j, axis]
        for reach in (window, np.inf):
            if reach > window and not worst[j] > window:
                break
            _dp_scan(
                j,
                x,
                reach,
                keys,
                order,
                prev_nodes,
                prev_worst,
                prev_sum,
                nodes,
                worst,
                total,
                back,
            )
    return worst, total, back
