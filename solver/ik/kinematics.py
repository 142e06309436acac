"""The IK objective with its exact gradient, the goal measure and pose errors (compiled).

Data layout. Everything a solve needs travels in one tuple of six arrays, built by
``IKSolver`` (``solver.py``): (NI, ND, EI, ED, DD, MISC). Few arrays because every
array crossing a compiled call boundary costs reference counting, and numba's
dispatcher type-checks each one. NI, ND, EI and ED are the chain's compiled arrays
(columns in ``solver.model.layout``; ED's target, tolerance and error columns are
written here and by the solver); DD and MISC are the IK's own:

    DD  float64[12 + n // 2, n]  reference pose, lower, upper, last q evaluated,
                              gradient scratch, 6 rows of Jacobian scratch, rest pose,
                              then n // 2 rows for several effectors' stacked Jacobian
    MISC float64[8 (+ pole block)]  posture weight, limit weight, limit margin, goal
                              measure of the last q evaluated, damping floor,
                              f of the last q evaluated, damping scale, polish
                              steps; then, in an IKSolver's, the pole block
                              (``pole_term``)

The gradient needs no Jacobian matrix: for each effector we walk its ancestors once
and accumulate J^T r column by column (revolute column: a x (p - o) for position and
a for orientation; prismatic: a and 0).

Orientation error is the rotation vector phi = log(R_e R_t^T) (world frame). With
R = exp([phi]) and dR/dt = [w] R, dphi = J_l^-1(phi) w, and phi^T J_l^-1(phi) = phi^T,
so d|phi|^2/dq = 2 phi^T J_w exactly (J_w the angular Jacobian): the same cheap
form as for position, with no approximation of the log map's derivative.

To add an effector mode: a member of ``solver.model.EffectorMode`` and its
``layout.MODE_*`` code, its error and gradient terms in ``effector_terms`` (and its
rows in ``metric.weighted_jacobian``), what a target must give for it
(``targets.GIVEN_*``, ``solver._NEEDS``) and the rows it adds (``solver._MODE_ROWS``).

The objective, its gradient and the metric allocate nothing (they run thousands of
times per second per session, and are compiled without reference counting,
``_jit.jit_leaf``): their scratch is DD's rows.

Helpers called once per joint may take arrays only where every caller is compiled
without reference counting (``jit_leaf``): elsewhere numba counts every array handed
to a helper (two atomic operations), which was ~40% of a solve.
"""

from __future__ import annotations

import math

from .._jit import jit_inline, jit_leaf
from ..model.forward import axis_and_point_rate, effector_frame, forward_kinematics
from ..model.layout import (
    ED_AIM,
    ED_ERR_P,
    ED_ERR_R,
    ED_TDIR,
    ED_TOL_P,
    ED_TOL_R,
    ED_TPOS,
    ED_TROT,
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
from .pole_term import pole_terms

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


# MISC
MISC_POSTURE = 0
MISC_LIMIT = 1
MISC_MARGIN = 2
MISC_GOAL = 3
MISC_DAMPING = 4  # floor of the Gauss-Newton damping mu
MISC_LAST_F = 5  # f of the last q evaluated (DD_XLAST)
MISC_DAMPING_SCALE = 6  # mu = scale x f (Levenberg-Marquardt damping relative to the error)
MISC_POLISH_STEPS = 7  # IKOptions.polish_steps (``polish``), as a float
MISC_SIZE = 8


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
def effector_terms(q, g, need_grad, ni, nd, ei, ed):  # type: ignore[no-untyped-def]
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
                wx, wy, wz, jx, jy, jz = axis_and_point_rate(nd, ni, k, px, py, pz)
                if ni[k, NI_KIND] == NODE_ROTATION:
                    g[d] += 2.0 * (
                        wp * (jx * rx + jy * ry + jz * rz) + wr * (wx * ox + wy * oy + wz * oz)
                    )
                else:  # a translation turns nothing, and (jx, jy, jz) is its axis
                    g[d] += 2.0 * wp * (jx * rx + jy * ry + jz * rz)
            k = ni[k, NI_PARENT]
    return f


@jit_inline
def regularisation(q, g, need_grad, dd, misc):  # type: ignore[no-untyped-def]
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
def goal_measure(ei, ed):  # type: ignore[no-untyped-def]
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
    f = effector_terms(q, g, need_grad, ni, nd, ei, ed)
    f += regularisation(q, g, need_grad, dd, misc)
    if misc.shape[0] > MISC_SIZE and misc[MISC_SIZE] > 0.0:
        # A frame's shaping pass with poles (pole_term, ik.poles); nd holds q's frames.
        f += pole_terms(q, g, need_grad, ni, nd, misc, MISC_SIZE)
    # Remember the goal measure for this q so the goal test needs no second FK.
    misc[MISC_GOAL] = goal_measure(ei, ed)
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
    effector_terms(q, dd[DD_GSCRATCH], False, ni, nd, ei, ed)
    # nd now holds q's frames but misc/XLAST do not describe q: mark them stale.
    if q.shape[0] > 0:  # an all-fixed chain has no XLAST entry to mark
        dd[DD_XLAST, 0] = math.nan
    return goal_measure(ei, ed)
