"""The JSON contract of the IK service: pydantic v2 models for every request, response
and WebSocket message.

Conventions, stated once and kept everywhere:

- lengths in metres, angles in radians, times in microseconds (``_us``) or seconds (``_s``);
- the world frame of a chain is the frame of its root (base) link;
- quaternions are objects ``{"w", "x", "y", "z"}`` (never positional arrays, so that
  engines using xyzw and wxyz orders cannot be confused); they must have unit norm
  within 1e-3 and are normalised by the server;
- every float must be finite (NaN and +-infinity are rejected), every model rejects
  unknown fields.

This package imports pydantic and ``solver.termination`` only (the termination codes
are part of the contract).
"""

from .chain import (
    BoneEffectorSpec,
    BoneSettingsSpec,
    BvhChain,
    ChainSpec,
    EffectorSpec,
    ExampleChain,
    FreeRootSpec,
    GltfChain,
    HierarchyChain,
    JointSpec,
    OriginSpec,
    UrdfChain,
)
from .common import ErrorBody, FiniteFloat, Quaternion, StrictModel, Vec3
from .engines import (
    BoneOutput,
    BonesOut,
    BoneTransformOut,
    Conventions,
    ConventionsOut,
    FkRequest,
    FkResult,
    QuaternionOut,
    Vec3Out,
)
from .errors import ERROR_CODE_DESCRIPTIONS, ErrorCode
from .health import NotReadyBody, StartupPhase, StartupProgress
from .results import (
    CompactFrameResult,
    CompactFrameResults,
    EffectorErrorOut,
    FrameResult,
    FrameResults,
    FramesQuery,
    PlanSummary,
    ResultView,
)
from .solve import (
    ClipRequest,
    DofInfo,
    EffectorInfo,
    FollowerInfo,
    Frame,
    FrameRequest,
    FramesBody,
    ModelWarning,
    OptionsPatch,
    Pose,
    PoseIn,
    SessionCounters,
    SessionCreate,
    SessionCreated,
    SessionInfo,
    SolveRequest,
    SolverOptions,
    Target,
)
from .ws import (
    CLIENT_MESSAGE_TYPES,
    ClientMessage,
    ClipMessage,
    ClipResultMessage,
    ErrorMessage,
    ErrorPayload,
    FkMessage,
    FkResultMessage,
    FrameMessage,
    PingMessage,
    PongMessage,
    ResultMessage,
    ServerMessage,
)

__all__ = [
    "BoneEffectorSpec",
    "BoneOutput",
    "BoneSettingsSpec",
    "BoneTransformOut",
    "BonesOut",
    "BvhChain",
    "Conventions",
    "ConventionsOut",
    "FkMessage",
    "FkRequest",
    "FkResultMessage",
    "FkResult",
    "FreeRootSpec",
    "GltfChain",
    "QuaternionOut",
    "Vec3Out",
    "CLIENT_MESSAGE_TYPES",
    "ChainSpec",
    "ClientMessage",
    "ClipMessage",
    "ClipRequest",
    "ClipResultMessage",
    "CompactFrameResult",
    "CompactFrameResults",
    "DofInfo",
    "FollowerInfo",
    "ModelWarning",
    "EffectorErrorOut",
    "EffectorInfo",
    "EffectorSpec",
    "ERROR_CODE_DESCRIPTIONS",
    "ErrorBody",
    "ErrorCode",
    "ErrorMessage",
    "NotReadyBody",
    "StartupPhase",
    "StartupProgress",
    "ErrorPayload",
    "ExampleChain",
    "FiniteFloat",
    "Frame",
    "FrameMessage",
    "FrameRequest",
    "FramesBody",
    "FramesQuery",
    "FrameResult",
    "FrameResults",
    "PlanSummary",
    "HierarchyChain",
    "JointSpec",
    "OptionsPatch",
    "OriginSpec",
    "PingMessage",
    "PongMessage",
    "Pose",
    "PoseIn",
    "Quaternion",
    "ResultMessage",
    "ResultView",
    "ServerMessage",
    "SessionCounters",
    "SessionCreate",
    "SessionCreated",
    "SessionInfo",
    "SolveRequest",
    "SolverOptions",
    "StrictModel",
    "Target",
    "UrdfChain",
    "Vec3",
]
