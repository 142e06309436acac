"""Frame results: what a solved frame answers (full or compact), and the plan summary."""

from __future__ import annotations

import enum
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from solver.optim.termination import Termination

from .common import StrictModel
from .engines import BonesOut

IKStatusName = Literal["solved", "not_reached", "budget_exhausted", "nonfinite"]
TerminationName = Literal[
    "goal_reached",
    "gtol",
    "step_small",
    "stalled",
    "line_search_failed",
    "max_iter",
    "max_fev",
    "deadline",
    "nonfinite",
]
# The Literal above is what /docs shows; this keeps it equal to the solver's enum.
assert set(TerminationName.__args__) == {t.value for t in Termination}  # type: ignore[attr-defined]


class EffectorErrorOut(StrictModel):
    """Pose error of one targeted effector after the solve."""

    name: str
    position_error_m: float | None = Field(description="Distance to the target position [m]")
    rotation_error_rad: float | None = Field(
        description="Orientation (pose) or aim-direction (aim) error [rad]; null for position"
    )
    within_tolerance: bool = Field(description="Both errors within the tolerances")


# The examples /docs shows: a full result, and the same without what compact leaves out.
_EXAMPLE_RESULT: dict[str, Any] = {
    "id": 1,
    "success": True,
    "status": "solved",
    "termination": "goal_reached",
    "joints": {"shoulder.z": 0.3217, "shoulder.y": 0.1301, "elbow": 1.9611},
    "q": [0.3217, 0.1301, 1.9611],
    "effectors": [
        {
            "name": "hand",
            "position_error_m": 3.1e-05,
            "rotation_error_rad": None,
            "within_tolerance": True,
        }
    ],
    "iterations": 12,
    "function_evals": 15,
    "passes": 1,
    "restarts": 0,
    "solve_us": 21.4,
    "server_us": 160.2,
    "largest_step_rad": 0.0123,
    "jumped": False,
}
_EXAMPLE_COMPACT: dict[str, Any] = {
    k: v for k, v in _EXAMPLE_RESULT.items() if k not in ("joints", "effectors")
}


class _FrameOutcome(StrictModel):
    """The fields every frame result has, full or compact (in the order /docs shows
    them; ``FrameResult`` adds ``joints`` and ``effectors`` after them). Neither result
    is the other's subclass, so that ``isinstance`` tells a compact one from a full one."""

    id: int | None = Field(description="The client's frame id, echoed (null if none was sent)")
    success: bool = Field(description="Every targeted effector is within the tolerances")
    status: IKStatusName = Field(
        description="solved | not_reached (converged outside tolerance: unreachable or a "
        "local minimum; closest pose returned) | budget_exhausted (time or iterations ran "
        "out; best pose returned) | nonfinite (the model produced NaN/inf)"
    )
    termination: TerminationName = Field(description="How the optimizer's last pass ended")
    q: list[float] = Field(description="Joint values in the session's DOF order [rad] or [m]")
    iterations: int = Field(description="Optimizer iterations, all passes")
    function_evals: int = Field(description="Objective evaluations")
    passes: int = Field(description="Optimizer passes (H resets and restarts start new ones)")
    restarts: int = Field(description="Random restarts")
    solve_us: float = Field(description="Time in the compiled solver [us]")
    server_us: float = Field(
        description="Request (HTTP) or message (WebSocket) received to this result ready [us]"
    )
    largest_step_rad: float | None = Field(
        description="Largest change of any joint from the previous answer of the session "
        "(a planned clip: from the frame before) [rad] or [m]; null for one-shot solves"
    )
    jumped: bool = Field(
        description="`largest_step_rad` is over the session's `max_joint_step_rad` (under "
        "`continuity: smooth` only on the frames that open a stream, solved without the "
        "step limit: see the option `continuity`)"
    )
    bones: BonesOut | None = Field(
        default=None,
        description="Bone rotations and transforms, when asked for (skeleton chains)",
    )


class FrameResult(_FrameOutcome):
    """The answer to one frame. A frame that did not reach its target is still a result
    (``success: false``), not an error."""

    model_config = ConfigDict(json_schema_extra={"examples": [_EXAMPLE_RESULT]})

    joints: dict[str, float] = Field(
        description="Joint values by DOF name [rad] or [m], then the mimic joints' values "
        "(the session's `followers`: multiplier x leader + offset)"
    )
    q: list[float] = Field(
        description="The DOFs' values as an array, in the session's DOF order (no mimic joints)"
    )
    effectors: list[EffectorErrorOut] = Field(description="Errors of the targeted effectors")


class PlanSummary(StrictModel):
    """What planning a clip (``"plan": true``) achieved."""

    largest_step_rad: float = Field(
        description="Largest change of any joint between consecutive frames of the plan, "
        "the first frame's from the pose before the clip [rad] or [m]"
    )
    tracked_largest_step_rad: float = Field(
        description="The same for frame-by-frame solving of the clip, for comparison"
    )
    candidates: int = Field(description="Poses the planner chose from, over all frames")
    plan_us: float = Field(description="Time spent planning [us]")


class FrameResults(StrictModel):
    """One result per frame, in the order of the frames."""

    results: list[FrameResult]
    plan: PlanSummary | None = Field(
        default=None, description="Present when the clip was planned (`plan: true`)"
    )


class ResultView(enum.StrEnum):
    """How much each frame result carries (query parameter ``results``)."""

    FULL = "full"  # every field of FrameResult (the default)
    COMPACT = "compact"  # CompactFrameResult: no ``joints`` by name, no ``effectors``


class CompactFrameResult(_FrameOutcome):
    """A frame result without ``joints`` (the same values as ``q``, by name) and without
    ``effectors`` (per-effector errors): what ``?results=compact`` answers. ``success``
    and ``status`` still say whether every targeted effector is within tolerance."""

    model_config = ConfigDict(json_schema_extra={"examples": [_EXAMPLE_COMPACT]})


class FramesQuery(BaseModel):
    """Query parameters of ``POST /v1/sessions/{id}/frames``; unknown ones are rejected
    (422), as unknown body fields are. Not strict: query values arrive as text."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    results: ResultView = Field(
        default=ResultView.FULL,
        description="`full` (default): every FrameResult field; `compact`: "
        "CompactFrameResult, without `joints` by name and per-effector `effectors` "
        "(`q` carries the values)",
    )


class CompactFrameResults(StrictModel):
    """One compact result per frame (``?results=compact``), in the order of the frames."""

    results: list[CompactFrameResult]
    plan: PlanSummary | None = Field(
        default=None, description="Present when the clip was planned (`plan: true`)"
    )
