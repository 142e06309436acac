"""Poses: what the service answers (``Pose``) and what a client sends (``PoseIn``: PUT
pose, a session's ``initial_pose``, a one-shot seed, a frame's animated ``pose``)."""

from __future__ import annotations

from pydantic import ConfigDict, Field, model_validator

from .common import FiniteFloat, StrictModel, check_exactly_one

HARD_MAX_DOF_VALUES = 8192


class Pose(StrictModel):
    """Joint values, by name and as an array in DOF order."""

    q: list[float] = Field(description="Values in DOF order [rad] or [m]")
    joints: dict[str, float] = Field(
        description="Values by name [rad] or [m]: every DOF, then every mimic joint "
        "(`followers`: multiplier x its leader + offset; not in `q`)",
        examples=[{"panda_finger_joint1": 0.02, "panda_finger_joint2": 0.02}],
    )
    clipped: list[str] = Field(
        default_factory=list,
        description="The DOFs whose value the client sent (PUT pose, `initial_pose`) was "
        "outside the limits and was set to the nearest limit; empty otherwise",
        examples=[["joint1"]],
    )


class PoseIn(StrictModel):
    """A pose: either ``q`` (every DOF, in order) or ``joints`` (some DOFs by name; the
    others keep their current value). Values are clipped into the limits (PUT .../pose
    answers which in ``clipped``; a frame's animated pose is clipped without a word)."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"joints": {"elbow": 1.2}}, {"q": [0.0, 0.2, 1.2]}]}
    )

    q: list[FiniteFloat] | None = Field(
        default=None, max_length=HARD_MAX_DOF_VALUES, description="Every DOF, in order"
    )
    joints: dict[str, FiniteFloat] | None = Field(
        default=None, max_length=HARD_MAX_DOF_VALUES, description="Some DOFs by name"
    )

    @model_validator(mode="after")
    def _exactly_one(self) -> PoseIn:
        check_exactly_one(self, "q", "joints")
        return self


# A frame's ``pose`` (``Frame``, the WebSocket ``frame`` message, batch entries).
FRAME_POSE_DESCRIPTION = (
    "The animated pose this frame starts from (IK on top of an animation): as "
    "`PUT .../pose` then the frame, in one step. The pose (clipped into the limits; "
    "`joints`: the other DOFs keep their current value) becomes the frame's start and the "
    "rest pose the posture pull steers towards; the frame is solved as the first after a "
    "pose set (under `smooth`, as `reach`), and `largest_step_rad` / `jumped` are measured "
    "from it. Later frames without `pose` continue from the answer. Not in a planned clip"
)
