"""Vectors and quaternions of the JSON contract as the solver's arrays.

Shared by chains (joint origins, effector tips), targets and the fast path, so that
the three build the same rotation for the same quaternion (tests/service/test_convert.py
checks the convention against ``solver.chain.quaternion_to_matrix``); and the effector
of a hierarchy chain or a skeleton's bone, whose tip frames are such vectors.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

import schemas as S
from solver.arrays import Vector
from solver.model import Effector, EffectorMode

from ..errors import invalid_problem

# A 3x3 rotation matrix as nine plain floats, row after row.
Flat9 = tuple[float, float, float, float, float, float, float, float, float]


def vec3(v: S.Vec3) -> Vector:
    """The vector as an array, shape (3,)."""
    return np.array((v.x, v.y, v.z), dtype=np.float64)


def rotation_matrix(q: S.Quaternion) -> Vector:
    """Rotation matrix of the normalised quaternion, shape (3, 3)."""
    return np.array(rotation_rows(q.w, q.x, q.y, q.z)).reshape(3, 3)


def rotation_rows(qw: float, qx: float, qy: float, qz: float) -> Flat9:
    """Rotation matrix of the normalised quaternion (w, x, y, z), row after row as
    plain floats: this is per frame, and the fast path packs them into the target's
    row as they are."""
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, x, y, z = qw / n, qx / n, qy / n, qz / n
    return (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )  # fmt: skip


def effector(e: S.EffectorSpec | S.BoneEffectorSpec, *, name: str, link: str) -> Effector:
    """The solver's effector for an effector spec: a hierarchy chain's (on a link) or a
    skeleton's (on a bone); the two differ only in how they name the effector's link."""
    return Effector(
        name=name,
        link=link,
        tip_offset=vec3(e.tip_offset),
        tip_rotation=rotation_matrix(e.tip_rotation),
        mode=EffectorMode(e.mode),
        aim_axis=vec3(e.aim_axis),
        position_weight=e.position_weight,
        rotation_weight=e.rotation_weight,
    )


def effectors_of(
    specs: Sequence[S.EffectorSpec | S.BoneEffectorSpec], limit: int
) -> list[Effector]:
    """The solver's effectors of a chain's effector specs (at most ``limit``,
    IK_MAX_EFFECTORS), their names checked unique.

    Targets name an effector, so two of one name would be ambiguous. The later one is
    refused, at the field that gave it its name: ``name``, or ``bone`` for a skeleton's
    effector without one (it is named after its bone: two on one bone need names).
    """
    if len(specs) > limit:
        raise invalid_problem(
            f"too many effectors: {len(specs)} > {limit} (IK_MAX_EFFECTORS)", "chain.effectors"
        )
    made: list[Effector] = []
    first: dict[str, int] = {}
    for i, e in enumerate(specs):
        if isinstance(e, S.BoneEffectorSpec):
            link, by_bone = e.bone, e.name is None
            name = e.bone if e.name is None else e.name
        else:
            name, link, by_bone = e.name, e.link, False
        if name in first:
            advice = "; an effector without a name is named after its bone: name one"
            advice = advice if by_bone else ""
            raise invalid_problem(
                f"duplicate effector name {name!r}: chain.effectors[{first[name]}] has it{advice}",
                f"chain.effectors[{i}].{'bone' if by_bone else 'name'}",
            )
        first[name] = i
        made.append(effector(e, name=name, link=link))
    return made
