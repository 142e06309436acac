"""Many characters per message: one frame for each of several sessions, one answer
holding each result (``POST /v1/batch`` and the WebSocket's ``batch`` message).

Each entry names its session and carries that session's token, so one connection (a
game server's) can drive every character it animates. Entries are answered one by one:
an entry that fails validation, names a session that does not exist or is over its rate
limit gets its own error in its place, and the others are solved. Only what concerns the
whole message (not JSON, too many entries, not ready) fails it as a whole.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, PlainValidator, ValidationError, WrapValidator
from pydantic.json_schema import SkipJsonSchema
from pydantic_core.core_schema import ValidatorFunctionWrapHandler

from .common import ErrorPayload, StrictModel
from .results import CompactFrameResult, FrameResult
from .solve import HARD_MAX_FRAMES, Frame

# Bounds on an entry's session id and token (ids are 22 characters, tokens 43).
MAX_SESSION_ID_CHARS = 64
MAX_TOKEN_CHARS = 256

_EXAMPLE_ENTRY: dict[str, Any] = {
    "session": "3q2-7wEJtM0Xr2bqVQm1dA",
    "token": "<the session's token>",
    "id": 1,
    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}],
}


class BatchFrame(Frame):
    """One session's frame in a batch: a ``Frame`` plus the session it is for."""

    model_config = ConfigDict(json_schema_extra={"examples": [_EXAMPLE_ENTRY]})

    session: str = Field(min_length=1, max_length=MAX_SESSION_ID_CHARS, description="Session id")
    token: str = Field(
        min_length=1,
        max_length=MAX_TOKEN_CHARS,
        description="The session's token (from POST /v1/sessions)",
    )


@dataclass(frozen=True, slots=True)
class InvalidEntry:
    """A batch entry that failed validation: answered with its own ``invalid_format``
    error while the rest of the batch is solved. Never in the JSON schema.

    Attributes:
        raw: The entry as it was decoded (its ``id`` and ``session`` are echoed if usable).
        errors: pydantic's errors, ``loc`` relative to the entry.
    """

    raw: Any
    errors: list[Any]


def _entry_or_invalid(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    """Validate one entry as a ``BatchFrame`` (in the message's own JSON or Python
    mode); an entry that fails becomes an ``InvalidEntry`` instead of failing the batch."""
    try:
        return handler(value)
    except ValidationError as e:
        return InvalidEntry(value, e.errors(include_url=False, include_input=False))


def _never(value: Any) -> Any:
    """Nothing a client sends is an InvalidEntry: only ``_entry_or_invalid`` makes one."""
    raise ValueError("not a batch entry")


# The schema shows a BatchFrame; at run time an entry is a BatchFrame or an InvalidEntry.
BatchEntry = (
    Annotated[BatchFrame, WrapValidator(_entry_or_invalid)]
    | SkipJsonSchema[Annotated[InvalidEntry, PlainValidator(_never)]]
)


class BatchRequest(StrictModel):
    """``POST /v1/batch``: one frame for each of several sessions, answered in one
    ``BatchResults`` (at most IK_MAX_FRAMES_PER_REQUEST entries). Entries for the same
    session are solved in the order given, each from the previous answer."""

    model_config = ConfigDict(json_schema_extra={"examples": [{"frames": [_EXAMPLE_ENTRY]}]})

    frames: list[BatchEntry] = Field(min_length=1, max_length=HARD_MAX_FRAMES)


class BatchEntryResult(StrictModel):
    """One entry's answer: its session, its frame ``id`` and its ``result``."""

    session: str
    id: int | None
    success: bool = Field(description="The frame's success")
    result: FrameResult | CompactFrameResult = Field(
        description="A CompactFrameResult with ?results=compact"
    )


class BatchEntryError(StrictModel):
    """One entry's error (the others are answered): ``session`` and ``id`` are null
    when the entry had none that could be read."""

    session: str | None
    id: int | None
    success: Literal[False]
    error: ErrorPayload


class BatchResults(StrictModel):
    """The answer to a batch: one entry per frame sent, in the same order."""

    results: list[BatchEntryResult | BatchEntryError]
