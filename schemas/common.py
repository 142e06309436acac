"""Building blocks: strict base model, finite floats, vectors, quaternions, error body."""

from __future__ import annotations

import math
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, model_validator

from .errors import ErrorCode

# Finite floats only: NaN and +-inf are rejected at the boundary (JSON has no literal
# for them anyway, but MessagePack and Python clients can send them).
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]

# Lengths, coordinates, limits and weights are bounded so that no finite input can
# overflow the kinematics (1e308 translations would give inf in the first product):
# 1000 km is far beyond any robot, and squares of 1e6 stay far from the float range.
MAX_COORDINATE = 1e6
Coordinate = Annotated[float, Field(allow_inf_nan=False, ge=-MAX_COORDINATE, le=MAX_COORDINATE)]

# A quaternion must have unit norm within this (float32 round-off in game engines).
QUATERNION_NORM_TOLERANCE = 1e-3


class StrictModel(BaseModel):
    """Base of every model: unknown fields rejected, finite floats, frozen, strict types.

    Strict: a number must be a JSON number (``"0.3"`` and ``"NaN"`` as strings are
    wrong types), an integer must be an integer, a string a string (MessagePack bytes are
    not coerced either). Integers are accepted where floats are expected.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True, strict=True)


def check_exactly_one(model: BaseModel, first: str, second: str) -> None:
    """A model validator's check that exactly one of two optional fields is set.

    Raises:
        ValueError: both or neither are set (pydantic reports it as the model's error).
    """
    if (getattr(model, first) is None) == (getattr(model, second) is None):
        raise ValueError(f"give exactly one of '{first}' and '{second}'")


class Vec3(StrictModel):
    """A 3-vector: a point or offset (a target's or pole's in the session's unit; a
    chain's in metres), or a direction (unitless); each component finite and within
    +-1e6."""

    model_config = ConfigDict(json_schema_extra={"examples": [{"x": 0.3, "y": 0.0, "z": 0.5}]})

    x: Coordinate = Field(description="x component")
    y: Coordinate = Field(description="y component")
    z: Coordinate = Field(description="z component")


class Quaternion(StrictModel):
    """A rotation as a unit quaternion ``{w, x, y, z}`` (w is the scalar part).

    The norm must be 1 within 1e-3; the server normalises it. Identity is
    ``{"w": 1, "x": 0, "y": 0, "z": 0}``.
    """

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0}]}
    )

    w: FiniteFloat = Field(description="scalar part")
    x: FiniteFloat = Field(description="x of the vector part")
    y: FiniteFloat = Field(description="y of the vector part")
    z: FiniteFloat = Field(description="z of the vector part")

    @model_validator(mode="after")
    def _unit_norm(self) -> Quaternion:
        # hypot, not sqrt of squares: 1e200**2 overflows (found by schemathesis: a 500).
        norm = math.hypot(self.w, self.x, self.y, self.z)
        if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            raise ValueError(
                f"quaternion must have unit norm (within {QUATERNION_NORM_TOLERANCE}), "
                f"got |q| = {norm:.6g}"
            )
        return self


IDENTITY = Quaternion(w=1.0, x=0.0, y=0.0, z=0.0)
ZERO3 = Vec3(x=0.0, y=0.0, z=0.0)


class ErrorBody(StrictModel):
    """Every HTTP error: FastAPI's ``detail`` plus a stable ``code``.

    For ``invalid_format`` (the body failed validation) ``detail`` is FastAPI's list of
    ``{loc, msg, type}`` entries and ``field`` the first entry's ``loc`` as a path; for
    every other code ``detail`` is a message and ``field`` names the offending field
    when there is one. Every ``field`` is written one way: keys dotted, list indices in
    brackets (``frame.targets[0].orientation``, ``chain.joints[1].lower``).
    """

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "detail": "chain.joints[1].lower: lower > upper (1.0 > -1.0)",
                    "code": "invalid_problem",
                    "field": "chain.joints[1].lower",
                }
            ]
        }
    )

    detail: str | list[dict[str, object]] = Field(description="What went wrong")
    # strict=False: a client (or a test) validating a decoded body passes the string.
    code: ErrorCode = Field(
        strict=False,
        description="Stable error code (the ErrorCode schema lists and explains them)",
    )
    field: str | None = Field(
        default=None,
        description="Path of the offending field, when known: keys dotted, list indices "
        "in brackets (frame.targets[0].position.x)",
    )


class ErrorPayload(StrictModel):
    """A recoverable error: the message (or the batch entry) was not solved; a WebSocket
    stays open."""

    code: ErrorCode = Field(
        strict=False,  # a decoded message's string validates (see ErrorBody)
        description="Stable error code (the ErrorCode schema lists and explains them)",
    )
    message: str
    field: str | None = None
    retry_after_s: float | None = Field(
        default=None,
        description="For not_ready, rate_limited, plans_busy, too_many_plans, server_busy, "
        "too_much_work, store_unavailable and shutting_down: when to try again [s] "
        "(HTTP's Retry-After)",
    )
