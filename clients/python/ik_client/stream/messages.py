"""The stream's messages as sent, before their id (a frame, a clip, a batch, an fk), and
the checks that an answer is of the kind its call waits for.
"""

from __future__ import annotations

from typing import Any

from ..errors import IKClientError
from ..types import (
    Answer,
    BatchAnswer,
    BatchEntryResult,
    BatchFrame,
    BoneOutput,
    ClipAnswer,
    ClipResult,
    FkAnswer,
    FkResult,
    Frame,
    FrameAnswer,
    FrameResult,
    Pong,
    PoseIn,
    Target,
)


def frame(
    targets: list[Target], bones: BoneOutput | None, pose: PoseIn | None = None
) -> dict[str, Any]:
    """A frame message; ``bones`` overrides the session's bone output for this frame,
    ``pose`` is the animated pose it starts from (``q`` or ``joints``)."""
    if bones is None and pose is None:
        return {"type": "frame", "targets": targets}
    body: dict[str, Any] = {"type": "frame", "targets": targets}
    if bones is not None:
        body["bones"] = bones
    if pose is not None:
        body["pose"] = pose
    return body


def clip(frames: list[Frame], plan: bool) -> dict[str, Any]:
    return {"type": "clip", "frames": frames, "plan": plan}


def batch(frames: list[BatchFrame]) -> dict[str, Any]:
    return {"type": "batch", "frames": frames}


def fk(
    q: list[float] | None, joints: dict[str, float] | None, bones: BoneOutput | None
) -> dict[str, Any]:
    """An fk message: the pose ``q``, or ``joints`` by name, or neither (the session's)."""
    body: dict[str, Any] = {"type": "fk"}
    for key, value in (("q", q), ("joints", joints), ("bones", bones)):
        if value is not None:
            body[key] = value
    return body


def expect_frame(answer: Answer) -> FrameResult:
    if not isinstance(answer, FrameAnswer):
        raise IKClientError(f"expected a frame result, got {answer!r}")
    return answer.result


def expect_fk(answer: Answer) -> FkResult:
    if not isinstance(answer, FkAnswer):
        raise IKClientError(f"expected an fk result, got {answer!r}")
    return answer.result


def expect_pong(answer: Answer) -> Pong:
    if not isinstance(answer, Pong):
        raise IKClientError(f"expected a pong, got {answer!r}")
    return answer


def expect_clip(answer: Answer) -> ClipResult:
    if not isinstance(answer, ClipAnswer):
        raise IKClientError(f"expected a clip result, got {answer!r}")
    return answer.clip


def expect_batch(answer: Answer) -> list[BatchEntryResult]:
    if not isinstance(answer, BatchAnswer):
        raise IKClientError(f"expected a batch result, got {answer!r}")
    return answer.results
