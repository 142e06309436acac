"""Compiled forward kinematics, the IK objective with its exact gradient, and pose errors.

Data layout. Everything a solve needs travels in one tuple of six arrays (``IKData``
in ``ik.py`` builds it): few arrays because every array crossing a compiled call
boundary costs reference counting, and numba's dispatcher type-checks each one.

    NI  int64[n_nodes, 3]     parent node (-1: root), kind (0 fixed, 1 rotation,
                              2 translation), variable index (-1: none)
    ND  float64[n_nodes, 27]  fixed transform before the motion (3x4, row-major,
                              0:12), unit axis (12:15), world rotation (15:24, row-
                              major) and origin (24:27) written by FK
    EI  int64[n_eff, 3]       node, mode (0 position, 1 pose, 2 aim), active flag
    ED  float64[n_eff, 36]    tip frame in the link (3x4, 0:12), aim axis (12:15),
                              weights w_p, w_r (15, 16), target position (17:20),
                              target rotation (20:29), target direction (29:32),
                              tolerances (32, 33), last errors [m], [rad] (34, 35)
    DD  float64[12 + n // 2, n]  reference pose, lower, upper, last q evaluated,
                              gradient scratch, 6 rows of Jacobian scratch, rest pose,
                              then n // 2 rows for several effectors' stacked Jacobian
    MISC float64[7]           posture weight, limit weight, limit margin, goal
                              measure of the last q evaluated, damping floor,
                              f of the last q evaluated, damping scale

The gradient needs no Jacobian matrix: for each effector we walk its ancestors once
and accumulate J^T r column by column (revolute column: a x (p - o) for position and
a for orientation; prismatic: a and 0).

Orientation error is the rotation vector phi = log(R_e R_t^T) (world frame). With
R = exp([phi]) and dR/dt = [w] R, dphi = J_l^-1(phi) w, and phi^T J_l^-1(phi) = phi^T,
so d|phi|^2/dq = 2 phi^T J_w exactly (J_w the angular Jacobian): the same cheap
form as for position, with no approximation of the log map's derivative.

The objective, its gradient and the metric allocate nothing (they run thousands of
times per second per session, and are compiled without reference counting,
``_jit.jit_leaf``): their scratch is DD's rows.

Helpers called once per joint may take arrays only where every caller is compiled
without reference counting (``jit_leaf``): elsewhere numba counts every array handed
to a helper (two atomic operations), which was ~40% of a solve.
"""

from __future__ import annotations

import math

from ._jit import jit, jit_inline, jit_leaf

# NI columns
NI_PARENT = 0
NI_KIND = 1
NI_DOF = 2
# ND columns
ND_PRE = 0
ND_AXIS = 12
ND_R = 15
ND_T = 24
ND_WIDTH = 27
# EI columns
EI_NODE = 0
EI_MODE = 1
EI_ACTIVE = 2
# ED columns
ED_TIP = 0
ED_AIM = 12
ED_WP = 15
ED_WR = 16
ED_TPOS = 17
ED_TROT = 20
ED_TDIR = 29
ED_TOL_P = 32
ED_TOL_R = 33
ED_ERR_P = 34
ED_ERR_R = 35
ED_WIDTH = 36
# DD rows
DD_QREF = 0
DD_LO = 1
DD_HI = 2
DD_XLAST = 3
DD_GSCRATCH = 4
DD_J = 5  # rows 5..10: one effector's weighted Jacobian (metric)
DD_REST = 11  # rest pose: where a stream's null-space step steers a redundant chain
DD_ROWS = 12
# Rows DD_STACK.. (n // 2 of them): several effectors' Jacobian rows stacked for the
# low-rank metric, which is used only while the task has at most n / 2 rows. Kept in
# DD because the metric is compiled without reference counting and cannot allocate.
DD_STACK = DD_ROWS


def dd_rows(n: int) -> int:
    """Rows of a chain's DD block for n variables."""
    return DD_ROWS + n // 2


# Above this many variables the direct Gauss-Newton metric (O(n^3)) costs more than it
# saves; the low-rank form (at most n / 2 task rows, O(n^2 rows)) is used at any size in
# the solve (the null-space step keeps this limit).
METRIC_MAX_DOF = 64
# MISC
MISC_POSTURE = 0
MISC_LIMIT = 1
MISC_MARGIN = 2
MISC_GOAL = 3
MISC_DAMPING = 4  # floor of the Gauss-Newton damping mu
MISC_LAST_F = 5  # f of the last q evaluated (DD_XLAST)
MISC_DAMPING_SCALE = 6  # mu = scale x f (Levenberg-Marquardt damping relative to the error)
MISC_SIZE = 7

NODE_FIXED = 0
NODE_ROTATION = 1
NODE_TRANSLATION = 2
MODE_POSITION = 0
MODE_POSE = 1
MODE_AIM = 2


@jit_leaf
def forward_kinematics(q, ni, nd):  # type: ignore[no-untyped-def]
    """World rotation and origin of every node for q, written into nd[:, 15:27]."""
    for k in range(ni.shape[0]):
        p = ni[k, NI_PARENT]
        if p < 0:
            for i in range(3):
                for j in range(3):
                    nd[k, ND_R + 3 * i + j] = nd[k, ND_PRE + 4 * i + j]
                nd[k, ND_T + i] = nd[k, ND_PRE + 4 * i + 3]
        else:
            for i in range(3):
                p0 = nd[p, ND_R + 3 * i]
                p1 = nd[p, ND_R + 3 * i + 1]
                p2 = nd[p, ND_R + 3 * i + 2]
                for j in range(3):
                    nd[k, ND_R + 3 * i + j] = (
                        p0 * nd[k, ND_PRE + j]
                        + p1 * nd[k, ND_PRE + 4 + j]
                        + p2 * nd[k, ND_PRE + 8 + j]
                    )
                nd[k, ND_T + i] = (
                    p0 * nd[k, ND_PRE + 3]
                    + p1 * nd[k, ND_PRE + 7]
                    + p2 * nd[k, ND_PRE + 11]
                    + nd[p, ND_T + i]
                )
        d = ni[k, NI_DOF]
        if d < 0:
            continue
        ux = nd[k, ND_AXIS]
        uy = nd[k, ND_AXIS + 1]
        uz = nd[k, ND_AXIS + 2]
        if ni[k, NI_KIND] == NODE_ROTATION:
            # R <- R @ Rot(axis, q) (Rodrigues).
            c = math.cos(q[d])
            s = math.sin(q[d])
            v = 1.0 - c
            r00 = c + ux * ux * v
            r01 = ux * uy * v - uz * s
            r02 = ux * uz * v + uy * s
            r10 = uy * ux * v + uz * s
            r11 = c + uy * uy * v
            r12 = uy * uz * v - ux * s
            r20 = uz * ux * v - uy * s
            r21 = uz * uy * v + ux * s
            r22 = c + uz * uz * v
            for i in range(3):
                a0 = nd[k, ND_R + 3 * i]
                a1 = nd[k, ND_R + 3 * i + 1]
                a2 = nd[k, ND_R + 3 * i + 2]
                nd[k, ND_R + 3 * i] = a0 * r00 + a1 * r10 + a2 * r20
                nd[k, ND_R + 3 * i + 1] = a0 * r01 + a1 * r11 + a2 * r21
                nd[k, ND_R + 3 * i + 2] = a0 * r02 + a1 * r12 + a2 * r22
        elif ni[k, NI_KIND] == NODE_TRANSLATION:
            for i in range(3):
                nd[k, ND_T + i] += (
                    nd[k, ND_R + 3 * i] * ux
                    + nd[k, ND_R + 3 * i + 1] * uy
                    + nd[k, ND_R + 3 * i + 2] * uz
                ) * q[d]


@jit_inline
def effector_frame(e, ei, ed, nd):  # type: ignore[no-untyped-def]
    """World tip frame of effector e: (r00..r22, px, py, pz) as 12 scalars."""
    node = ei[e, EI_NODE]
    if node < 0:
        return (
            ed[e, 0],
            ed[e, 1],
            ed[e, 2],
            ed[e, 4],
            ed[e, 5],
            ed[e, 6],
            ed[e, 8],
            ed[e, 9],
            ed[e, 10],
            ed[e, 3],
            ed[e, 7],
            ed[e, 11],
        )
    a00 = nd[node, ND_R]
    a01 = nd[node, ND_R + 1]
    a02 = nd[node, ND_R + 2]
    a10 = nd[node, ND_R + 3]
    a11 = nd[node, ND_R + 4]
    a12 = nd[node, ND_R + 5]
    a20 = nd[node, ND_R + 6]
    a21 = nd[node, ND_R + 7]
    a22 = nd[node, ND_R + 8]
    b00, b01, b02, b03 = ed[e, 0], ed[e, 1], ed[e, 2], ed[e, 3]
    b10, b11, b12, b13 = ed[e, 4], ed[e, 5], ed[e, 6], ed[e, 7]
    b20, b21, b22, b23 = ed[e, 8], ed[e, 9], ed[e, 10], ed[e, 11]
    return (
        a00 * b00 + a01 * b10 + a02 * b20,
        a00 * b01 + a01 * b11 + a02 * b21,
        a00 * b02 + a01 * b12 + a02 * b22,
        a10 * b00 + a11 * b10 + a12 * b20,
        a10 * b01 + a11 * b11 + a12 * b21,
        a10 * b02 + a11 * b12 + a12 * b22,
        a20 * b00 + a21 * b10 + a22 * b20,
        a20 * b01 + a21 * b11 + a22 * b21,
        a20 * b02 + a21 * b12 + a22 * b22,
        a00 * b03 + a01 * b13 + a02 * b23 + nd[node, ND_T],
        a10 * b03 + a11 * b13 + a12 * b23 + nd[node, ND_T + 1],
        a20 * b03 + a21 * b13 + a22 * b23 + nd[node, ND_T + 2],
    )


@jit_inline
def rotation_log(r00, r01, r02, r10, r11, r12, r20, r21, r22):  # type: ignore[no-untyped-def]
    """Rotation vector phi with exp([phi]) = R, |phi| in [0, pi]: (phi_x, phi_y, phi_z, |phi|)."""
    c = 0.5 * (r00 + r11 + r22 - 1.0)
    c = min(1.0, max(-1.0, c))
    vx = 0.5 * (r21 - r12)
    vy = 0.5 * (r02 - r20)
    vz = 0.5 * (r10 - r01)
    s = math.sqrt(vx * vx + vy * vy + vz * vz)
    theta = math.atan2(s, c)
    if theta < 1e-6:
        k = 1.0 + theta * theta / 6.0  # theta / sin(theta), series
        return vx * k, vy * k, vz * k, theta
    if theta < math.pi - 1e-4:
        k = theta / s
        return vx * k, vy * k, vz * k, theta
    # Near pi, sin(theta) carries no axis information: use (R + I) / 2 ~ a a^T.
    if r00 >= r11 and r00 >= r22:
        ax, ay, az = r00 + 1.0, r10, r20
    elif r11 >= r22:
        ax, ay, az = r01, r11 + 1.0, r21
    else:
        ax, ay, az = r02, r12, r22 + 1.0
    norm = math.sqrt(ax * ax + ay * ay + az * az)
    ax, ay, az = ax / norm, ay / norm, az / norm
    if ax * vx + ay * vy + az * vz < 0.0:
        ax, ay, az = -ax, -ay, -az
    return ax * theta, ay * theta, az * theta, theta


@jit_inline
def _rotate(r00, r01, r02, r10, r11, r12, r20, r21, r22, ux, uy, uz):  # type: ignore[no-untyped-def]
    """R u for a row-major R: the world axis of node k's motion is R_k a (a rotation
    leaves its own axis fixed)."""
    return (
        r00 * ux + r01 * uy + r02 * uz,
        r10 * ux + r11 * uy + r12 * uz,
        r20 * ux + r21 * uy + r22 * uz,
    )


@jit_inline
def _world_axis(nd, k):  # type: ignore[no-untyped-def]
    """World axis R_k a of node k's motion, from the frames FK wrote into ND. Takes
    the array: every caller is compiled without reference counting (jit_leaf), so
    passing it costs nothing."""
    return _rotate(
        nd[k, ND_R],
        nd[k, ND_R + 1],
        nd[k, ND_R + 2],
        nd[k, ND_R + 3],
        nd[k, ND_R + 4],
        nd[k, ND_R + 5],
        nd[k, ND_R + 6],
        nd[k, ND_R + 7],
        nd[k, ND_R + 8],
        nd[k, ND_AXIS],
        nd[k, ND_AXIS + 1],
        nd[k, ND_AXIS + 2],
    )


@jit_inline
def is_last_point(x, dd):  # type: ignore[no-untyped-def]
    """Whether x is the point evaluated last (DD_XLAST): then ND, ED's errors and
    MISC's f and goal describe it, and need not be computed again."""
    for i in range(x.shape[0]):
        if x[i] != dd[DD_XLAST, i]:
            return False
    return True


@jit_inline
def pose_rotation_error(ed, e, r00, r01, r02, r10, r11, r12, r20, r21, r22):  # type: ignore[no-untyped-def]
    """Effector e's orientation error for its frame R: phi = log(R R_t^T) (world
    frame), as (phi_x, phi_y, phi_z, |phi|)."""
    t = ED_TROT
    e00 = r00 * ed[e, t] + r01 * ed[e, t + 1] + r02 * ed[e, t + 2]
    e01 = r00 * ed[e, t + 3] + r01 * ed[e, t + 4] + r02 * ed[e, t + 5]
    e02 = r00 * ed[e, t + 6] + r01 * ed[e, t + 7] + r02 * ed[e, t + 8]
    e10 = r10 * ed[e, t] + r11 * ed[e, t + 1] + r12 * ed[e, t + 2]
    e11 = r10 * ed[e, t + 3] + r11 * ed[e, t + 4] + r12 * ed[e, t + 5]
    e12 = r10 * ed[e, t + 6] + r11 * ed[e, t + 7] + r12 * ed[e, t + 8]
    e20 = r20 * ed[e, t] + r21 * ed[e, t + 1] + r22 * ed[e, t + 2]
    e21 = r20 * ed[e, t + 3] + r21 * ed[e, t + 4] + r22 * ed[e, t + 5]
    e22 = r20 * ed[e, t + 6] + r21 * ed[e, t + 7] + r22 * ed[e, t + 8]
    return rotation_log(e00, e01, e02, e10, e11, e12, e20, e21, e22)


@jit_inline
def _effector_terms(q, g, need_grad, ni, nd, ei, ed):  # type: ignore[no-untyped-def]
    """Pose part of f (and of g); stores each effector's errors in ed[:, 34:36]."""
    forward_kinematics(q, ni, nd)
    f = 0.0
    for e in range(ei.shape[0]):
        ed[e, ED_ERR_P] = 0.0
        ed[e, ED_ERR_R] = 0.0
        if ei[e, EI_ACTIVE] == 0:
            continue
        r00, r01, r02, r10, r11, r12, r20, r21, r22, px, py, pz = effector_frame(e, ei, ed, nd)
        wp = ed[e, ED_WP]
        wr = ed[e, ED_WR]
        mode = ei[e, EI_MODE]
        rx = px - ed[e, ED_TPOS]
        ry = py - ed[e, ED_TPOS + 1]
        rz = pz - ed[e, ED_TPOS + 2]
        dist2 = rx * rx + ry * ry + rz * rz
        ed[e, ED_ERR_P] = math.sqrt(dist2)
        f += wp * dist2
        # (ox, oy, oz): the orientation term's gradient is 2 w_r w . o for angular velocity w.
        ox = 0.0
        oy = 0.0
        oz = 0.0
        if mode == MODE_POSE:
            ox, oy, oz, theta = pose_rotation_error(
                ed, e, r00, r01, r02, r10, r11, r12, r20, r21, r22
            )
            ed[e, ED_ERR_R] = theta
            f += wr * theta * theta
        elif mode == MODE_AIM:
            a = ED_AIM
            ax = r00 * ed[e, a] + r01 * ed[e, a + 1] + r02 * ed[e, a + 2]
            ay = r10 * ed[e, a] + r11 * ed[e, a + 1] + r12 * ed[e, a + 2]
            az = r20 * ed[e, a] + r21 * ed[e, a + 1] + r22 * ed[e, a + 2]
            dx = ax - ed[e, ED_TDIR]
            dy = ay - ed[e, ED_TDIR + 1]
            dz = az - ed[e, ED_TDIR + 2]
            f += wr * (dx * dx + dy * dy + dz * dz)
            # d|a - d|^2/dt = 2 (a - d) . (w x a) = 2 w . (a x (a - d)).
            ox = ay * dz - az * dy
            oy = az * dx - ax * dz
            oz = ax * dy - ay * dx
            cosang = ax * ed[e, ED_TDIR] + ay * ed[e, ED_TDIR + 1] + az * ed[e, ED_TDIR + 2]
            ed[e, ED_ERR_R] = math.acos(min(1.0, max(-1.0, cosang)))
        if not need_grad:
            continue
        k = ei[e, EI_NODE]
        while k >= 0:
            d = ni[k, NI_DOF]
            if d >= 0:
                wx, wy, wz = _world_axis(nd, k)
                if ni[k, NI_KIND] == NODE_ROTATION:
                    lx = px - nd[k, ND_T]
                    ly = py - nd[k, ND_T + 1]
                    lz = pz - nd[k, ND_T + 2]
                    jx = wy * lz - wz * ly
                    jy = wz * lx - wx * lz
                    jz = wx * ly - wy * lx
                    g[d] += 2.0 * (
                        wp * (jx * rx + jy * ry + jz * rz) + wr * (wx * ox + wy * oy + wz * oz)
                    )
                else:
                    g[d] += 2.0 * wp * (wx * rx + wy * ry + wz * rz)
            k = ni[k, NI_PARENT]
    return f


@jit_inline
def _regularisation(q, g, need_grad, dd, misc):  # type: ignore[no-untyped-def]
    """Posture pull towards the reference pose and a penalty inside each limit's margin band.

    The limit term is zero in the interior and quadratic within ``margin`` x range
    of a limit, so it only acts on a joint drifting towards its stop (C1-smooth).
    """
    w_post = misc[MISC_POSTURE]
    w_lim = misc[MISC_LIMIT]
    if w_post == 0.0 and w_lim == 0.0:
        return 0.0
    margin = misc[MISC_MARGIN]
    f = 0.0
    for i in range(q.shape[0]):
        if w_post != 0.0:
            dq = q[i] - dd[DD_QREF, i]
            f += w_post * dq * dq
            if need_grad:
                g[i] += 2.0 * w_post * dq
        lo = dd[DD_LO, i]
        hi = dd[DD_HI, i]
        if w_lim != 0.0 and math.isfinite(lo) and math.isfinite(hi):
            band = margin * (hi - lo)
            below = lo + band - q[i]
            above = q[i] - (hi - band)
            if below > 0.0:
                f += w_lim * below * below
                if need_grad:
                    g[i] -= 2.0 * w_lim * below
            elif above > 0.0:
                f += w_lim * above * above
                if need_grad:
                    g[i] += 2.0 * w_lim * above
    return f


@jit_inline
def _goal_measure(ei, ed):  # type: ignore[no-untyped-def]
    """max over effectors of error / tolerance: <= 1 exactly when the IK succeeded."""
    worst = 0.0
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        if ei[e, EI_MODE] == MODE_POSITION or ed[e, ED_WP] > 0.0:
            worst = max(worst, ed[e, ED_ERR_P] / ed[e, ED_TOL_P])
        if ei[e, EI_MODE] != MODE_POSITION and ed[e, ED_WR] > 0.0:
            worst = max(worst, ed[e, ED_ERR_R] / ed[e, ED_TOL_R])
    return worst


@jit_leaf
def ik_objective(q, g, need_grad, data):  # type: ignore[no-untyped-def]
    """f(q) = sum_e w_p |p_e - t_e|^2 + w_r |rot err_e|^2 + posture + limit margin."""
    ni, nd, ei, ed, dd, misc = data
    if need_grad:
        for i in range(g.shape[0]):
            g[i] = 0.0
    f = _effector_terms(q, g, need_grad, ni, nd, ei, ed)
    f += _regularisation(q, g, need_grad, dd, misc)
    # Remember the goal measure for this q so the goal test needs no second FK.
    misc[MISC_GOAL] = _goal_measure(ei, ed)
    misc[MISC_LAST_F] = f
    for i in range(q.shape[0]):
        dd[DD_XLAST, i] = q[i]
    return f


@jit_inline
def ik_goal(f, q, data):  # type: ignore[no-untyped-def]
    """Normalised pose error at q (cached from the last objective call when q matches)."""
    dd = data[4]
    for i in range(q.shape[0]):
        if q[i] != dd[DD_XLAST, i]:
            ik_objective(q, dd[DD_GSCRATCH], False, data)
            break
    return data[5][MISC_GOAL]


@jit_leaf
def effector_errors(q, data):  # type: ignore[no-untyped-def]
    """Errors at q into ED[:, 34:36]; returns the goal measure."""
    ni, nd, ei, ed, dd, misc = data
    _effector_terms(q, dd[DD_GSCRATCH], False, ni, nd, ei, ed)
    # nd now holds q's frames but misc/XLAST do not describe q: mark them stale.
    if q.shape[0] > 0:  # an all-fixed chain has no XLAST entry to mark
        dd[DD_XLAST, 0] = math.nan
    return _goal_measure(ei, ed)


@jit
def effector_frame_py(e, ei, ed, nd):  # type: ignore[no-untyped-def]
    """``effector_frame`` callable from Python (inline-only functions are not)."""
    return effector_frame(e, ei, ed, nd)


@jit_inline
def _held(qi, gi, lo_i, hi_i):  # type: ignore[no-untyped-def]
    """A variable is frozen, or sits on a bound with the gradient pushing outward
    (scalars: see ``_rotate`` on arrays handed to per-joint helpers)."""
    return lo_i == hi_i or (qi <= lo_i and gi > 0.0) or (qi >= hi_i and gi < 0.0)


@jit_leaf
def ik_metric(q, g, lo, hi, data, h):  # type: ignore[no-untyped-def]
    """The registered metric (see ``_metric``), damped with mu = scale x f + 1e-9."""
    return _metric(q, g, lo, hi, data, h, -1.0)


@jit_inline
def _metric(q, g, lo, hi, data, h, mu_fixed):  # type: ignore[no-untyped-def]
    """Inverse Hessian for the free variables from the exact Jacobian: (2 J^T W J + mu I)^-1.

    BFGS from H = I takes dozens of iterations on a pose problem; seeding a pass (or
    every step, ``metric_every``) with the damped Gauss-Newton metric (Levenberg-
    Marquardt's matrix with mu = s f + 1e-9, s = MISC_DAMPING_SCALE, Sugihara 2011,
    floored at MISC_DAMPING) gives Gauss-Newton steps
    that BFGS can refine. Held variables (frozen, or on a bound with the gradient
    pushing out) are left out of the coupling: the direction then uses the inverse of
    the free block, as a projected Newton method must (Bertsekas 1982), instead of a
    block of the full inverse, which crawled for 1000+ iterations with one joint on
    its limit. Returns False (caller keeps H = I) when the direct O(n^3) form would be
    needed for more than METRIC_MAX_DOF variables.
    """
    ni, nd, ei, ed, dd, misc = data
    n = q.shape[0]
    rows = 0
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] != 0:
            rows += 3 if ei[e, EI_MODE] == MODE_POSITION else 6
    if n > METRIC_MAX_DOF and 2 * rows > n:
        return False
    # The line search has usually just evaluated q: its frames are still in nd.
    if is_last_point(q, dd):
        f = misc[MISC_LAST_F]
    else:
        f = _effector_terms(q, dd[DD_GSCRATCH], False, ni, nd, ei, ed)
        # ND and ED's errors now describe q, not the point in DD_XLAST: mark it stale.
        dd[DD_XLAST, 0] = math.nan
    free = dd[DD_GSCRATCH]  # reused as a 0/1 mask of the free variables
    for i in range(n):
        free[i] = 0.0 if _held(q[i], g[i], lo[i], hi[i]) else 1.0
    if mu_fixed < 0.0:
        mu = max(misc[MISC_DAMPING_SCALE] * f + 1e-9, misc[MISC_DAMPING])
    else:
        mu = mu_fixed
    c = mu + 2.0 * misc[MISC_POSTURE]
    if 2 * rows <= n:
        return _low_rank_metric(ni, nd, ei, ed, dd, free, c, rows, h)
    for i in range(n):
        for j in range(n):
            h[i, j] = 0.0
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        _weighted_jacobian(e, ni, nd, ei, ed, dd)
        for i in range(n):
            if free[i] == 0.0:
                continue
            for j in range(i, n):
                if free[j] == 0.0:
                    continue
                acc = 0.0
                for r in range(6):
                    acc += dd[DD_J + r, i] * dd[DD_J + r, j]
                h[i, j] += 2.0 * acc
                if j != i:
                    h[j, i] += 2.0 * acc
    for i in range(n):
        h[i, i] += c
    return _invert_spd_in_place(h)


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
        _weighted_jacobian(only, ni, nd, ei, ed, dd)
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
        _weighted_jacobian(e, ni, nd, ei, ed, dd)
        k = 3 if ei[e, EI_MODE] == MODE_POSITION else 6
        for r in range(k):
            for i in range(n):
                y[r0 + r, i] = dd[DD_J + r, i] * free[i]
        r0 += k
    return _woodbury_inverse(y, c, h)


@jit_inline
def cholesky_in_place(m, rows):  # type: ignore[no-untyped-def]
    """m's leading rows x rows block (symmetric; its lower triangle is read) <- its
    lower Cholesky factor L, in the lower triangle; False if not positive definite."""
    for j in range(rows):
        s = m[j, j]
        for k in range(j):
            s -= m[j, k] * m[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        m[j, j] = d
        for i in range(j + 1, rows):
            s = m[i, j]
            for k in range(j):
                s -= m[i, k] * m[j, k]
            m[i, j] = s / d
    return True


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
def _weighted_jacobian(e, ni, nd, ei, ed, dd):  # type: ignore[no-untyped-def]
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
            wx, wy, wz = _world_axis(nd, k)
            if ni[k, NI_KIND] == NODE_ROTATION:
                lx = px - nd[k, ND_T]
                ly = py - nd[k, ND_T + 1]
                lz = pz - nd[k, ND_T + 2]
                dd[DD_J, d] += sp * (wy * lz - wz * ly)
                dd[DD_J + 1, d] += sp * (wz * lx - wx * lz)
                dd[DD_J + 2, d] += sp * (wx * ly - wy * lx)
                if mode == MODE_POSE:
                    dd[DD_J + 3, d] += sr * wx
                    dd[DD_J + 4, d] += sr * wy
                    dd[DD_J + 5, d] += sr * wz
                elif mode == MODE_AIM:
                    # d a / dt = w x a
                    dd[DD_J + 3, d] += sr * (wy * az - wz * ay)
                    dd[DD_J + 4, d] += sr * (wz * ax - wx * az)
                    dd[DD_J + 5, d] += sr * (wx * ay - wy * ax)
            else:
                dd[DD_J, d] += sp * wx
                dd[DD_J + 1, d] += sp * wy
                dd[DD_J + 2, d] += sp * wz
        k = ni[k, NI_PARENT]


@jit_inline
def _invert_spd_in_place(m):  # type: ignore[no-untyped-def]
    """m <- m^-1 for a symmetric positive definite m (Cholesky); False if not SPD.

    Allocation-free, as LAPACK's potrf + potri: L goes into the lower triangle, is
    inverted there, and inv(L)^T inv(L) is written column by column into the upper
    triangle (each column's diagonal last: it is the only inv(L) entry that column
    still reads), then mirrored. It runs once per solver iteration; an n x n
    scratch allocation per call cost more than the arithmetic at 6-7 joints.
    """
    n = m.shape[0]
    if not cholesky_in_place(m, n):
        return False
    # inv(L) in place (lower triangle).
    for j in range(n):
        m[j, j] = 1.0 / m[j, j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= m[i, k] * m[k, j]
            m[i, j] = s / m[i, i]
    # (m^-1)[i, j] = sum_{k >= j} inv(L)[k, i] inv(L)[k, j] for i <= j, into the upper
    # triangle; column j's diagonal overwrites inv(L)[j, j], which later columns do
    # not read (they sum over rows k > j only).
    for j in range(n):
        for i in range(j + 1):
            s = 0.0
            for k in range(j, n):
                s += m[k, i] * m[k, j]
            m[i, j] = s
    for j in range(n):
        for i in range(j):
            m[j, i] = m[i, j]
    return True


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
    if not _metric(q, g, lo, hi, data, h, mu):
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
