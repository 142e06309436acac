"""What the client sends, typed: TypedDicts, plain dicts that a type checker can check
(a caller may pass its own dicts as they are)."""

from __future__ import annotations

from typing import Any, NotRequired, TypedDict

from .enums import Continuity


class Vec3(TypedDict):
    x: float
    y: float
    z: float


class Quaternion(TypedDict):
    """A unit quaternion; w is the scalar part."""

    w: float
    x: float
    y: float
    z: float


class Pole(TypedDict):
    """Where an effector's limb bends (schema ``Pole``): a point the knee or elbow bone
    bends towards, in the session's conventions; ``bone`` names it (default: the middle
    of the limb). Soft: it never makes a reachable frame fail."""

    position: Vec3
    bone: NotRequired[str]


class Target(TypedDict):
    """What one effector should reach (schema ``Target``). ``position_weight`` and
    ``rotation_weight`` in [0, 1] blend IK in and out (0 free, 1 exact, in between a
    soft pull that never fails the frame); ``pole`` chooses where the limb bends."""

    effector: str
    position: NotRequired[Vec3]
    orientation: NotRequired[Quaternion]
    direction: NotRequired[Vec3]
    position_weight: NotRequired[float]
    rotation_weight: NotRequired[float]
    pole: NotRequired[Pole]


class BoneOutput(TypedDict, total=False):
    """Which bone data an answer carries (schema ``BoneOutput``; skeleton chains):
    each moving bone's local rotation, and the world transforms of the bones named."""

    local_rotations: bool
    world: list[str]


class Conventions(TypedDict, total=False):
    """The client's coordinates (schema ``Conventions``): a ``preset`` (unity, unreal,
    godot, gltf, threejs, ros) or ``up`` ("y" / "z"), ``handedness`` ("right" /
    "left") and ``unit`` ("m" / "cm"); docs/engines.md."""

    preset: str
    up: str
    handedness: str
    unit: str


class PoseIn(TypedDict, total=False):
    """A pose (schema ``PoseIn``): exactly one of ``q`` (every DOF, in order) or
    ``joints`` (some DOFs by name) [rad] or [m]."""

    q: list[float]
    joints: dict[str, float]


class Frame(TypedDict):
    """One frame of a clip (schema ``Frame``); ``id`` is echoed in its result, ``pose``
    is the animated pose it starts from (not in a planned clip)."""

    targets: list[Target]
    id: NotRequired[int]
    bones: NotRequired[BoneOutput]
    pose: NotRequired[PoseIn]


class BatchFrame(TypedDict):
    """One session's frame in a batch (schema ``BatchFrame``): a ``Frame`` plus the
    session it is for and that session's token."""

    session: str
    token: str
    targets: list[Target]
    id: NotRequired[int]
    bones: NotRequired[BoneOutput]
    pose: NotRequired[PoseIn]  # the animated pose it starts from


class SolverOptionsPatch(TypedDict, total=False):
    """Solver options to change (schema ``OptionsPatch``); left out: unchanged."""

    position_tolerance_m: float
    rotation_tolerance_rad: float
    time_budget_us: float
    max_iter: int
    max_restarts: int
    restart_radius_rad: float
    max_step_rad: float
    posture_weight: float
    limit_weight: float
    limit_margin: float
    continuity: Continuity | str
    max_joint_step_rad: float


# A chain is one of the schema's three formats (HierarchyChain, UrdfChain, ExampleChain),
# e.g. {"format": "example", "name": "panda_arm"}; the server validates it and names the
# field at fault, so the client passes it through as given.
Chain = dict[str, Any]
