"""Blend weights strictly between 0 and 1: the goal a fraction of the way to the target.

A game blends IK in and out by weight (Unreal's IK Rig goal alpha, Final IK's
``IKPositionWeight``): at weight w the effector is sent the fraction w of the way from
where it is to its target. Here "where it is" is the tip at the frame's start pose
(the seed: a stream's previous answer, a one-shot solve's seed), so

    position   p = p0 + w (t - p0)
    rotation   R = R0 exp(w log(R0^T Rt))      (slerp from R0 towards Rt)
    direction  d = slerp(d0, dt, w)            (d0: the aim axis at the start)

The part keeps w times the model's weight in the objective (``task``), so the pull
fades to nothing as w goes to 0 (at weight 0 the part is free: it pulls nothing, and a
target that pulls nothing leaves its limb where it was, ``task``).

A frame with such parts is solved by ``solve_blended``: first as if every part were
exact (the usual tolerances, no random restarts: the optimizer aims at the in-between
goals); if that does not solve it (an in-between goal out of reach, say), once more
from that answer with the soft parts' tolerances infinite, so that only full-weight
parts decide success (and the random restarts serve those alone). In a stream the start pose is the
previous answer, so a weight held below 1 frame after frame eases the effector onto
its target (each frame covers that fraction of the remaining distance); a client that
wants a fixed mix of an animated pose and the IK answer sends that pose as the seed
(one-shot solves) or ramps the weight to 1.

Pure Python on the loaded task's rows; runs only for frames with such a weight.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ..arrays import Matrix, Vector
from ..model import Chain, EffectorMode
from ..model.forward import forward_kinematics
from ..model.layout import ED_TIP, ED_TOL_P, ED_TOL_R, EI_NODE, ND_R, ND_T
from ..optim import codes as C
from .frame import STATUS_SOLVED, TARGETS_OK
from .targets import GIVEN_DIRECTION, GIVEN_POSITION, GIVEN_ROTATION

# ``frame.solve_frame``'s answer: (bad target, status, termination code, iterations,
# evaluations, passes, restarts, seconds).
SolveResult = tuple[int, int, int, int, int, int, int, float]
# A solve of one frame from given arguments (``frame.solve_frame``'s).
FrameCall = Callable[..., SolveResult]


def combined(answer: SolveResult, calls: tuple[SolveResult, ...]) -> SolveResult:
    """``answer`` with the iterations, evaluations, restarts and time of all ``calls``
    (its passes stay its own: the pass log in the output block is the answer's)."""
    return (
        answer[0],
        answer[1],
        answer[2],
        sum(r[3] for r in calls),
        sum(r[4] for r in calls),
        answer[5],
        sum(r[6] for r in calls),
        sum(r[7] for r in calls),
    )


def solve_blended(call: FrameCall, *args: Any, relax_soft_parts: Callable[[], None]) -> SolveResult:
    """``call(*args)`` (``frame.solve_frame``'s arguments) for a frame with soft parts
    (see the module docstring)."""
    data, x0, h0, fopt, iopt, policy, out_x, out, step, scratch, ints = args
    if fopt[C.F_F_GOAL] == -math.inf:  # no goal (a pole's shaping pass): nothing to judge
        return call(*args)
    aiming = iopt.copy()
    aiming[C.I_MAX_RESTARTS] = 0
    first = call(data, x0, h0, fopt, aiming, policy, out_x, out, step, scratch, ints)
    if first[0] != TARGETS_OK or first[1] == STATUS_SOLVED:
        return first
    # The tolerances as loaded come back afterwards: a later call of the same frame (a
    # pole's fallback) aims at the soft parts again.
    ed = data[3]
    tolerances = ed[:, ED_TOL_P : ED_TOL_R + 1].copy()
    relax_soft_parts()
    try:
        left = fopt.copy()
        left[C.F_BUDGET] = max(0.0, fopt[C.F_BUDGET] - first[7])
        start = out_x.copy()
        second = call(data, start, h0, left, iopt, policy, out_x, out, step, scratch, ints)
    finally:
        ed[:, ED_TOL_P : ED_TOL_R + 1] = tolerances
    return combined(second, (first, second))


def blend_rows(
    chain: Chain,
    q0: Vector,
    rows: np.ndarray,
    blended: list[tuple[int, float, float, int]],
) -> None:
    """Move each blended effector's target row (in ``rows``, the task's packed target
    rows: position, rotation, direction) towards its tip pose at q0.

    Args:
        chain: The model.
        q0: The frame's start pose.
        rows: One packed target row per effector (written in place).
        blended: (effector index, position weight, rotation weight, GIVEN_* bits)
            per target with a part strictly between 0 and 1 (``Task.blended``).
    """
    # The tips at q0 from one compiled FK (``model.forward.effector_poses`` builds every
    # effector's 4x4 in Python: 4x the time for CesiumMan's four).
    cc = chain.compiled
    nd = cc.nd.copy()
    forward_kinematics(np.ascontiguousarray(q0, dtype=np.float64), cc.ni, nd)
    for i, wp, wr, bits in blended:
        start = _tip_pose(i, cc.ei, cc.ed, nd)
        row = rows[i]
        if bits & GIVEN_POSITION and 0.0 < wp < 1.0:
            row[0:3] = start[:3, 3] + wp * (row[0:3] - start[:3, 3])
        if not 0.0 < wr < 1.0:
            continue
        if bits & GIVEN_ROTATION:
            r0 = start[:3, :3]
            rt = row[3:12].reshape(3, 3)
            row[3:12] = (r0 @ _rotation_power(r0.T @ rt, wr)).reshape(9)
        if bits & GIVEN_DIRECTION and chain.effectors[i].mode is EffectorMode.AIM:
            d0 = start[:3, :3] @ chain.effectors[i].aim_axis
            row[12:15] = _slerp(d0, row[12:15], wr)


def _tip_pose(e: int, ei: np.ndarray, ed: np.ndarray, nd: np.ndarray) -> Matrix:
    """Effector e's tip frame (3x4: rotation, position) from the node frames in nd."""
    tip = ed[e, ED_TIP : ED_TIP + 12].reshape(3, 4)
    node = ei[e, EI_NODE]
    if node < 0:
        return tip.copy()
    r = nd[node, ND_R : ND_R + 9].reshape(3, 3)
    out: Matrix = r @ tip
    out[:, 3] += nd[node, ND_T : ND_T + 3]
    return out


def _rotation_power(r: Matrix, w: float) -> Matrix:
    """exp(w log R): the rotation about R's axis by w times its angle (R orthonormal)."""
    c = min(1.0, max(-1.0, 0.5 * (np.trace(r) - 1.0)))
    v = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    s = float(np.linalg.norm(v))
    theta = math.atan2(s, c)
    if theta < 1e-9:
        return np.eye(3)
    if s > 1e-6:
        axis = v / s
    else:  # near pi: the axis from (R + I) / 2 = a a^T
        m = 0.5 * (r + np.eye(3))
        axis = m[:, int(np.argmax(np.diag(m)))]
        axis = axis / np.linalg.norm(axis)
    angle = w * theta
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    power: Matrix = np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)
    return power


def _slerp(a: Vector, b: Vector, w: float) -> Vector:
    """The unit direction the fraction w of the way from a to b (b any length > 0)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    angle = math.acos(min(1.0, max(-1.0, float(a @ b))))
    if angle < 1e-9:
        return b
    if angle > math.pi - 1e-6:  # opposite: any perpendicular plane; keep a's rotation sense
        perp = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        perp /= np.linalg.norm(perp)
        t = w * angle
        return math.cos(t) * a + math.sin(t) * perp
    s = math.sin(angle)
    return (math.sin((1.0 - w) * angle) * a + math.sin(w * angle) * b) / s
