"""What ``skeleton.chain_from_skeleton`` builds: moving bones, per-bone axes, limits and
terminators, effectors on bones, an optional free root.

The defaults (what a game developer gets when they give no settings) are the decisions
in ``skeleton``'s docstring; ``default_limits`` is its ball joint.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from solver.model import MAX_DOF_HARD, Effector

DEFAULT_AXES = "xyz"


@dataclass(frozen=True, slots=True, kw_only=True)
class BoneSettings:
    """How one moving bone's joint is built.

    Attributes:
        axes: Rotation axes in order (1-3 distinct letters of "xyz"); None for the
            default (see ``skeleton``'s decisions).
        lower, upper: One limit per axis [rad]; None for the default ball ranges.
        terminator: Bones above this one do not move for effectors below it.
    """

    axes: str | None = None
    lower: tuple[float, ...] | None = None
    upper: tuple[float, ...] | None = None
    terminator: bool = False


@dataclass(frozen=True, slots=True, kw_only=True)
class FreeRoot:
    """A root that translates: limits relative to its rest position [m], per x, y, z."""

    lower_m: tuple[float, float, float] = (-10.0, -10.0, -10.0)
    upper_m: tuple[float, float, float] = (10.0, 10.0, 10.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class SkeletonSettings:
    """What ``chain_from_skeleton`` builds.

    Attributes:
        effectors: At least one; each ``link`` is a bone name (tip offset [m] and
            rotation in that bone's frame; a glTF bone's own scale does not apply).
        moving: Names of the bones that move; None for the default (see ``skeleton``'s
            decisions). The others are fixed at their rest transform.
        bones: Per-bone settings, keyed by bone name (moving bones only, except
            ``terminator``, which any bone may carry).
        default_axes: Axes of a moving bone whose source gives no rotation order.
        free_root: Makes the (single) root bone translate; None keeps it in place.
        root_link: Name of the chain's base link (the file's world frame).
        max_dof: Upper bound on the chain's variables.
    """

    effectors: Sequence[Effector]
    moving: Sequence[str] | None = None
    bones: Mapping[str, BoneSettings] = field(default_factory=dict)
    default_axes: str = DEFAULT_AXES
    free_root: FreeRoot | None = None
    root_link: str = "world"
    max_dof: int = MAX_DOF_HARD


def default_limits(axes: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The default ball joint's limits [rad] for these axes (see ``skeleton``'s decisions):
    every axis +-2 pi, a full turn either way from the rest pose.

    Not the Tait-Bryan box (the middle angle of three within +-pi/2): its bound on the
    middle angle lies on the gimbal lock, where the two other axes line up, and is no
    limit of the joint's rotations (just past it, the same rotations continue with the
    other two angles turned by pi). A stream that drove a middle angle to that bound
    stalled there under ``smooth``, up to 8 cm off for up to 1.6 s, on circles a hand of
    walk.bvh or CesiumMan reaches without any large step once the bound is +-pi
    (bench/history/2026-11-29-bvh-euler-wall.md). Nor +-pi on the outer two: an angle
    does not wrap, so a bound at +-pi is a wall too (a knee's pole swung front, back and
    front from the rest pose held the hip's first angle at -pi on the third swing);
    +-2 pi keeps the walls a full turn away, with the same frames, steps and times on
    those circles.
    """
    return tuple(-2 * math.pi for _ in axes), tuple(2 * math.pi for _ in axes)
