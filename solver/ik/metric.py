"""The Gauss-Newton metric the IK hands the optimizer, and the null-space step.

- ``ik_metric``: the inverse of the damped Gauss-Newton matrix (2 J^T W J + mu I)^-1
  on the free variables, registered with the IK objective (``optim.objective``): the
  optimizer re-seeds H from it (``IKOptions.metric_every``). Direct for small chains
  (handed over as the matrix's Cholesky factor, except where blocks inverted one by
  one are less work), low-rank
  (Woodbury) while the task has at most n / 2 rows. ``metric_inverse``: the same as
  H itself.
- ``weighted_jacobian``: one effector's sqrt(W)-weighted Jacobian rows (also used by
  the planner's kernels, ``solver.path.kernels``).
- ``null_space_step``: after a solved stream frame, a step towards the rest pose
  within the chain's self-motion.

Compiled (numba) without reference counting: scratch is DD's rows (``kinematics``).
"""

from __future__ import annotations

import math

from .._jit import jit_inline, jit_leaf
from ..model.forward import axis_and_point_rate, effector_frame
from ..model.layout import (
    ED_AIM,
    ED_WP,
    ED_WR,
    EI_ACTIVE,
    EI_MODE,
    EI_NODE,
    MODE_AIM,
    MODE_POSE,
    MODE_POSITION,
    NI_DOF,
    NI_KIND,
    NI_PARENT,
    NODE_ROTATION,
)
from ..optim.codes import METRIC_FACTOR, METRIC_INVERSE, METRIC_NONE
from .kinematics import (
    DD_GSCRATCH,
    DD_HI,
    DD_J,
    DD_LO,
    DD_STACK,
    DD_XLAST,
    MISC_DAMPING,
    MISC_DAMPING_SCALE,
    MISC_LAST_F,
    MISC_POSTURE,
    effector_terms,
    is_last_point,
)
from .spd import (
    block_cubes,
    cholesky_in_place,
    find_blocks,
    invert_blocks,
    invert_spd_in_place,
    join_roots,
)

# Above this many variables the direct Gauss-Newton metric (O(n^3)) costs more than it
# saves; the low-rank form (at most n / 2 task rows, O(n^2 rows)) is used at any size in
# the solve (the null-space step keeps this limit).
METRIC_MAX_DOF = 64


@jit_inline
def is_held(qi, gi, lo_i, hi_i):  # type: ignore[no-untyped-def]
    """A variable is frozen, or sits on a bound with the gradient pushing outward
    (scalars: see ``model.forward.world_axis`` on arrays handed to per-joint helpers)."""
    return lo_i == hi_i or (qi <= lo_i and gi > 0.0) or (qi >= hi_i and gi < 0.0)


@jit_leaf
def ik_metric(q, g, lo, hi, data, h):  # type: ignore[no-untyped-def]
    """The registered metric (see ``_metric``), damped with mu = scale x f + 1e-9; a
    ``codes.MetricKind``: on the direct form, the Cholesky factor of its matrix
    (``METRIC_FACTOR``: the optimizer's step is then two triangular solves, and the
    inverse's other two thirds are done only if H itself is read), unless its
    blocks inverted one by one are less work."""
    return _metric(q, g, lo, hi, data, h, -1.0, True, None)


@jit_leaf
def metric_inverse(q, g, lo, hi, data, h):  # type: ignore[no-untyped-def]
    """``ik_metric`` as the inverse H itself; False where there is none."""
    return _metric(q, g, lo, hi, data, h, -1.0, False, None) != METRIC_NONE


@jit_leaf
def damped_metric_inverse(q, free, lo, hi, data, h, mu):  # type: ignore[no-untyped-def]
    """(2 J^T W J + mu I)^-1 on the variables that ``free`` (0/1) marks, as H itself,
    for a given mu (the polish's Levenberg-Marquardt with its own active set,
    ``polish``); False where there is none."""
    return _metric(q, q, lo, hi, data, h, mu, False, free) != METRIC_NONE


@jit_inline
def _metric(q, g, lo, hi, data, h, mu_fixed, factor, free_given):  # type: ignore[no-untyped-def]
    """Inverse Hessian for the free variables from the exact Jacobian: (2 J^T W J + mu I)^-1.

    BFGS from H = I takes dozens of iterations on a pose problem; seeding a pass (or
    every step, ``metric_every``) with the damped Gauss-Newton metric (Levenberg-
    Marquardt's matrix with mu = s f + 1e-9, s = MISC_DAMPING_SCALE, Sugihara 2011,
    floored at MISC_DAMPING) gives Gauss-Newton steps
    that BFGS can refine. Held variables (frozen, or on a bound with the gradient
    pushing out) are left out of the coupling: the direction then uses the inverse of
    the free block, as a projected Newton method must (Bertsekas 1982), instead of a
    block of the full inverse, which crawled for 1000+ iterations with one joint on
    its limit. Returns what it wrote (``codes.MetricKind``): with ``factor``, the
    direct form's Cholesky factor (unless its blocks are less work); METRIC_NONE (the
    caller keeps H = I) when the direct O(n^3) form would be needed for more than
    METRIC_MAX_DOF variables. ``free_given`` (0/1 per variable) overrides which are
    free (None: those not held).
    """
    ni, nd, ei, ed, dd, misc = data
    n = q.shape[0]
    rows = 0
    active = 0
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] != 0:
            rows += 3 if ei[e, EI_MODE] == MODE_POSITION else 6
            active += 1
    if n > METRIC_MAX_DOF and 2 * rows > n:
        return METRIC_NONE
    # The line search has usually just evaluated q: its frames are still in nd.
    if is_last_point(q, dd):
        f = misc[MISC_LAST_F]
    else:
        f = effector_terms(q, dd[DD_GSCRATCH], False, ni, nd, ei, ed)
        # ND and ED's errors now describe q, not the point in DD_XLAST: mark it stale.
        dd[DD_XLAST, 0] = math.nan
    free = dd[DD_GSCRATCH]  # reused as a 0/1 mask of the free variables
    if free_given is None:  # the usual case: free unless held
        for i in range(n):
            free[i] = 0.0 if is_held(q[i], g[i], lo[i], hi[i]) else 1.0
    else:
        for i in range(n):
            free[i] = free_given[i]
    if mu_fixed < 0.0:
        mu = max(misc[MISC_DAMPING_SCALE] * f + 1e-9, misc[MISC_DAMPING])
    else:
        mu = mu_fixed
    c = mu + 2.0 * misc[MISC_POSTURE]
    if 2 * rows <= n:
        ok = _low_rank_metric(ni, nd, ei, ed, dd, free, c, rows, h)
        return METRIC_INVERSE if ok else METRIC_NONE
    for i in range(n):
        for j in range(n):
            h[i, j] = 0.0
    # An effector's Jacobian is zero outside the variables on its path to the root, so
    # only their pairs are summed: on a tree of many limbs (a humanoid's 9 effectors,
    # 29 variables) each limb's block instead of every n x n pair per effector. The
    # sums are the same, term for term (the pairs skipped add exact zeros). One
    # effector's path is usually the whole chain: listing it cost a single-tip arm's
    # solve 4-5% (bench.ab_core), so it keeps the plain loop.
    listed = active > 1 and dd.shape[0] > DD_STACK  # a row to list the path's variables in
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        weighted_jacobian(e, ni, nd, ei, ed, dd)
        if listed:
            _add_path_pairs(e, ni, ei, dd, free, h)
        else:
            _add_all_pairs(dd, free, h)
    for i in range(n):
        h[i, i] += c
    # From 13 variables (many limbs; an arm's 7 are one block, and finding the blocks
    # cost a single-tip Panda solve 17%), with two rows of DD to list the blocks in:
    # blocks are inverted one by one (g1: 29^3 -> 17^3 + 2 x 6^3), unless the factor
    # of the whole is less work than their inverses (the sum of their cubes / 2). The
    # factor costs n^3 / 6 where the metric is re-seeded every iteration, but n^3 / 2
    # with its completion where BFGS updates come between (by default from as many
    # task rows as variables, ``IKOptions.metric_interval``: g1). A held variable is a
    # block of its own: Tiago's fingertips (27 variables, 18 rows; one block but for
    # the joints on their limits) take the factor. The effectors' paths give the
    # blocks for the price of a walk along them (the search over the n^2 entries was
    # 1.6 us of Tiago's ~9 us iteration): where even those (the matrix's blocks or
    # coarser) make the factor the less work, there is no search.
    if n >= 13 and dd.shape[0] > DD_STACK + 2:
        root = dd[DD_STACK + 1]
        order = dd[DD_STACK + 2]
        weight = 3.0 if rows < n else 1.0  # (sum of cubes / 2) / (factor's cost / n^3)
        if factor and n**3 < weight * _path_block_cubes(ni, ei, free, root, order):
            return METRIC_FACTOR if cholesky_in_place(h, n) else METRIC_NONE
        if find_blocks(h, root) > 1 and not (factor and n**3 < weight * block_cubes(root, order)):
            ok = invert_blocks(h, root, order)
            return METRIC_INVERSE if ok else METRIC_NONE
    if factor:
        return METRIC_FACTOR if cholesky_in_place(h, n) else METRIC_NONE
    return METRIC_INVERSE if invert_spd_in_place(h) else METRIC_NONE


@jit_inline
def _path_block_cubes(ni, ei, free, root, counts):  # type: ignore[no-untyped-def]
    """``spd.block_cubes`` of the blocks that the targeted effectors' paths make (the
    free variables on one path are one block; a held variable, or one on no path, is
    a block of its own): the matrix's own blocks or coarser, where an entry of two
    variables on one path happens to be exactly zero. ``root`` and ``counts`` are
    scratch; root pointers go to smaller indexes, as ``spd.find_blocks``'s."""
    n = root.shape[0]
    for i in range(n):
        root[i] = i
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        first = -1
        k = ei[e, EI_NODE]
        while k >= 0:
            d = ni[k, NI_DOF]
            k = ni[k, NI_PARENT]
            if d < 0 or free[d] == 0.0:
                continue
            if first < 0:
                first = d
            else:
                join_roots(root, first, d)
    for i in range(n):  # root[i] < i is final already: point i straight at it
        root[i] = root[int(root[i])]
    return block_cubes(root, counts)


@jit_inline
def _add_pair(dd, h, i, j):  # type: ignore[no-untyped-def]
    """h[i, j] and h[j, i] += 2 (J^T J)[i, j] for one effector's rows in DD_J (i <= j)."""
    acc = 0.0
    for r in range(6):
        acc += dd[DD_J + r, i] * dd[DD_J + r, j]
    h[i, j] += 2.0 * acc
    if j != i:
        h[j, i] += 2.0 * acc


@jit_inline
def _add_all_pairs(dd, free, h):  # type: ignore[no-untyped-def]
    n = h.shape[0]
    for i in range(n):
        if free[i] == 0.0:
            continue
        for j in range(i, n):
            if free[j] != 0.0:
                _add_pair(dd, h, i, j)


@jit_inline
def _add_path_pairs(e, ni, ei, dd, free, h):  # type: ignore[no-untyped-def]
    """``_add_all_pairs`` over the free variables on effector e's path only, listed
    once each (a mimic leader can move several nodes) in DD's first stacked row."""
    path = dd[DD_STACK]
    count = 0
    k = ei[e, EI_NODE]
    while k >= 0:
        d = ni[k, NI_DOF]
        k = ni[k, NI_PARENT]
        if d < 0 or free[d] == 0.0:
            continue
        seen = False
        for m in range(count):
            if path[m] == d:
                seen = True
                break
        if not seen:
            path[count] = d
            count += 1
    for a in range(count):
        da = int(path[a])
        for b in range(a, count):
            db = int(path[b])
            if da <= db:
                _add_pair(dd, h, da, db)
            else:
                _add_pair(dd, h, db, da)


@jit_leaf
def _low_rank_metric(ni, nd, ei, ed, dd, free, c, rows, h):  # type: ignore[no-untyped-def]
    """h <- (c I + 2 J^T J)^-1 through the rows x rows matrix M = c I + 2 J J^T, for
    a task with at most half as many rows as variables (position-only arms, long
    chains; at 6 rows for 7 variables the direct inverse measured as fast).

    J holds sqrt(W)-weighted rows with the held variables' columns zeroed, so a held
    variable gets 1/c on the diagonal and no coupling, as in the direct path. With
    one targeted effector (the usual case) J stays in DD's Jacobian rows; several
    effectors stack theirs in DD's rows from DD_STACK.
    """
    n = h.shape[0]
    only = -1
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] != 0:
            only = e if only == -1 else -2
    if only >= 0:
        weighted_jacobian(only, ni, nd, ei, ed, dd)
        for r in range(rows):
            for i in range(n):
                dd[DD_J + r, i] *= free[i]
        return _woodbury_inverse(dd[DD_J : DD_J + rows], c, h)
    if dd.shape[0] < DD_STACK + rows:  # a DD block not sized by dd_rows(n)
        return False
    y = dd[DD_STACK : DD_STACK + rows]
    r0 = 0
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        weighted_jacobian(e, ni, nd, ei, ed, dd)
        k = 3 if ei[e, EI_MODE] == MODE_POSITION else 6
        for r in range(k):
            for i in range(n):
                y[r0 + r, i] = dd[DD_J + r, i] * free[i]
        r0 += k
    return _woodbury_inverse(y, c, h)


@jit_leaf
def _woodbury_inverse(y, c, h):  # type: ignore[no-untyped-def]
    """h <- (c I + 2 Y^T Y)^-1 for Y (rows x n, rows <= n / 2); Y is overwritten.

    Woodbury: (c I + 2 J^T J)^-1 = (I - 2 J^T M^-1 J) / c with M = c I + 2 J J^T,
    and with M = L L^T, J^T M^-1 J = Y^T Y for Y = L^-1 J. Costs O(n^2 rows) instead
    of O(n^3): the 40-DOF tail's 40x40 inverse becomes a 3x3 Cholesky and one n x n
    product. L lives in h's top-left rows x rows block until the last loop, which
    reads only Y.
    """
    rows, n = y.shape
    low = h
    for a in range(rows):
        for b in range(a + 1):
            acc = 0.0
            for i in range(n):
                acc += y[a, i] * y[b, i]
            low[a, b] = 2.0 * acc + (c if a == b else 0.0)
    if not cholesky_in_place(low, rows):
        return False
    # Y <- L^-1 J, column by column (forward substitution in place).
    for i in range(n):
        for a in range(rows):
            s = y[a, i]
            for k in range(a):
                s -= low[a, k] * y[k, i]
            y[a, i] = s / low[a, a]
    inv_c = 1.0 / c
    for i in range(n):
        for j in range(i, n):
            acc = 0.0
            for a in range(rows):
                acc += y[a, i] * y[a, j]
            v = ((1.0 if i == j else 0.0) - 2.0 * acc) * inv_c
            h[i, j] = v
            h[j, i] = v
    return True


@jit_inline
def weighted_jacobian(e, ni, nd, ei, ed, dd):  # type: ignore[no-untyped-def]
    """sqrt(W)-weighted Jacobian of effector e into DD rows DD_J..DD_J+5: position
    rows 0-2, orientation (pose) or aim-direction (aim) rows 3-5, zero for position
    mode. The frames in ND must be those of the current q."""
    n = dd.shape[1]
    for r in range(6):
        for i in range(n):
            dd[DD_J + r, i] = 0.0
    r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = effector_frame(e, ei, ed, nd)
    mode = ei[e, EI_MODE]
    sp = math.sqrt(ed[e, ED_WP])
    sr = math.sqrt(ed[e, ED_WR]) if mode != MODE_POSITION else 0.0
    a = ED_AIM
    ax = r00 * ed[e, a] + r01 * ed[e, a + 1] + r02 * ed[e, a + 2]
    ay = r10 * ed[e, a] + r11 * ed[e, a + 1] + r12 * ed[e, a + 2]
    az = r20 * ed[e, a] + r21 * ed[e, a + 1] + r22 * ed[e, a + 2]
    k = ei[e, EI_NODE]
    while k >= 0:
        d = ni[k, NI_DOF]
        if d >= 0:
            wx, wy, wz, jx, jy, jz = axis_and_point_rate(nd, ni, k, px, py, pz)
            dd[DD_J, d] += sp * jx
            dd[DD_J + 1, d] += sp * jy
            dd[DD_J + 2, d] += sp * jz
            if ni[k, NI_KIND] == NODE_ROTATION:
                if mode == MODE_POSE:
                    dd[DD_J + 3, d] += sr * wx
                    dd[DD_J + 4, d] += sr * wy
                    dd[DD_J + 5, d] += sr * wz
                elif mode == MODE_AIM:
                    # d a / dt = w x a
                    dd[DD_J + 3, d] += sr * (wy * az - wz * ay)
                    dd[DD_J + 4, d] += sr * (wz * ax - wx * az)
                    dd[DD_J + 5, d] += sr * (wx * ay - wy * ax)
        k = ni[k, NI_PARENT]


@jit_leaf
def null_space_step(q, data, rest, max_step, out, h, g):  # type: ignore[no-untyped-def]
    """A step towards ``rest`` that leaves the effectors where they are (to first order).

    With A = 2 J^T W J over the targeted effectors, mu (A + mu I)^-1 is the projector
    onto A's null space as mu -> 0 (task directions are shrunk by mu / (2 sigma^2 +
    mu)). Applied to z = rest - q it moves a redundant chain through its self-motion
    towards its rest pose: what keeps a stream of small target moves from drifting the
    arm into its limits or a singularity over hundreds of frames (the classic
    pseudo-inverse drift). The step is scaled so that no variable moves more than
    max_step. Writes q + step (clipped to the limits) into out; False if impossible.
    ``h`` (n x n) and ``g`` (n) are work space (the caller's: nothing is allocated).
    """
    ni, nd, ei, ed, dd, misc = data
    n = q.shape[0]
    if n > METRIC_MAX_DOF:
        return False
    lo = dd[DD_LO]
    hi = dd[DD_HI]
    for i in range(n):
        g[i] = 0.0  # nothing is held by a gradient: only frozen variables stay out
    mu = 1e-6
    if _metric(q, g, lo, hi, data, h, mu, False, None) == METRIC_NONE:
        return False
    big = 0.0
    for i in range(n):
        acc = 0.0
        for j in range(n):
            if lo[j] != hi[j]:
                acc += h[i, j] * (rest[j] - q[j])
        out[i] = mu * acc if lo[i] != hi[i] else 0.0
        big = max(big, abs(out[i]))
    scale = 1.0 if big <= max_step else max_step / big
    for i in range(n):
        v = q[i] + scale * out[i]
        out[i] = min(hi[i], max(lo[i], v))
    return True
