"""WebSocket envelopes (``/v1/sessions/{id}/ws``), a discriminated union on ``type``.

The same shapes travel as JSON text messages or as MessagePack binary messages; the
server answers in the encoding of the message it answers. Every message carries the
client's ``id``: a non-negative integer that must increase within a connection.
"""

from __future__ import annotations

from typing import Annotated, Literal, get_args

from pydantic import Field

from .batch import BatchEntry, BatchEntryError, BatchEntryResult
from .common import ErrorPayload, StrictModel
from .engines import BoneOutput, FkRequest, FkResult
from .poses import FRAME_POSE_DESCRIPTION, PoseIn
from .results import CompactFrameResult, FrameResult, PlanSummary
from .solve import (
    HARD_MAX_FRAMES,
    HARD_MAX_TARGETS,
    ClipRequest,
    Frame,
    FrameId,
    Target,
)


class FrameMessage(StrictModel):
    """Client -> server: solve one frame, warm-started from the session's current pose."""

    type: Literal["frame"]
    id: FrameId = Field(description="Frame id; must be greater than the previous message's id")
    targets: list[Target] = Field(min_length=1, max_length=HARD_MAX_TARGETS)
    bones: BoneOutput | None = Field(
        default=None, description="Bone output for this frame (default: the session's)"
    )
    pose: PoseIn | None = Field(default=None, description=FRAME_POSE_DESCRIPTION)


class ClipMessage(StrictModel):
    """Client -> server: a clip of frames, solved in order, each warm-started from the
    previous answer, or with ``plan`` as a whole (as ``POST .../frames`` with
    ``{"frames": [...]}``); answered by one ``clip_result``. The server caps its length
    (IK_MAX_FRAMES_PER_REQUEST) and the message's size (IK_WS_MAX_MESSAGE_BYTES)."""

    type: Literal["clip"]
    id: FrameId = Field(description="Message id; must be greater than the previous message's id")
    frames: list[Frame] = Field(min_length=1, max_length=HARD_MAX_FRAMES)
    plan: bool = Field(default=False, description=ClipRequest.model_fields["plan"].description)


class FkMessage(FkRequest):
    """Client -> server: forward kinematics of a pose (``q`` or ``joints``; neither: the
    session's current pose), answered by an ``fk_result``; the pose is not changed."""

    type: Literal["fk"]
    id: FrameId


class BatchMessage(StrictModel):
    """Client -> server: one frame for each of several sessions (a game server's
    characters), answered by one ``batch_result``. Each entry names its session and
    carries its token; an entry that fails gets its own error, the others are solved.
    At most IK_MAX_FRAMES_PER_REQUEST entries."""

    type: Literal["batch"]
    id: FrameId = Field(description="Message id; must be greater than the previous message's id")
    frames: list[BatchEntry] = Field(min_length=1, max_length=HARD_MAX_FRAMES)


class PingMessage(StrictModel):
    """Client -> server: ask for a ``pong`` (keep-alive, round-trip time)."""

    type: Literal["ping"]
    id: FrameId


ClientMessage = Annotated[
    FrameMessage | ClipMessage | BatchMessage | FkMessage | PingMessage,
    Field(discriminator="type"),
]


def _message_types() -> tuple[str, ...]:
    """The ``type`` tags of ``ClientMessage``, read from its union (so the error that
    lists them cannot fall behind a new message type)."""
    union, _field = get_args(ClientMessage)
    models = get_args(union)
    return tuple(tag for m in models for tag in get_args(m.model_fields["type"].annotation))


CLIENT_MESSAGE_TYPES: tuple[str, ...] = _message_types()
"""The ``type`` values a client may send: ``("frame", "clip", "batch", "fk", "ping")``."""


class ResultMessage(StrictModel):
    """Server -> client: the result of frame ``id``; ``success`` is the frame's success."""

    id: int
    type: Literal["result"]
    success: bool
    result: FrameResult | CompactFrameResult = Field(
        description="A CompactFrameResult on a socket opened with ?results=compact"
    )


class ClipResultMessage(StrictModel):
    """Server -> client: the results of clip ``id``, one per frame in order (each
    echoing its frame's ``id``); ``success``: every frame's success."""

    id: int
    type: Literal["clip_result"]
    success: bool
    results: list[FrameResult] | list[CompactFrameResult] = Field(
        description="CompactFrameResults on a socket opened with ?results=compact"
    )
    plan: PlanSummary | None = Field(
        default=None, description="Present when the clip was planned (`plan: true`)"
    )


class BatchResultMessage(StrictModel):
    """Server -> client: the answers of batch ``id``, one per entry in order, each a
    result or that entry's error; ``success``: every entry's success."""

    id: int
    type: Literal["batch_result"]
    success: bool
    results: list[BatchEntryResult | BatchEntryError]


class ErrorMessage(StrictModel):
    """Server -> client: message ``id`` (null if it could not be read) failed."""

    id: int | None
    type: Literal["result"]
    success: Literal[False]
    error: ErrorPayload


class FkResultMessage(FkResult):
    """Server -> client: the answer to an ``fk`` message (an ``FkResult``)."""

    id: int
    type: Literal["fk_result"]


class PongMessage(StrictModel):
    """Server -> client: the answer to a ping."""

    id: int
    type: Literal["pong"]


ServerMessage = (
    ResultMessage
    | ClipResultMessage
    | BatchResultMessage
    | FkResultMessage
    | ErrorMessage
    | PongMessage
)
