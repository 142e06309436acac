"""Typed client of the IK service: ``Client`` / ``AsyncClient`` over HTTP, and a session's
WebSocket as a ``Stream`` / ``AsyncStream`` that numbers frames, pipelines, speaks JSON
or MessagePack and reconnects without losing or repeating an answer.

    from ik_client import Client

    with Client("http://127.0.0.1:8000") as ik:
        session = ik.create_session({"format": "example", "name": "panda_arm"})
        target = {"effector": "tool", "position": {"x": 0.4, "y": 0.1, "z": 0.5},
                  "orientation": {"w": 0, "x": 1, "y": 0, "z": 0}}
        with ik.stream(session) as stream:
            print(stream.frame([target]).q)
"""

from .calls import SessionRef
from .client import AsyncClient, Client
from .errors import (
    CLOSE_CODE_MEANINGS,
    AuthError,
    CloseCode,
    ConnectionLost,
    ErrorCode,
    IKClientError,
    InvalidRequest,
    MessageTooBig,
    NotFound,
    RetryLater,
    ServerFault,
    ServerRestarting,
    ServiceError,
    SessionGone,
    SlowReader,
    StreamAuthError,
    StreamClosed,
    TooManyWebSockets,
)
from .stream import AsyncStream, Reconnect, Stream
from .types import (
    Answer,
    Chain,
    ClipAnswer,
    ClipResult,
    Dof,
    Effector,
    EffectorError,
    EffectorMode,
    Encoding,
    Frame,
    FrameAnswer,
    FrameResult,
    PlanSummary,
    Pong,
    Pose,
    PoseIn,
    Quaternion,
    Session,
    SessionCounters,
    SessionInfo,
    SolverOptions,
    SolverOptionsPatch,
    Status,
    Target,
    Termination,
    Vec3,
)

__all__ = [
    "CLOSE_CODE_MEANINGS",
    "Answer",
    "AsyncClient",
    "AsyncStream",
    "AuthError",
    "Chain",
    "Client",
    "ClipAnswer",
    "ClipResult",
    "CloseCode",
    "ConnectionLost",
    "Dof",
    "Effector",
    "EffectorError",
    "EffectorMode",
    "Encoding",
    "ErrorCode",
    "Frame",
    "FrameAnswer",
    "FrameResult",
    "IKClientError",
    "InvalidRequest",
    "MessageTooBig",
    "NotFound",
    "PlanSummary",
    "Pong",
    "Pose",
    "PoseIn",
    "Quaternion",
    "Reconnect",
    "RetryLater",
    "ServerFault",
    "ServerRestarting",
    "ServiceError",
    "Session",
    "SessionCounters",
    "SessionGone",
    "SessionInfo",
    "SessionRef",
    "SlowReader",
    "SolverOptions",
    "SolverOptionsPatch",
    "Status",
    "Stream",
    "StreamAuthError",
    "StreamClosed",
    "Target",
    "Termination",
    "TooManyWebSockets",
    "Vec3",
]
