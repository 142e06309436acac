"""Forward kinematics: the world frame of every node and effector tip for joint values q.

``forward_kinematics``, ``effector_frame`` and the Jacobian's pieces read from the
frames FK wrote (``world_axis``, ``axis_and_point_rate``) are compiled (numba) and
shared by the IK objective (``solver.ik.kinematics``), its metric and its pole term;
``link_poses`` and ``effector_poses`` are their Python face, 4x4 matrices.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import jit, jit_inline, jit_leaf
from ..arrays import Matrix, Vector
from .chain import Chain
from .layout import (
    EI_NODE,
    ND_AXIS,
    ND_JAXIS,
    ND_PRE,
    ND_R,
    ND_RATE,
    ND_T,
    NI_DOF,
    NI_KIND,
    NI_PARENT,
    NODE_ROTATION,
    NODE_TRANSLATION,
)


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
        # A mimic joint moves by multiplier x its leader's variable (its offset is in
        # the fixed transform); every other joint's rate is 1.
        value = nd[k, ND_RATE] * q[d]
        if ni[k, NI_KIND] == NODE_ROTATION:
            # R <- R @ Rot(axis, value) (Rodrigues).
            c = math.cos(value)
            s = math.sin(value)
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
                ) * value


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
def _rotate(r00, r01, r02, r10, r11, r12, r20, r21, r22, ux, uy, uz):  # type: ignore[no-untyped-def]
    """R u for a row-major R: the world axis of node k's motion is R_k a (a rotation
    leaves its own axis fixed)."""
    return (
        r00 * ux + r01 * uy + r02 * uz,
        r10 * ux + r11 * uy + r12 * uz,
        r20 * ux + r21 * uy + r22 * uz,
    )


@jit_inline
def world_axis(nd, k):  # type: ignore[no-untyped-def]
    """World axis R_k a of node k's motion per unit of its variable, from the frames
    FK wrote into ND (a is the Jacobian's axis, ``layout.ND_JAXIS``: a mimic joint
    moves multiplier x as fast as its leader's variable, so its column is scaled by
    it, and adds to the leader's column). Takes the array: every caller is compiled
    without reference counting (jit_leaf), so passing it costs nothing."""
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
        nd[k, ND_JAXIS],
        nd[k, ND_JAXIS + 1],
        nd[k, ND_JAXIS + 2],
    )


@jit_inline
def axis_and_point_rate(nd, ni, k, px, py, pz):  # type: ignore[no-untyped-def]
    """Node k's world axis w (``world_axis``) and how fast point p moves per unit of
    k's variable: w x (p - o_k) about k's origin o_k for a rotation, w for a
    translation. The second triple is the position rows of the Jacobian's column for
    p, as the IK objective's gradient, the metric and the pole term all need it."""
    wx, wy, wz = world_axis(nd, k)
    if ni[k, NI_KIND] == NODE_ROTATION:
        lx = px - nd[k, ND_T]
        ly = py - nd[k, ND_T + 1]
        lz = pz - nd[k, ND_T + 2]
        return wx, wy, wz, wy * lz - wz * ly, wz * lx - wx * lz, wx * ly - wy * lx
    return wx, wy, wz, wx, wy, wz


@jit
def effector_frame_py(e, ei, ed, nd):  # type: ignore[no-untyped-def]
    """``effector_frame`` callable from Python (inline-only functions are not)."""
    return effector_frame(e, ei, ed, nd)


def node_frames(chain: Chain, q: Vector) -> np.ndarray:
    """The compiled chain's node array (``layout.ND_*``) with every node's world frame
    for joint values q: what ``link_poses`` reads, for callers that need the nodes'
    axes (``ik.poles``)."""
    cc = chain.compiled
    nd = cc.nd.copy()
    qa = np.ascontiguousarray(q, dtype=np.float64).reshape(-1)
    if qa.shape != (chain.n_dof,):
        raise ValueError(f"q must have {chain.n_dof} values, got {qa.shape[0]}")
    forward_kinematics(qa, cc.ni, nd)
    return nd


def link_poses(chain: Chain, q: Vector) -> dict[str, Matrix]:
    """World pose (4x4, base = root link frame) of every link for joint values q."""
    nd = node_frames(chain, q)
    out: dict[str, Matrix] = {}
    for link, node in chain.compiled.link_node.items():
        m = np.eye(4)
        if node >= 0:
            m[:3, :3] = nd[node, ND_R : ND_R + 9].reshape(3, 3)
            m[:3, 3] = nd[node, ND_T : ND_T + 3]
        out[link] = m
    return out


def effector_poses(chain: Chain, q: Vector) -> list[Matrix]:
    """World pose (4x4) of each effector's tip frame, in ``chain.effectors`` order."""
    nd = node_frames(chain, q)
    cc = chain.compiled
    out = []
    for e in range(len(chain.effectors)):
        frame = effector_frame_py(e, cc.ei, cc.ed, nd)
        m = np.eye(4)
        m[:3, :3] = np.array(frame[:9]).reshape(3, 3)
        m[:3, 3] = frame[9:]
        out.append(m)
    return out
