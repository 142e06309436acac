"""The judges of bench/character_tracking.py: how close each answer is, how far it
moved from the last one (as joint variables and as bone rotations), and what a pose
looked like around a pop."""

from __future__ import annotations

import math

import numpy as np

from solver.model import EffectorMode
from solver.model.forward import effector_poses
from solver.model.skeleton import SkeletonChain


def effector_frames(built: SkeletonChain, qs: np.ndarray) -> np.ndarray:
    """Shape (frames, n_effectors, 4, 4): every effector's world pose per frame."""
    return np.array([effector_poses(built.chain, q) for q in qs])


def within_tolerance(
    built: SkeletonChain,
    qs: np.ndarray,
    targets: np.ndarray,
    position_m: float,
    rotation_rad: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, whether every effector of the answer (our FK) is within the
    tolerances of its target (``targets``: ``effector_frames`` of the reference;
    rotations are judged on POSE effectors only), and the largest position error [m]."""
    got = effector_frames(built, qs)
    position = np.linalg.norm(got[:, :, :3, 3] - targets[:, :, :3, 3], axis=2)
    ok: np.ndarray = (position <= position_m).all(axis=1)
    pose = [i for i, e in enumerate(built.chain.effectors) if e.mode is EffectorMode.POSE]
    if pose:
        r = np.einsum("fekj,fekl->fejl", targets[:, pose, :3, :3], got[:, pose, :3, :3])
        cos = np.clip(0.5 * (np.trace(r, axis1=2, axis2=3) - 1.0), -1.0, 1.0)
        ok &= (np.arccos(cos) <= rotation_rad).all(axis=1)
    return ok, position.max(axis=1)


def joint_steps(start: np.ndarray, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the largest |change| of a variable from the previous answer (the
    first frame's from ``start``) and which variable it was."""
    d = np.abs(np.diff(np.vstack([start, qs]), axis=0))
    return d.max(axis=1), d.argmax(axis=1)


def bone_rotations(built: SkeletonChain, start: np.ndarray, qs: np.ndarray) -> np.ndarray:
    """Shape (frames + 1, n_moving, 4): the moving bones' local rotations at ``start``
    and at each answer."""
    return np.array([built.local_rotations(q) for q in np.vstack([start, qs])])


def bone_steps(quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the largest angle [rad] of a bone's relative rotation from the
    previous frame (what a game shows: a full turn of a variable is no step) and which
    moving bone it was."""
    dot = np.abs(np.sum(quats[1:] * quats[:-1], axis=2))
    angle = 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))
    return angle.max(axis=1), angle.argmax(axis=1)


def describe_pop(
    built: SkeletonChain, before: np.ndarray, after: np.ndarray, ref_before: np.ndarray, var: int
) -> str:
    """The bone of variable ``var`` around a step: its angles before and after, how
    near its middle angle was to +-90 deg (gimbal lock), how near a limit, the bone's
    rotation over the step, and how far the answer had drifted from the reference."""
    chain = built.chain
    bone = chain.dof_names[var].rpartition(".")[0]
    idx = [i for i, n in enumerate(chain.dof_names) if n.rpartition(".")[0] == bone]
    axes = "".join(chain.dof_names[i].rpartition(".")[2] for i in idx)
    row = built.moving.index(bone)
    qa, qb = built.local_rotations(before)[row], built.local_rotations(after)[row]
    turn = 2.0 * math.acos(min(1.0, abs(float(qa @ qb))))
    parts = [
        f"{chain.dof_names[var]} {before[var]:+.3f} -> {after[var]:+.3f} rad",
        f"{bone} ({axes}) before [{', '.join(f'{before[i]:+.3f}' for i in idx)}] after "
        f"[{', '.join(f'{after[i]:+.3f}' for i in idx)}]",
        f"bone turned {turn:.3f} rad",
    ]
    if len(idx) == 3:
        middle = before[idx[1]]
        gimbal = abs(abs(math.remainder(middle, math.pi)) - 0.5 * math.pi)
        parts.append(f"middle angle {gimbal:.3f} rad from +-90 deg")
    room = min(float(before[var] - chain.lower[var]), float(chain.upper[var] - before[var]))
    parts.append(f"{room:.3f} rad from a limit")
    parts.append(f"{float(np.abs(before - ref_before).max()):.3f} rad from the reference before")
    return "; ".join(parts)
