"""What a game engine needs: coordinate conventions per session, and bone output
(local rotations, world transforms) in those conventions."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from .chain import Name
from .common import StrictModel

EnginePreset = Literal["unity", "unreal", "godot", "gltf", "threejs", "ros"]
UpAxis = Literal["y", "z"]
Handedness = Literal["right", "left"]
LengthUnit = Literal["m", "cm"]
HARD_MAX_OUTPUT_BONES = 4096


class Conventions(StrictModel):
    """The client's coordinate conventions: targets come in, bone rotations and
    transforms go out in them. A ``preset`` sets all three; a field given beside it
    overrides it; a field given by neither is the chain's native one (glTF and BVH: Y
    up, right-handed, metres; hierarchy, URDF and examples: Z up, right-handed,
    metres). Joint values (``q``, ``joints``), effector tip offsets and per-effector
    errors stay in the chain's own frame and units."""

    preset: EnginePreset | None = Field(
        default=None,
        description="unity (Y up, left, m), unreal (Z up, left, cm), godot / gltf / threejs "
        "(Y up, right, m), ros (Z up, right, m)",
    )
    up: UpAxis | None = Field(default=None, description="The up axis")
    handedness: Handedness | None = Field(
        default=None,
        description="left-handed Y-up mirrors X (as glTFast / UnityGLTF import glTF); "
        "left-handed Z-up swaps Y and Z of glTF's frame (as Unreal's glTF importer)",
    )
    unit: LengthUnit | None = Field(default=None, description="Length unit of positions")


class ConventionsOut(StrictModel):
    """The conventions a session speaks (its ``conventions`` resolved: the preset, the
    fields given, the chain's own for the rest)."""

    up: UpAxis
    handedness: Handedness
    unit_m: float = Field(description="Metres per length unit of positions (0.01: cm)")


class BoneOutput(StrictModel):
    """Which bone data a result carries (skeleton chains: gltf, bvh)."""

    local_rotations: bool = Field(
        default=False,
        description="Each moving bone's local rotation {w,x,y,z} (what the engine's bone "
        "local rotation holds), in the session's conventions",
    )
    world: list[Name] = Field(
        default_factory=list,
        max_length=HARD_MAX_OUTPUT_BONES,
        description="Bones whose world transform (position, rotation) to return",
    )


class _Answer(BaseModel):
    """Base of the answer-only models: not StrictModel subclasses, so that the request
    hints (``service/hints.py``), which read field names off StrictModel's subclasses,
    still know ``position`` as a Vec3 and ``rotation`` as a Quaternion."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True)


class QuaternionOut(_Answer):
    """A unit quaternion (w is the scalar part)."""

    w: float
    x: float
    y: float
    z: float


class Vec3Out(_Answer):
    """A position in the session's conventions."""

    x: float
    y: float
    z: float


class BoneTransformOut(_Answer):
    """A bone's world transform in the session's conventions."""

    position: Vec3Out
    rotation: QuaternionOut


class BonesOut(_Answer):
    """Bone data of a pose."""

    local: dict[str, QuaternionOut] | None = Field(
        default=None, description="Local rotation of each moving bone, by name"
    )
    world: dict[str, BoneTransformOut] | None = Field(
        default=None, description="World transforms of the bones asked for"
    )


class EffectorPoseOut(_Answer):
    """An effector's world pose: the tip frame a target's ``position`` and
    ``orientation`` (or ``direction``) are compared with, in the session's conventions."""

    name: str = Field(description="The effector's name, as targets address it (``effector``)")
    position: Vec3Out = Field(description="The tip point, in the session's frame and unit")
    orientation: QuaternionOut = Field(
        description="The tip frame's orientation {w,x,y,z}, in the session's frame (as a "
        "pose target's ``orientation``)"
    )
    direction: Vec3Out | None = Field(
        default=None,
        description="Aim effectors: the unit direction the aim axis points along, in the "
        "session's frame (as an aim target's ``direction``); null for the other modes",
    )


class FkRequest(StrictModel):
    """Forward kinematics: a pose (``q`` or ``joints``; neither: the session's current
    pose) -> the world pose of every effector and, on skeleton chains, bone data. Does
    not change the session's pose."""

    q: list[float] | None = Field(default=None, max_length=4096, description="Every DOF")
    joints: dict[str, float] | None = Field(
        default=None, max_length=4096, description="Some DOFs by name (the others: current)"
    )
    bones: BoneOutput | None = Field(
        default=None,
        description="Bone data to return (skeleton chains: gltf, bvh; left out: the local "
        "rotations). A chain without bones answers none, and refuses bone data asked for",
    )


class FkResult(StrictModel):
    """The world poses of a pose's effectors, and its bone data on skeleton chains."""

    q: list[float] = Field(description="The pose used, in DOF order")
    effectors: list[EffectorPoseOut] = Field(
        description="Every effector's world pose, in the chain's effector order"
    )
    bones: BonesOut | None = Field(
        default=None, description="Skeleton chains (gltf, bvh) only: the bone data asked for"
    )
    clipped: list[str] = Field(
        default_factory=list,
        description="The DOFs the request's q or joints had outside their limits, which the "
        "pose used sets to the nearest limit (as PUT .../pose does), in DOF order",
    )
