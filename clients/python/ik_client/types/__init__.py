"""What the service takes and gives, typed: requests as TypedDicts (plain dicts that a
type checker can check), answers as frozen dataclasses built from the JSON.

The field names are those of the service's OpenAPI schema (``/openapi.json``; the
component each class mirrors is named in its docstring, and a live test compares them).
Answers ignore fields they do not know, so a newer server does not break an older client.

Requests are in ``requests``, answers of solving in ``results``, a session's
description in ``sessions``, the enums in ``enums``; every name is importable from here
(``ik_client.types``) and from ``ik_client``.
"""

from .enums import (
    Continuity,
    EffectorMode,
    Encoding,
    Status,
    Termination,
)
from .requests import (
    BatchFrame,
    BoneOutput,
    Chain,
    Conventions,
    Frame,
    Pole,
    PoseIn,
    Quaternion,
    SolverOptionsPatch,
    Target,
    Vec3,
)
from .results import (
    Answer,
    BatchAnswer,
    BatchEntryResult,
    ClipAnswer,
    ClipResult,
    EffectorError,
    EffectorPose,
    FkAnswer,
    FkResult,
    FrameAnswer,
    FrameResult,
    PlanSummary,
    Pong,
)
from .sessions import (
    ConventionsOut,
    Dof,
    Effector,
    Follower,
    ModelWarning,
    Pose,
    Session,
    SessionCounters,
    SessionInfo,
    SolverOptions,
)

__all__ = [
    "Answer",
    "BatchAnswer",
    "BatchEntryResult",
    "BatchFrame",
    "BoneOutput",
    "Chain",
    "ClipAnswer",
    "ClipResult",
    "Continuity",
    "Conventions",
    "ConventionsOut",
    "Dof",
    "Effector",
    "EffectorError",
    "EffectorMode",
    "EffectorPose",
    "Encoding",
    "FkAnswer",
    "FkResult",
    "Follower",
    "Frame",
    "FrameAnswer",
    "FrameResult",
    "ModelWarning",
    "PlanSummary",
    "Pole",
    "Pong",
    "Pose",
    "PoseIn",
    "Quaternion",
    "Session",
    "SessionCounters",
    "SessionInfo",
    "SolverOptions",
    "SolverOptionsPatch",
    "Status",
    "Target",
    "Termination",
    "Vec3",
]
