"""The enums of what the service takes and gives (``Termination`` is generated with
the error codes: ../codes.py)."""

from __future__ import annotations

import enum

from ..codes import Termination as Termination  # re-exported: ik_client.types.Termination


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
