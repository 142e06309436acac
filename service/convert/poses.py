"""Poses: a request's ``q`` or ``joints`` -> a full joint vector, and back to JSON."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

import schemas as S
from solver.arrays import Vector

from ..errors import invalid_problem
from .chains import ChainView


def pose_vector(pose: S.PoseIn, view: ChainView, current: Vector, field: str = "") -> Vector:
    """A full q from a PoseIn (``joints`` fills in ``current``), clipped into the limits.
    ``field``: where the pose sits in the request ("" for a request that is the pose).

    Raises:
        ServiceError: ``invalid_problem`` naming ``<field>.q`` (wrong length) or
            ``<field>.joints.<name>`` (no such DOF).
    """
    at = f"{field}." if field else ""
    chain = view.chain
    if pose.q is not None:
        if len(pose.q) != chain.n_dof:
            raise invalid_problem(
                f"q must have {chain.n_dof} values (one per DOF), got {len(pose.q)}", f"{at}q"
            )
        q = np.array(pose.q, dtype=np.float64)
    else:
        assert pose.joints is not None
        q = np.array(current, dtype=np.float64)
        for name, value in pose.joints.items():
            i = view.dof_index.get(name)
            if i is None and name in chain.followers.names:
                k = chain.followers.names.index(name)
                leader = chain.dof_names[int(chain.followers.leader[k])]
                raise invalid_problem(
                    f"{name!r} is a mimic joint: it follows {leader!r}; set {leader!r} instead",
                    f"{at}joints.{name}",
                )
            if i is None:
                raise invalid_problem(
                    f"unknown DOF {name!r} (DOFs: {list(chain.dof_names)})",
                    f"{at}joints.{name}",
                )
            q[i] = value
    return np.clip(q, chain.lower, chain.upper)


def frame_pose(pose: S.PoseIn | None, view: ChainView, field: str) -> Vector | None:
    """A frame's animated ``pose`` as the frame's job carries it: every DOF's value
    clipped into the limits, NaN for a DOF ``joints`` leaves out (it keeps the value the
    session has when the frame is solved: ``Session.start_at``); None without a pose.

    Raises:
        ServiceError: ``invalid_problem`` naming ``<field>.q`` or ``<field>.joints.<name>``.
    """
    if pose is None:
        return None
    return pose_vector(pose, view, np.full(view.chain.n_dof, np.nan), field)


def clipped_dofs(pose: S.PoseIn, view: ChainView) -> list[str]:
    """The DOFs whose value in ``pose`` is outside the limits (``pose_vector`` sets them
    to the nearest limit), in DOF order. Called after ``pose_vector`` accepted it."""
    chain = view.chain
    if pose.q is not None:
        sent = dict(zip(chain.dof_names, pose.q, strict=True))
    else:
        assert pose.joints is not None
        sent = pose.joints
    return [
        name
        for i, name in enumerate(chain.dof_names)
        if name in sent and not chain.lower[i] <= sent[name] <= chain.upper[i]
    ]


def pose_dict(view: ChainView, q: Vector, clipped: Sequence[str] = ()) -> dict[str, Any]:
    """A ``Pose``: q in DOF order, and by name with the mimic joints' values;
    ``clipped``: the DOFs a pose the client sent had outside the limits."""
    values = q.tolist()
    chain = view.chain
    joints = dict(zip(chain.dof_names, values, strict=True))
    followers = chain.followers
    if followers.names:
        joints.update(zip(followers.names, followers.values(q).tolist(), strict=True))
    return {"q": values, "joints": joints, "clipped": list(clipped)}
