"""Targets, frames, solver options and the session resources (results: ``results.py``)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Discriminator, Field, Tag, model_validator

from solver.model.notes import NoteKind

from .chain import EXAMPLE_ARM, ChainSpec, EffectorModeName, Name
from .common import FiniteFloat, Quaternion, StrictModel, Vec3
from .engines import BoneOutput, Conventions, ConventionsOut
from .poses import FRAME_POSE_DESCRIPTION, Pose, PoseIn

# Frame ids: non-negative integers that a JavaScript client can hold exactly.
MAX_FRAME_ID = 2**53 - 1
FrameId = Annotated[int, Field(ge=0, le=MAX_FRAME_ID)]

HARD_MAX_FRAMES = 10_000
HARD_MAX_TARGETS = 256

# --- solver options -------------------------------------------------------------------
_OPTION_FIELDS: dict[str, dict[str, Any]] = {
    "position_tolerance_m": {
        "gt": 0.0,
        "le": 1.0,
        "description": "A frame succeeds when every position error is at most this [m]",
    },
    "rotation_tolerance_rad": {
        "gt": 0.0,
        "le": 3.15,
        "description": "... and every orientation / aim error at most this [rad]",
    },
    "time_budget_us": {
        "gt": 0.0,
        "le": 1_000_000.0,
        "description": "Wall-clock budget of one frame's solve [us]; the server caps it "
        "(IK_MAX_TIME_BUDGET_US)",
    },
    "max_iter": {"ge": 1, "le": 100_000, "description": "Iterations per frame, all passes"},
    "max_restarts": {"ge": 0, "le": 10_000, "description": "Random restarts per frame"},
    "restart_radius_rad": {
        "gt": 0.0,
        "le": 1e9,
        "description": "Restarts sample within this distance of the seed, per variable "
        "[rad] or [m]; use a large value (e.g. 100) to sample the whole range",
    },
    "max_step_rad": {
        "gt": 0.0,
        "le": 1e3,
        "description": "Cap on any variable's change per iteration [rad] or [m]",
    },
    "posture_weight": {
        "ge": 0.0,
        "le": 1e6,
        "description": "Pull towards the seed (previous pose in a session): w * sum(dq^2)",
    },
    "limit_weight": {"ge": 0.0, "le": 1e6, "description": "Penalty near the joint limits"},
    "limit_margin": {
        "ge": 0.0,
        "lt": 0.5,
        "description": "Width of the limit band, as a fraction of each joint's range",
    },
    "continuity": {
        "description": "What a session frame does when its target cannot be reached near "
        "the previous answer: `smooth` never moves a joint more than `max_joint_step_rad` "
        "from the previous answer (such a frame answers `not_reached` with the closest pose "
        "inside that step), once the stream has an answer to stay near: a frame solved "
        "since the pose was set, one that misses only targets beyond reach (every other "
        "target met), or the 10th missed in a row (until then frames are solved as under "
        "`reach`); `reach` solves every frame, jumping to another branch if it must (the "
        "result says `jumped`). One-shot solves ignore it",
    },
    "max_joint_step_rad": {
        "gt": 0.0,
        "le": 1e3,
        "description": "Per-frame step limit of `smooth` [rad] or [m] (default 0.1; 0.3 on "
        "gltf and bvh chains); under `reach` a larger step is reported as `jumped`",
    },
}

# A session's continuity policy (solver.ik.Continuity's values).
ContinuityName = Literal["smooth", "reach"]


class SolverOptions(StrictModel):
    """The effective solver options of a session or a one-shot solve."""

    position_tolerance_m: FiniteFloat = Field(**_OPTION_FIELDS["position_tolerance_m"])
    rotation_tolerance_rad: FiniteFloat = Field(**_OPTION_FIELDS["rotation_tolerance_rad"])
    time_budget_us: FiniteFloat = Field(**_OPTION_FIELDS["time_budget_us"])
    max_iter: int = Field(**_OPTION_FIELDS["max_iter"])
    max_restarts: int = Field(**_OPTION_FIELDS["max_restarts"])
    restart_radius_rad: FiniteFloat = Field(**_OPTION_FIELDS["restart_radius_rad"])
    max_step_rad: FiniteFloat = Field(**_OPTION_FIELDS["max_step_rad"])
    posture_weight: FiniteFloat = Field(**_OPTION_FIELDS["posture_weight"])
    limit_weight: FiniteFloat = Field(**_OPTION_FIELDS["limit_weight"])
    limit_margin: FiniteFloat = Field(**_OPTION_FIELDS["limit_margin"])
    continuity: ContinuityName = Field(**_OPTION_FIELDS["continuity"])
    max_joint_step_rad: FiniteFloat = Field(**_OPTION_FIELDS["max_joint_step_rad"])


class OptionsPatch(StrictModel):
    """Solver options to change; fields left out keep their current (or default) value."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"time_budget_us": 800, "position_tolerance_m": 0.001}]}
    )

    position_tolerance_m: FiniteFloat | None = Field(
        default=None, **_OPTION_FIELDS["position_tolerance_m"]
    )
    rotation_tolerance_rad: FiniteFloat | None = Field(
        default=None, **_OPTION_FIELDS["rotation_tolerance_rad"]
    )
    time_budget_us: FiniteFloat | None = Field(default=None, **_OPTION_FIELDS["time_budget_us"])
    max_iter: int | None = Field(default=None, **_OPTION_FIELDS["max_iter"])
    max_restarts: int | None = Field(default=None, **_OPTION_FIELDS["max_restarts"])
    restart_radius_rad: FiniteFloat | None = Field(
        default=None, **_OPTION_FIELDS["restart_radius_rad"]
    )
    max_step_rad: FiniteFloat | None = Field(default=None, **_OPTION_FIELDS["max_step_rad"])
    posture_weight: FiniteFloat | None = Field(default=None, **_OPTION_FIELDS["posture_weight"])
    limit_weight: FiniteFloat | None = Field(default=None, **_OPTION_FIELDS["limit_weight"])
    limit_margin: FiniteFloat | None = Field(default=None, **_OPTION_FIELDS["limit_margin"])
    continuity: ContinuityName | None = Field(default=None, **_OPTION_FIELDS["continuity"])
    max_joint_step_rad: FiniteFloat | None = Field(
        default=None, **_OPTION_FIELDS["max_joint_step_rad"]
    )


# --- targets and frames ----------------------------------------------------------------
BlendWeight = Annotated[float, Field(allow_inf_nan=False, ge=0.0, le=1.0)]


class Pole(StrictModel):
    """A point a mid-chain bone (knee, elbow) bends towards: it picks the bend side and
    never makes a reachable frame fail. In the session's conventions, as targets."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"position": {"x": 0.1, "y": 0.5, "z": 0.6}},
                {"position": {"x": 0.1, "y": 0.5, "z": 0.6}, "bone": "leg_joint_R_2"},
            ]
        }
    )

    position: Vec3 = Field(description="The point the bone bends towards [session unit]")
    bone: Name | None = Field(
        default=None,
        description="The link (bone) whose origin is pulled towards the point: the knee "
        "or elbow bone (shin, forearm), on the effector's path to the root. Default: the "
        "middle of the effector's limb",
    )


class Target(StrictModel):
    """What one effector should reach in this frame, in the session's conventions and unit.

    position effectors need ``position``; pose effectors need ``orientation`` (and
    ``position``, unless only the orientation matters); aim effectors need
    ``direction`` (and optionally ``position``). Effectors without a target in a frame
    are not pulled (their joints stay free only if another target moves them).
    ``position_weight`` / ``rotation_weight`` blend IK in and out (docs/engines.md);
    ``pole`` chooses where the limb bends.
    """

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}},
                {
                    "effector": "tool",
                    "position": {"x": 0.4, "y": 0.0, "z": 0.5},
                    "orientation": {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0},
                },
                {
                    "effector": "left_foot",
                    "position": {"x": 0.1, "y": 0.05, "z": 0.1},
                    "position_weight": 0.5,
                    "pole": {"position": {"x": 0.1, "y": 0.5, "z": 0.6}},
                },
            ]
        }
    )

    effector: Name = Field(description="Effector name")
    position: Vec3 | None = Field(default=None, description="Target tip position [session unit]")
    orientation: Quaternion | None = Field(
        default=None, description="Target tip orientation (pose effectors)"
    )
    direction: Vec3 | None = Field(
        default=None,
        description="Direction the aim axis should point along (aim effectors); any "
        "non-zero length, normalised by the server",
    )
    position_weight: BlendWeight = Field(
        default=1.0,
        description="Blend weight of the position in [0, 1]: 1 exact, 0 free (not pulled, "
        "never fails the frame), in between a soft pull towards the point that fraction of "
        "the way from the tip's pose at the frame's start; below 1 it never fails the frame",
    )
    rotation_weight: BlendWeight = Field(
        default=1.0,
        description="The same for the orientation (pose effectors) or direction (aim)",
    )
    pole: Pole | None = Field(
        default=None, description="Where this effector's limb bends (knee, elbow)"
    )

    @model_validator(mode="after")
    def _something(self) -> Target:
        if self.position is None and self.orientation is None and self.direction is None:
            raise ValueError("a target needs a position, an orientation or a direction")
        return self


class Frame(StrictModel):
    """One frame: a target per effector (at most one each). ``id`` is echoed back."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "id": 1,
                    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}],
                }
            ]
        }
    )

    id: FrameId | None = Field(default=None, description="Client's frame id, echoed in the result")
    targets: list[Target] = Field(min_length=1, max_length=HARD_MAX_TARGETS)
    bones: BoneOutput | None = Field(
        default=None, description="Bone output for this frame (default: the session's)"
    )
    pose: PoseIn | None = Field(default=None, description=FRAME_POSE_DESCRIPTION)


# POST /v1/sessions/{id}/frames takes one frame, or {"frames": [...]} (a clip).
FrameRequest = Frame


class ClipRequest(StrictModel):
    """An ordered list of frames, solved one after the other, each warm-started from the
    previous answer (the server caps the length: IK_MAX_FRAMES_PER_REQUEST); with
    ``plan``, solved as a whole."""

    frames: list[Frame] = Field(min_length=1, max_length=HARD_MAX_FRAMES)
    plan: bool = Field(
        default=False,
        description="Solve the clip as a whole, knowing every frame in advance: the joint "
        "path whose largest step between consecutive frames is smallest (the first frame's "
        "counted from the current pose), instead of each frame from the previous answer. "
        "Every frame that frame-by-frame solving would reach is reached, and where that "
        "reaches every frame the largest step is never larger; a redundant arm no longer "
        "jumps where its self-motion meets a singularity. Costs about 0.1-0.2 ms per frame "
        "(a 7-DOF arm under 6-D poses; frame by frame: under 0.01 ms) and answers only once "
        "the whole clip is planned, so it suits clips known ahead "
        "(trajectories, animations), not live streams. The response adds a `plan` summary.",
    )


def _frames_tag(value: Any) -> str:
    if isinstance(value, dict):
        return "clip" if "frames" in value else "frame"
    return "clip" if isinstance(value, ClipRequest) else "frame"


FramesBody = Annotated[
    Annotated[Frame, Tag("frame")] | Annotated[ClipRequest, Tag("clip")],
    Discriminator(_frames_tag),
]


# --- sessions --------------------------------------------------------------------------
class DofInfo(StrictModel):
    """One degree of freedom of the chain."""

    name: str
    lower: float | None = Field(description="Lower limit [rad] or [m]; null if unbounded")
    upper: float | None = Field(description="Upper limit [rad] or [m]; null if unbounded")


class FollowerInfo(StrictModel):
    """A mimic joint (URDF ``<mimic>``): not a DOF, its value is
    ``multiplier * leader + offset``. It moves with its leader (whose limits its own
    narrow); results report its value in ``joints``, not in ``q``."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "name": "panda_finger_joint2",
                    "leader": "panda_finger_joint1",
                    "multiplier": 1.0,
                    "offset": 0.0,
                }
            ]
        }
    )

    name: str = Field(description="The mimic joint")
    leader: str = Field(description="The DOF it follows")
    multiplier: float
    offset: float = Field(description="[rad] or [m]")


ModelWarningCode = Literal[
    "unlimited_by_convention",
    "default_limit",
    "mimic_narrows_leader",
    "mimic_limits_ignored",
    "unlikely_units",
]
assert set(ModelWarningCode.__args__) == {k.value for k in NoteKind}  # type: ignore[attr-defined]


class ModelWarning(StrictModel):
    """Something in the chain's file read in a way you should know about: the chain
    was built, but maybe not as you meant it."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "code": "unlimited_by_convention",
                    "joint": "xtrans",
                    "field": "limit",
                    "message": "lower > upper (1.0 > -1.0) read as no limits (Bullet's convention)",
                }
            ]
        }
    )

    code: ModelWarningCode = Field(
        description="unlimited_by_convention: `lower > upper` read as no limits (pybullet's "
        "files); default_limit: a missing `lower` or `upper` read as URDF's default 0; "
        "mimic_narrows_leader: a mimic joint's limits narrow its leader's range; "
        "mimic_limits_ignored: a mimic joint's limits leave its leader no room (written for "
        "the other sense of the map) and are ignored, as ROS and pinocchio do"
    )
    joint: str = Field(description="The joint in the file")
    field: str = Field(description="The element or attribute, e.g. `limit.lower`")
    message: str


class EffectorInfo(StrictModel):
    """One effector of the chain."""

    name: str
    mode: EffectorModeName


_FOLLOWERS = "Mimic joints: not DOFs (not in `q`); their values are in results' `joints`"
_WARNINGS = "What the chain's file was read by a convention or default you should know of"


class SessionCreate(StrictModel):
    """A chain, solver options (missing fields take the server's defaults) and an
    optional initial pose (default: the middle of each joint's range)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "chain": EXAMPLE_ARM,
                    "options": {"time_budget_us": 1000},
                    "initial_pose": {"joints": {"elbow": 1.0}},
                }
            ]
        }
    )

    chain: ChainSpec
    options: OptionsPatch | None = None
    initial_pose: PoseIn | None = None
    conventions: Conventions | None = Field(
        default=None,
        description="The client's up axis, handedness and unit (default: the chain's own)",
    )
    bones: BoneOutput | None = Field(
        default=None, description="Bone output of every result (skeleton chains)"
    )


class SessionCreated(StrictModel):
    """The new session. ``token`` is shown only here: send it as
    ``Authorization: Bearer <token>`` on every call that touches the session."""

    id: str = Field(description="Session id (URL-safe)")
    token: str = Field(description="Access token (URL-safe)")
    n_dof: int
    dof: list[DofInfo] = Field(description="The joint order of q, with limits")
    effectors: list[EffectorInfo]
    followers: list[FollowerInfo] = Field(description=_FOLLOWERS)
    warnings: list[ModelWarning] = Field(description=_WARNINGS)
    conventions: ConventionsOut
    options: SolverOptions
    pose: Pose
    idle_ttl_s: float = Field(description="The session expires after this long without use [s]")


class SessionCounters(StrictModel):
    """Work done by a session."""

    frames: int = Field(description="Frames solved")
    solved: int = Field(description="Frames that reached their targets")
    not_solved: int = Field(description="Frames that did not")


class SessionInfo(StrictModel):
    """A session's chain summary, current pose and counters."""

    id: str
    n_dof: int
    dof: list[DofInfo]
    effectors: list[EffectorInfo]
    followers: list[FollowerInfo] = Field(description=_FOLLOWERS)
    warnings: list[ModelWarning] = Field(description=_WARNINGS)
    conventions: ConventionsOut
    options: SolverOptions
    pose: Pose
    counters: SessionCounters
    created_at: float = Field(description="Creation time, Unix epoch [s]")
    idle_s: float = Field(description="Time since the last use [s]")
    idle_ttl_s: float = Field(description="Idle time after which the session expires [s]")
    websockets: int = Field(description="Open WebSocket connections")


class SolveRequest(StrictModel):
    """A stateless one-shot solve: chain, one frame of targets, optional seed."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "chain": EXAMPLE_ARM,
                    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}],
                    "seed": {"joints": {"elbow": 1.0}},
                }
            ]
        }
    )

    chain: ChainSpec
    targets: list[Target] = Field(min_length=1, max_length=HARD_MAX_TARGETS)
    seed: PoseIn | None = Field(
        default=None, description="Start pose (default: the middle of each joint's range)"
    )
    options: OptionsPatch | None = None
    id: FrameId | None = Field(default=None, description="Echoed in the result")
    conventions: Conventions | None = Field(
        default=None,
        description="The client's up axis, handedness and unit (default: the chain's own)",
    )
    bones: BoneOutput | None = Field(
        default=None, description="Bone output of the result (skeleton chains)"
    )
