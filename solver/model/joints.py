"""The parts a model is built from: joint kinds, effector modes, rigid transforms,
joints and effectors (validated when a ``Chain`` is built, in ``chain``).

The article's model: every object (link) has a local frame relative to its parent,
a pivot it rotates about, a joint of rotational (up to three axes, each with limits)
or sliding kind, optional terminators, and end effectors. We add URDF-style
revolute, continuous and prismatic joints about any unit axis.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..arrays import Matrix, Vector
from ..errors import InvalidModel
from .rotations import quaternion_to_matrix, rpy_to_matrix


class JointKind(enum.StrEnum):
    """How a joint moves its child link."""

    FIXED = "fixed"
    ROTATIONAL = "rotational"  # the article's joint: 1-3 rotations about local x/y/z
    REVOLUTE = "revolute"  # one rotation about any unit axis, with limits
    CONTINUOUS = "continuous"  # revolute without limits
    PRISMATIC = "prismatic"  # sliding along a unit axis, with limits


class EffectorMode(enum.StrEnum):
    """What an effector's target constrains."""

    POSITION = "position"  # the tip point reaches the target position
    POSE = "pose"  # position and full orientation
    AIM = "aim"  # position (if weighted) and a local axis pointing along a direction


def finite_array(
    values: Sequence[float] | Sequence[Sequence[float]] | Vector,
    what: str,
    *,
    joint: str,
    field: str,
) -> Vector:
    arr = np.asarray(values, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise InvalidModel(f"{what} must be finite", joint=joint, field=field)
    return arr


@dataclass(frozen=True, slots=True)
class Transform:
    """A rigid transform: rotation (3x3, orthonormal, det +1) then translation [m]."""

    translation: Vector = field(default_factory=lambda: np.zeros(3))
    rotation: Matrix = field(default_factory=lambda: np.eye(3))

    @classmethod
    def identity(cls) -> Transform:
        return cls()

    @classmethod
    def from_quaternion(
        cls,
        translation: Sequence[float],
        w: float,
        x: float,
        y: float,
        z: float,
        *,
        owner: str = "",
        field_name: str = "rotation",
    ) -> Transform:
        """From a unit quaternion (w, x, y, z); |q| must be 1 within 1e-6."""
        q = finite_array([w, x, y, z], "quaternion", joint=owner, field=field_name)
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > 1e-6:
            raise InvalidModel(
                f"quaternion must have unit norm, got |q| = {norm:.9g}",
                joint=owner,
                field=field_name,
            )
        return cls(_translation(translation, owner), quaternion_to_matrix(q / norm))

    @classmethod
    def from_rpy(
        cls, translation: Sequence[float], roll: float, pitch: float, yaw: float, *, owner: str = ""
    ) -> Transform:
        """From URDF roll-pitch-yaw [rad]: R = Rz(yaw) Ry(pitch) Rx(roll)."""
        r, p, y = finite_array([roll, pitch, yaw], "rpy", joint=owner, field="rpy")
        return cls(_translation(translation, owner), rpy_to_matrix(float(r), float(p), float(y)))

    @classmethod
    def from_matrix34(
        cls, matrix: Sequence[Sequence[float]] | Matrix, *, owner: str = ""
    ) -> Transform:
        """From a 3x4 [R | t] matrix; R must be orthonormal with det +1 within 1e-6."""
        m = finite_array(matrix, "matrix", joint=owner, field="matrix")
        if m.shape != (3, 4):
            raise InvalidModel(f"matrix must be 3x4, got {m.shape}", joint=owner, field="matrix")
        rot = m[:, :3]
        if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0.0:
            raise InvalidModel(
                "matrix rotation part must be orthonormal with determinant +1",
                joint=owner,
                field="matrix",
            )
        return cls(m[:, 3].copy(), rot.copy())

    def as_matrix34(self) -> Matrix:
        out = np.empty((3, 4))
        out[:, :3] = self.rotation
        out[:, 3] = self.translation
        return out


def _translation(values: Sequence[float], owner: str) -> Vector:
    t = finite_array(values, "translation", joint=owner, field="translation")
    if t.shape != (3,):
        raise InvalidModel(
            f"translation must have 3 components, got {t.shape}", joint=owner, field="translation"
        )
    return t


@dataclass(frozen=True, slots=True)
class Mimic:
    """A joint that follows another: its value is ``multiplier * leader + offset``.

    The follower is not a variable of its own: its motion adds to its leader's
    Jacobian column, and its limits narrow the leader's range (URDF ``<mimic>``).
    """

    joint: str  # the leader
    multiplier: float = 1.0
    offset: float = 0.0  # [rad] or [m]


AXIS_VECTORS = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


@dataclass(frozen=True, slots=True, kw_only=True)
class Joint:
    """A joint from ``parent`` link to ``child`` link.

    Attributes:
        name: Unique joint name; single-DOF joints expose one variable of this name,
            rotational joints one per axis named ``f"{name}.{axis}"``.
        parent: Parent link name.
        child: Child link name (each link has at most one parent joint: a tree).
        kind: See ``JointKind``.
        origin: Rest transform of the joint frame in the parent link frame.
        pivot: Point the motion acts about, in the joint frame [m].
        axis: Unit axis for revolute / continuous / prismatic joints.
        axes: Active local axes of a rotational joint, in order, e.g. "zyx".
        lower, upper: One limit per DOF [rad] or [m]; continuous joints use -inf/inf.
        terminator: Joints above this one do not move for chains running through it.
        mimic: Set for a joint that follows another single-DOF joint (``Mimic``): it
            has no variable of its own and is not in ``dof_names``.
    """

    name: str
    parent: str
    child: str
    kind: JointKind
    origin: Transform = field(default_factory=Transform)
    pivot: Vector = field(default_factory=lambda: np.zeros(3))
    axis: Vector = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    axes: str = ""
    lower: tuple[float, ...] = ()
    upper: tuple[float, ...] = ()
    terminator: bool = False
    mimic: Mimic | None = None

    @property
    def dof_names(self) -> tuple[str, ...]:
        if self.kind is JointKind.FIXED or self.mimic is not None:
            return ()
        if self.kind is JointKind.ROTATIONAL:
            return tuple(f"{self.name}.{a}" for a in self.axes)
        return (self.name,)


@dataclass(frozen=True, slots=True, kw_only=True)
class Effector:
    """A named point on a link that a target pulls on.

    Attributes:
        name: Unique effector name (targets refer to it).
        link: Link carrying the effector.
        tip_offset: Tip point in the link frame [m].
        tip_rotation: Orientation of the tip frame in the link frame (pose targets
            and the aim axis are expressed in the tip frame).
        mode: What the target constrains.
        aim_axis: For AIM: the tip-frame axis that must point along the target direction.
        position_weight: Weight of squared position error [1/m^2 relative].
        rotation_weight: Weight of squared orientation error [m^2/rad^2]; 0.1 m
            lever arm by default, i.e. 1 mrad counts like 0.1 mm.
    """

    name: str
    link: str
    tip_offset: Vector = field(default_factory=lambda: np.zeros(3))
    tip_rotation: Matrix = field(default_factory=lambda: np.eye(3))
    mode: EffectorMode = EffectorMode.POSITION
    aim_axis: Vector = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    position_weight: float = 1.0
    rotation_weight: float = 0.01
