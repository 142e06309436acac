"""Compiled forward kinematics, the IK objective with its exact gradient, and pose errors.

All functions take the flat arrays of ``chain.CompiledChain`` (bundled, with the
targets and scratch space, in the ``data`` tuple built by ``ik.py``). The gradient
needs no Jacobian matrix: for each effector we walk its ancestors once and
accumulate J^T r column by column (revolute column: a x (p - o) for position and a
for orientation; prismatic: a and 0).

Orientation error is the rotation vector phi = log(R_e R_t^T) (world frame). With
R = exp([phi]) and dR/dt = [w] R, dphi = J_l^-1(phi) w, and phi^T J_l^-1(phi) = phi^T,
so d|phi|^2/dq = 2 phi^T J_w exactly (J_w the angular Jacobian): the same cheap
form as for position, with no approximation of the log map's derivative.
"""

from __future__ import annotations

import math

import numpy as np
from ._jit import jit, jit_inline

from .chain import NODE_ROTATION, NODE_TRANSLATION

# Indices into the data tuple (see ik._problem_data); numba needs literal indices.
D_PARENT = 0
D_PRE = 1
D_KIND = 2
D_AXIS = 3
D_DOF = 4
D_EFF_NODE = 5
D_EFF_TIP = 6
D_EFF_MODE = 7
D_EFF_AIM = 8
D_EFF_W = 9
D_TGT_POS = 10
D_TGT_ROT = 11
D_TGT_DIR = 12
D_EFF_ACTIVE = 13
D_TOL = 14
D_REG = 15
D_Q_REF = 16
D_LO = 17
D_HI = 18
D_WORK_R = 19
D_WORK_T = 20
D_SCRATCH = 21
D_X_LAST = 22
D_MAT = 23  # float64[2, 3, 3] scratch: effector rotation, error rotation
D_VEC = 24  # float64[3, 3] scratch: effector position, rotation vector, position residual
D_ERR = 25  # float64[2, n_eff]: position and rotation error per effector
D_G_SCRATCH = 26  # float64[n]: gradient buffer for value-only re-evaluations

MODE_POSITION = 0
MODE_POSE = 1
MODE_AIM = 2

REG_POSTURE = 0  # weight of sum (q - q_ref)^2
REG_LIMIT = 1  # weight of the limit-margin penalty
REG_MARGIN = 2  # margin as a fraction of each variable's range


@jit
def forward_kinematics(q, parent, pre, kind, axis, dof, out_r, out_t):  # type: ignore[no-untyped-def]
    """World rotation (n_nodes, 3, 3) and origin (n_nodes, 3) of every node for q.

    Allocation-free on purpose: this runs inside the objective, which the core calls
    through a function argument, and numba can neither cache nor cheaply run a
    callee that allocates there.
    """
    for k in range(parent.shape[0]):
        p = parent[k]
        if p < 0:
            for i in range(3):
                for j in range(3):
                    out_r[k, i, j] = pre[k, i, j]
                out_t[k, i] = pre[k, i, 3]
        else:
            for i in range(3):
                p0, p1, p2 = out_r[p, i, 0], out_r[p, i, 1], out_r[p, i, 2]
                for j in range(3):
                    out_r[k, i, j] = p0 * pre[k, 0, j] + p1 * pre[k, 1, j] + p2 * pre[k, 2, j]
                out_t[k, i] = p0 * pre[k, 0, 3] + p1 * pre[k, 1, 3] + p2 * pre[k, 2, 3] + out_t[p, i]
        d = dof[k]
        if d < 0:
            continue
        if kind[k] == NODE_ROTATION:
            # out_r[k] <- out_r[k] @ Rot(axis, q) (Rodrigues).
            ux, uy, uz = axis[k, 0], axis[k, 1], axis[k, 2]
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
                a0, a1, a2 = out_r[k, i, 0], out_r[k, i, 1], out_r[k, i, 2]
                out_r[k, i, 0] = a0 * r00 + a1 * r10 + a2 * r20
                out_r[k, i, 1] = a0 * r01 + a1 * r11 + a2 * r21
                out_r[k, i, 2] = a0 * r02 + a1 * r12 + a2 * r22
        elif kind[k] == NODE_TRANSLATION:
            for i in range(3):
                out_t[k, i] += (
                    out_r[k, i, 0] * axis[k, 0] + out_r[k, i, 1] * axis[k, 1] + out_r[k, i, 2] * axis[k, 2]
                ) * q[d]


@jit_inline
def effector_frame(e, node, tip, work_r, work_t, r_out, p_out):  # type: ignore[no-untyped-def]
    """World rotation and position of effector e's tip frame."""
    if node < 0:
        for i in range(3):
            for j in range(3):
                r_out[i, j] = tip[e, i, j]
            p_out[i] = tip[e, i, 3]
        return
    for i in range(3):
        for j in range(3):
            r_out[i, j] = (
                work_r[node, i, 0] * tip[e, 0, j]
                + work_r[node, i, 1] * tip[e, 1, j]
                + work_r[node, i, 2] * tip[e, 2, j]
            )
        p_out[i] = (
            work_r[node, i, 0] * tip[e, 0, 3]
            + work_r[node, i, 1] * tip[e, 1, 3]
            + work_r[node, i, 2] * tip[e, 2, 3]
            + work_t[node, i]
        )


@jit_inline
def rotation_log(r, out):  # type: ignore[no-untyped-def]
    """Rotation vector phi with exp([phi]) = r, |phi| in [0, pi]; returns |phi|."""
    c = 0.5 * (r[0, 0] + r[1, 1] + r[2, 2] - 1.0)
    if c > 1.0:
        c = 1.0
    elif c < -1.0:
        c = -1.0
    vx = 0.5 * (r[2, 1] - r[1, 2])
    vy = 0.5 * (r[0, 2] - r[2, 0])
    vz = 0.5 * (r[1, 0] - r[0, 1])
    s = math.sqrt(vx * vx + vy * vy + vz * vz)
    theta = math.atan2(s, c)
    if theta < 1e-6:
        k = 1.0 + theta * theta / 6.0  # theta / sin(theta), series
        out[0] = vx * k
        out[1] = vy * k
        out[2] = vz * k
    elif theta < math.pi - 1e-4:
        k = theta / s
        out[0] = vx * k
        out[1] = vy * k
        out[2] = vz * k
    else:
        # Near pi, sin(theta) carries no axis information: use (R + I) / 2 ~ a a^T.
        best = 0
        for i in range(1, 3):
            if r[i, i] > r[best, best]:
                best = i
        col0 = 0.5 * (r[0, best] + (1.0 if best == 0 else 0.0))
        col1 = 0.5 * (r[1, best] + (1.0 if best == 1 else 0.0))
        col2 = 0.5 * (r[2, best] + (1.0 if best == 2 else 0.0))
        norm = math.sqrt(col0 * col0 + col1 * col1 + col2 * col2)
        ax, ay, az = col0 / norm, col1 / norm, col2 / norm
        if ax * vx + ay * vy + az * vz < 0.0:
            ax, ay, az = -ax, -ay, -az
        out[0] = ax * theta
        out[1] = ay * theta
        out[2] = az * theta
    return theta


@jit_inline
def _effector_terms(q, g, need_grad, data, pos_err, rot_err):  # type: ignore[no-untyped-def]
    """Pose part of f (and of g); fills per-effector errors [m] and [rad]."""
    parent = data[D_PARENT]
    kind = data[D_KIND]
    axis = data[D_AXIS]
    dof = data[D_DOF]
    eff_node = data[D_EFF_NODE]
    tip = data[D_EFF_TIP]
    mode = data[D_EFF_MODE]
    aim = data[D_EFF_AIM]
    weights = data[D_EFF_W]
    tgt_pos = data[D_TGT_POS]
    tgt_rot = data[D_TGT_ROT]
    tgt_dir = data[D_TGT_DIR]
    active = data[D_EFF_ACTIVE]
    work_r = data[D_WORK_R]
    work_t = data[D_WORK_T]
    forward_kinematics(q, parent, data[D_PRE], kind, axis, dof, work_r, work_t)
    mats = data[D_MAT]
    vecs = data[D_VEC]
    re = mats[0]
    rerr = mats[1]
    pe = vecs[0]
    phi = vecs[1]
    rp = vecs[2]
    f = 0.0
    for e in range(eff_node.shape[0]):
        pos_err[e] = 0.0
        rot_err[e] = 0.0
        if active[e] == 0:
            continue
        node = eff_node[e]
        effector_frame(e, node, tip, work_r, work_t, re, pe)
        wp = weights[e, 0]
        wr = weights[e, 1]
        m = mode[e]
        for i in range(3):
            rp[i] = pe[i] - tgt_pos[e, i]
        pos_err[e] = math.sqrt(rp[0] * rp[0] + rp[1] * rp[1] + rp[2] * rp[2])
        f += wp * pos_err[e] * pos_err[e]
        ax = 0.0
        ay = 0.0
        az = 0.0
        if m == MODE_POSE:
            for i in range(3):
                for j in range(3):
                    rerr[i, j] = (
                        re[i, 0] * tgt_rot[e, j, 0] + re[i, 1] * tgt_rot[e, j, 1] + re[i, 2] * tgt_rot[e, j, 2]
                    )
            rot_err[e] = rotation_log(rerr, phi)
            f += wr * rot_err[e] * rot_err[e]
        elif m == MODE_AIM:
            ax = re[0, 0] * aim[e, 0] + re[0, 1] * aim[e, 1] + re[0, 2] * aim[e, 2]
            ay = re[1, 0] * aim[e, 0] + re[1, 1] * aim[e, 1] + re[1, 2] * aim[e, 2]
            az = re[2, 0] * aim[e, 0] + re[2, 1] * aim[e, 1] + re[2, 2] * aim[e, 2]
            dx = ax - tgt_dir[e, 0]
            dy = ay - tgt_dir[e, 1]
            dz = az - tgt_dir[e, 2]
            f += wr * (dx * dx + dy * dy + dz * dz)
            # Gradient of |a - d|^2 along an angular velocity w is 2 w . (a x (a - d)).
            phi[0] = ay * dz - az * dy
            phi[1] = az * dx - ax * dz
            phi[2] = ax * dy - ay * dx
            cosang = ax * tgt_dir[e, 0] + ay * tgt_dir[e, 1] + az * tgt_dir[e, 2]
            cosang = min(1.0, max(-1.0, cosang))
            rot_err[e] = math.acos(cosang)
        if not need_grad:
            continue
        use_rot = m == MODE_POSE or m == MODE_AIM  # phi holds this effector's rotation term
        k = node
        while k >= 0:
            d = dof[k]
            if d >= 0:
                # World axis of node k's motion: R_k a (a rotation leaves its own axis fixed).
                wx = work_r[k, 0, 0] * axis[k, 0] + work_r[k, 0, 1] * axis[k, 1] + work_r[k, 0, 2] * axis[k, 2]
                wy = work_r[k, 1, 0] * axis[k, 0] + work_r[k, 1, 1] * axis[k, 1] + work_r[k, 1, 2] * axis[k, 2]
                wz = work_r[k, 2, 0] * axis[k, 0] + work_r[k, 2, 1] * axis[k, 1] + work_r[k, 2, 2] * axis[k, 2]
                if kind[k] == NODE_ROTATION:
                    lx = pe[0] - work_t[k, 0]
                    ly = pe[1] - work_t[k, 1]
                    lz = pe[2] - work_t[k, 2]
                    jx = wy * lz - wz * ly
                    jy = wz * lx - wx * lz
                    jz = wx * ly - wy * lx
                    grad = 2.0 * wp * (jx * rp[0] + jy * rp[1] + jz * rp[2])
                    if use_rot:
                        grad += 2.0 * wr * (wx * phi[0] + wy * phi[1] + wz * phi[2])
                    g[d] += grad
                else:
                    g[d] += 2.0 * wp * (wx * rp[0] + wy * rp[1] + wz * rp[2])
            k = parent[k]
    return f


@jit_inline
def _regularisation(q, g, need_grad, data):  # type: ignore[no-untyped-def]
    """Posture pull towards q_ref and a penalty inside each limit's margin band.

    The limit term is zero in the interior and quadratic within ``margin`` x range
    of a limit, so it only acts on a joint drifting towards its stop (C1-smooth).
    """
    reg = data[D_REG]
    w_post = reg[REG_POSTURE]
    w_lim = reg[REG_LIMIT]
    if w_post == 0.0 and w_lim == 0.0:
        return 0.0
    q_ref = data[D_Q_REF]
    lo = data[D_LO]
    hi = data[D_HI]
    margin = reg[REG_MARGIN]
    f = 0.0
    for i in range(q.shape[0]):
        if w_post != 0.0:
            dq = q[i] - q_ref[i]
            f += w_post * dq * dq
            if need_grad:
                g[i] += 2.0 * w_post * dq
        if w_lim != 0.0 and math.isfinite(lo[i]) and math.isfinite(hi[i]):
            band = margin * (hi[i] - lo[i])
            below = lo[i] + band - q[i]
            above = q[i] - (hi[i] - band)
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
def _goal_measure(data, pos_err, rot_err):  # type: ignore[no-untyped-def]
    """max over effectors of error / tolerance: <= 1 exactly when the IK succeeded."""
    tol = data[D_TOL]
    mode = data[D_EFF_MODE]
    weights = data[D_EFF_W]
    active = data[D_EFF_ACTIVE]
    worst = 0.0
    for e in range(pos_err.shape[0]):
        if active[e] == 0:
            continue
        if mode[e] == MODE_POSITION or weights[e, 0] > 0.0:
            v = pos_err[e] / tol[e, 0]
            if v > worst:
                worst = v
        if mode[e] != MODE_POSITION and weights[e, 1] > 0.0:
            v = rot_err[e] / tol[e, 1]
            if v > worst:
                worst = v
    return worst


@jit
def ik_objective(q, g, need_grad, data):  # type: ignore[no-untyped-def]
    """f(q) = sum_e w_p |p_e - t_e|^2 + w_r |rot err_e|^2 + posture + limit margin."""
    errs = data[D_ERR]
    pos_err = errs[0]
    rot_err = errs[1]
    if need_grad:
        for i in range(g.shape[0]):
            g[i] = 0.0
    f = _effector_terms(q, g, need_grad, data, pos_err, rot_err)
    f += _regularisation(q, g, need_grad, data)
    # Remember the goal measure for this q so the goal test needs no second FK.
    scratch = data[D_SCRATCH]
    x_last = data[D_X_LAST]
    scratch[0] = _goal_measure(data, pos_err, rot_err)
    for i in range(q.shape[0]):
        x_last[i] = q[i]
    return f


@jit
def ik_goal(f, q, data):  # type: ignore[no-untyped-def]
    """Normalised pose error at q (cached from the last objective call when q matches)."""
    x_last = data[D_X_LAST]
    same = True
    for i in range(q.shape[0]):
        if q[i] != x_last[i]:
            same = False
            break
    if not same:
        ik_objective(q, data[D_G_SCRATCH], False, data)
    return data[D_SCRATCH][0]


@jit
def effector_errors(q, data, pos_err, rot_err):  # type: ignore[no-untyped-def]
    """Per-effector position [m] and orientation [rad] errors at q; returns the goal measure."""
    _effector_terms(q, data[D_G_SCRATCH], False, data, pos_err, rot_err)
    return _goal_measure(data, pos_err, rot_err)
