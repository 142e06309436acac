"""What the service takes and gives, typed: requests as TypedDicts (plain dicts that a
type checker can check), answers as frozen dataclasses built from the JSON.

The field names are those of the service's OpenAPI schema (``/openapi.json``; the
component each class mirrors is named in its docstring, and a live test compares them).
Answers ignore fields they do not know, so a newer server does not break an older client.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any, Literal, NotRequired, TypedDict

from .codes import Termination as Termination  # re-exported: ik_client.types.Termination
from .errors import ServiceError, service_error


class Status(enum.StrEnum):
    """Whether a frame reached its targets, and if not, why."""

    SOLVED = "solved"
    NOT_REACHED = "not_reached"
    BUDGET_EXHAUSTED = "budget_exhausted"
    NONFINITE = "nonfinite"


class Continuity(enum.StrEnum):
    """A session's continuity policy (schema ``SolverOptions.continuity``)."""

    SMOOTH = "smooth"  # never step a joint more than max_joint_step_rad per frame
    REACH = "reach"  # solve every frame, jumping to another branch if it must


class EffectorMode(enum.StrEnum):
    POSITION = "position"
    POSE = "pose"
    AIM = "aim"


class Encoding(enum.StrEnum):
    """How a stream's messages travel: JSON text or MessagePack binary messages."""

    JSON = "json"
    MSGPACK = "msgpack"


# --- requests ---------------------------------------------------------------------------
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


class Frame(TypedDict):
    """One frame of a clip (schema ``Frame``); ``id`` is echoed in its result."""

    targets: list[Target]
    id: NotRequired[int]
    bones: NotRequired[BoneOutput]


class BatchFrame(TypedDict):
    """One session's frame in a batch (schema ``BatchFrame``): a ``Frame`` plus the
    session it is for and that session's token."""

    session: str
    token: str
    targets: list[Target]
    id: NotRequired[int]
    bones: NotRequired[BoneOutput]


class PoseIn(TypedDict, total=False):
    """A pose (schema ``PoseIn``): exactly one of ``q`` (every DOF, in order) or
    ``joints`` (some DOFs by name) [rad] or [m]."""

    q: list[float]
    joints: dict[str, float]


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


# --- answers ----------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class EffectorError:
    """Schema ``EffectorErrorOut``: the pose error of one targeted effector."""

    name: str
    position_error_m: float | None
    rotation_error_rad: float | None
    within_tolerance: bool

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> EffectorError:
        return cls(d["name"], d["position_error_m"], d["rotation_error_rad"], d["within_tolerance"])


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameResult:
    """Schemas ``FrameResult`` and ``CompactFrameResult``: the answer to one frame.

    ``joints`` and ``effectors`` are None in compact results (``compact=True``). A frame
    that did not reach its targets is a result with ``success`` False, not an error.
    """

    id: int | None
    success: bool
    status: Status
    termination: Termination
    q: list[float]
    joints: dict[str, float] | None
    effectors: list[EffectorError] | None
    iterations: int
    function_evals: int
    passes: int
    restarts: int
    solve_us: float
    server_us: float
    # Largest joint step from the session's previous answer (None: a one-shot solve) and
    # whether it is over the session's ``max_joint_step_rad`` (a jump).
    largest_step_rad: float | None = None
    jumped: bool = False
    # Schema ``BonesOut`` as sent: {"local": {bone: {w,x,y,z}}, "world": {bone: {...}}}.
    bones: dict[str, Any] | None = None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> FrameResult:
        effectors = d.get("effectors")
        return cls(
            id=d["id"],
            success=d["success"],
            status=Status(d["status"]),
            termination=Termination(d["termination"]),
            q=d["q"],
            joints=d.get("joints"),
            effectors=None
            if effectors is None
            else [EffectorError.from_json(e) for e in effectors],
            iterations=d["iterations"],
            function_evals=d["function_evals"],
            passes=d["passes"],
            restarts=d["restarts"],
            solve_us=d["solve_us"],
            server_us=d["server_us"],
            largest_step_rad=d["largest_step_rad"],
            jumped=d["jumped"],
            bones=d.get("bones"),
        )


@dataclass(frozen=True, slots=True)
class EffectorPose:
    """Schema ``EffectorPoseOut``: an effector's world pose in the session's conventions
    (the tip frame its targets are compared with); ``direction``: where an aim
    effector's aim axis points (None for position and pose effectors)."""

    name: str  # as targets address it
    position: Vec3
    orientation: Quaternion
    direction: Vec3 | None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> EffectorPose:
        return cls(d["name"], d["position"], d["orientation"], d.get("direction"))


@dataclass(frozen=True, slots=True)
class FkResult:
    """Schema ``FkResult``: where a pose puts the chain (``POST .../fk``): every
    effector's world pose and, on skeleton chains, the bone data asked for."""

    q: list[float]  # the pose used, in DOF order
    # Schema ``BonesOut`` as sent: {"local": {bone: {w,x,y,z}}, "world": {bone: {...}}};
    # None on chains without bones (URDF, hierarchy, examples). Before ``effectors``:
    # FkResult(q, bones) kept its meaning when they came.
    bones: dict[str, Any] | None = None
    # Every effector, in the chain's order (empty from a server older than them).
    effectors: list[EffectorPose] = field(default_factory=list)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> FkResult:
        effectors = [EffectorPose.from_json(e) for e in d.get("effectors", [])]
        return cls(d["q"], d.get("bones"), effectors)


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanSummary:
    """Schema ``PlanSummary``: what planning a clip achieved."""

    largest_step_rad: float
    tracked_largest_step_rad: float
    candidates: int
    plan_us: float

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> PlanSummary:
        return cls(
            largest_step_rad=d["largest_step_rad"],
            tracked_largest_step_rad=d["tracked_largest_step_rad"],
            candidates=d["candidates"],
            plan_us=d["plan_us"],
        )


@dataclass(frozen=True, slots=True)
class ClipResult:
    """Schema ``FrameResults``: one result per frame, in order; ``plan`` when planned."""

    results: list[FrameResult]
    plan: PlanSummary | None

    @property
    def success(self) -> bool:
        return all(r.success for r in self.results)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ClipResult:
        plan = d.get("plan")
        return cls(
            [FrameResult.from_json(r) for r in d["results"]],
            None if plan is None else PlanSummary.from_json(plan),
        )


@dataclass(frozen=True, slots=True)
class BatchEntryResult:
    """One entry of a batch's answer (schemas ``BatchEntryResult`` / ``BatchEntryError``):
    its ``result``, or its own ``error`` (a ``ServiceError`` subclass, not raised: the
    other entries were answered)."""

    session: str | None
    id: int | None
    success: bool
    result: FrameResult | None
    error: ServiceError | None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> BatchEntryResult:
        e = d.get("error")
        r = d.get("result")
        error = None
        if e is not None:
            error = service_error(
                e["code"], e["message"], field=e.get("field"),
                retry_after_s=e.get("retry_after_s"),
            )  # fmt: skip
        result = None if r is None else FrameResult.from_json(r)
        return cls(d["session"], d["id"], d["success"], result, error)


@dataclass(frozen=True, slots=True)
class Pose:
    """Schema ``Pose``: joint values in DOF order and by name [rad] or [m]; ``clipped``
    names the DOFs whose value the client sent (``set_pose``, ``initial_pose``) was
    outside the limits and was set to the nearest limit."""

    q: list[float]
    joints: dict[str, float]
    clipped: list[str]

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Pose:
        return cls(d["q"], d["joints"], d.get("clipped", []))


@dataclass(frozen=True, slots=True)
class Dof:
    """Schema ``DofInfo``: one degree of freedom and its limits (None: unbounded)."""

    name: str
    lower: float | None
    upper: float | None


@dataclass(frozen=True, slots=True)
class Effector:
    """Schema ``EffectorInfo``."""

    name: str
    mode: EffectorMode


@dataclass(frozen=True, slots=True)
class Follower:
    """Schema ``FollowerInfo``: a mimic joint, ``multiplier * leader + offset``; not a
    DOF (not in ``q``), its value is in results' ``joints``."""

    name: str
    leader: str
    multiplier: float
    offset: float


@dataclass(frozen=True, slots=True)
class ModelWarning:
    """Schema ``ModelWarning``: the chain's file read by a convention or a default."""

    code: str
    joint: str
    field: str
    message: str


@dataclass(frozen=True, slots=True, kw_only=True)
class SolverOptions:
    """Schema ``SolverOptions``: the effective options of a session."""

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
    continuity: Continuity
    max_joint_step_rad: float

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SolverOptions:
        values = {name: d[name] for name in cls.__dataclass_fields__}
        values["continuity"] = Continuity(values["continuity"])
        return cls(**values)


@dataclass(frozen=True, slots=True)
class SessionCounters:
    """Schema ``SessionCounters``."""

    frames: int
    solved: int
    not_solved: int


@dataclass(frozen=True, slots=True, kw_only=True)
class ConventionsOut:
    """Schema ``ConventionsOut``: the coordinates a session speaks."""

    up: str
    handedness: str
    unit_m: float

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ConventionsOut:
        return cls(up=d["up"], handedness=d["handedness"], unit_m=d["unit_m"])


@dataclass(frozen=True, slots=True, kw_only=True)
class _SessionSummary:
    """What ``Session`` and ``SessionInfo`` both carry: the chain's summary, the options,
    the pose and the conventions."""

    id: str
    n_dof: int
    dof: list[Dof]
    effectors: list[Effector]
    followers: list[Follower]
    warnings: list[ModelWarning]
    options: SolverOptions
    pose: Pose
    idle_ttl_s: float
    conventions: ConventionsOut

    @staticmethod
    def _summary(d: dict[str, Any]) -> dict[str, Any]:
        return {
            "id": d["id"],
            "n_dof": d["n_dof"],
            "dof": [Dof(x["name"], x["lower"], x["upper"]) for x in d["dof"]],
            "effectors": [Effector(x["name"], EffectorMode(x["mode"])) for x in d["effectors"]],
            "followers": [
                Follower(x["name"], x["leader"], x["multiplier"], x["offset"])
                for x in d["followers"]
            ],
            "warnings": [
                ModelWarning(x["code"], x["joint"], x["field"], x["message"]) for x in d["warnings"]
            ],
            "options": SolverOptions.from_json(d["options"]),
            "pose": Pose.from_json(d["pose"]),
            "idle_ttl_s": d["idle_ttl_s"],
            "conventions": ConventionsOut.from_json(d["conventions"]),
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class Session(_SessionSummary):
    """Schema ``SessionCreated``: a new session. ``token`` is shown only once; every call
    on the session takes this object (or any object with ``id`` and ``token``)."""

    token: str

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Session:
        return cls(token=d["token"], **cls._summary(d))


@dataclass(frozen=True, slots=True, kw_only=True)
class SessionInfo(_SessionSummary):
    """Schema ``SessionInfo``: a session's chain summary, options, pose and counters."""

    counters: SessionCounters
    created_at: float
    idle_s: float
    websockets: int

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SessionInfo:
        c = d["counters"]
        return cls(
            counters=SessionCounters(c["frames"], c["solved"], c["not_solved"]),
            created_at=d["created_at"],
            idle_s=d["idle_s"],
            websockets=d["websockets"],
            **cls._summary(d),
        )


# --- stream answers -----------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class FrameAnswer:
    """A ``result`` message: the answer to the stream's frame ``id``; ``success``: the
    frame's (as ``result.success``)."""

    id: int
    result: FrameResult
    success: bool
    type: Literal["result"] = "result"


@dataclass(frozen=True, slots=True)
class ClipAnswer:
    """A ``clip_result`` message: the answer to the stream's clip ``id``."""

    id: int
    clip: ClipResult
    type: Literal["clip_result"] = "clip_result"


@dataclass(frozen=True, slots=True)
class BatchAnswer:
    """A ``batch_result`` message: the answer to the stream's batch ``id``, one entry per
    frame sent, in order, each a result or that entry's own error; ``success``: every
    entry's success."""

    id: int
    results: list[BatchEntryResult]
    success: bool
    type: Literal["batch_result"] = "batch_result"


@dataclass(frozen=True, slots=True)
class Pong:
    """A ``pong`` message: the answer to the stream's ping ``id``."""

    id: int
    type: Literal["pong"] = "pong"


@dataclass(frozen=True, slots=True)
class FkAnswer:
    """An ``fk_result`` message: the answer to the stream's fk ``id``."""

    id: int
    result: FkResult
    type: Literal["fk_result"] = "fk_result"


Answer = FrameAnswer | ClipAnswer | BatchAnswer | FkAnswer | Pong
