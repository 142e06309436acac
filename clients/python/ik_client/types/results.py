"""What solving answers, typed: frozen dataclasses built from the JSON of a frame, a
clip, a batch, an fk (over HTTP or the stream), and the stream's answer messages that
carry them under the caller's id."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from ..errors import ServiceError, service_error
from .enums import Status, Termination
from .requests import Quaternion, Vec3


@dataclass(frozen=True, slots=True)
class EffectorError:
    """Schema ``EffectorErrorOut``: the pose error of one targeted effector."""

    name: str
    position_error_m: float | None
    rotation_error_rad: float | None
    within_tolerance: bool

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> EffectorError:
        return cls(d["name"], d["position_error_m"], d["rotation_error_rad"], d["within_tolerance"])


@dataclass(frozen=True, slots=True, kw_only=True)
class FrameResult:
    """Schemas ``FrameResult`` and ``CompactFrameResult``: the answer to one frame.

    ``joints`` and ``effectors`` are None in compact results (``compact=True``). A frame
    that did not reach its targets is a result with ``success`` False, not an error.
    """

    id: int | None
    success: bool
    status: Status
    termination: Termination
    q: list[float]
    joints: dict[str, float] | None
    effectors: list[EffectorError] | None
    iterations: int
    function_evals: int
    passes: int
    restarts: int
    solve_us: float
    server_us: float
    # Largest joint step from the session's previous answer (None: a one-shot solve) and
    # whether it is over the session's ``max_joint_step_rad`` (a jump).
    largest_step_rad: float | None = None
    jumped: bool = False
    # Schema ``BonesOut`` as sent: {"local": {bone: {w,x,y,z}}, "world": {bone: {...}}}.
    bones: dict[str, Any] | None = None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> FrameResult:
        effectors = d.get("effectors")
        return cls(
            id=d["id"],
            success=d["success"],
            status=Status(d["status"]),
            termination=Termination(d["termination"]),
            q=d["q"],
            joints=d.get("joints"),
            effectors=None
            if effectors is None
            else [EffectorError.from_json(e) for e in effectors],
            iterations=d["iterations"],
            function_evals=d["function_evals"],
            passes=d["passes"],
            restarts=d["restarts"],
            solve_us=d["solve_us"],
            server_us=d["server_us"],
            largest_step_rad=d["largest_step_rad"],
            jumped=d["jumped"],
            bones=d.get("bones"),
        )


@dataclass(frozen=True, slots=True)
class EffectorPose:
    """Schema ``EffectorPoseOut``: an effector's world pose in the session's conventions
    (the tip frame its targets are compared with); ``direction``: where an aim
    effector's aim axis points (None for position and pose effectors)."""

    name: str  # as targets address it
    position: Vec3
    orientation: Quaternion
    direction: Vec3 | None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> EffectorPose:
        return cls(d["name"], d["position"], d["orientation"], d.get("direction"))


@dataclass(frozen=True, slots=True)
class FkResult:
    """Schema ``FkResult``: where a pose puts the chain (``POST .../fk``): every
    effector's world pose and, on skeleton chains, the bone data asked for."""

    q: list[float]  # the pose used, in DOF order
    # Schema ``BonesOut`` as sent: {"local": {bone: {w,x,y,z}}, "world": {bone: {...}}};
    # None on chains without bones (URDF, hierarchy, examples). Before ``effectors``:
    # FkResult(q, bones) kept its meaning when they came.
    bones: dict[str, Any] | None = None
    # Every effector, in the chain's order (empty from a server older than them).
    effectors: list[EffectorPose] = field(default_factory=list)
    # The DOFs the pose sent had outside their limits (set to the nearest limit in q).
    clipped: list[str] = field(default_factory=list)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> FkResult:
        effectors = [EffectorPose.from_json(e) for e in d.get("effectors", [])]
        return cls(d["q"], d.get("bones"), effectors, d.get("clipped", []))


@dataclass(frozen=True, slots=True, kw_only=True)
class PlanSummary:
    """Schema ``PlanSummary``: what planning a clip achieved."""

    largest_step_rad: float
    tracked_largest_step_rad: float
    candidates: int
    plan_us: float

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> PlanSummary:
        return cls(
            largest_step_rad=d["largest_step_rad"],
            tracked_largest_step_rad=d["tracked_largest_step_rad"],
            candidates=d["candidates"],
            plan_us=d["plan_us"],
        )


@dataclass(frozen=True, slots=True)
class ClipResult:
    """Schema ``FrameResults``: one result per frame, in order; ``plan`` when planned."""

    results: list[FrameResult]
    plan: PlanSummary | None

    @property
    def success(self) -> bool:
        return all(r.success for r in self.results)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ClipResult:
        plan = d.get("plan")
        return cls(
            [FrameResult.from_json(r) for r in d["results"]],
            None if plan is None else PlanSummary.from_json(plan),
        )


@dataclass(frozen=True, slots=True)
class BatchEntryResult:
    """One entry of a batch's answer (schemas ``BatchEntryResult`` / ``BatchEntryError``):
    its ``result``, or its own ``error`` (a ``ServiceError`` subclass, not raised: the
    other entries were answered)."""

    session: str | None
    id: int | None
    success: bool
    result: FrameResult | None
    error: ServiceError | None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> BatchEntryResult:
        e = d.get("error")
        r = d.get("result")
        error = None
        if e is not None:
            error = service_error(
                e["code"], e["message"], field=e.get("field"),
                retry_after_s=e.get("retry_after_s"),
            )  # fmt: skip
        result = None if r is None else FrameResult.from_json(r)
        return cls(d["session"], d["id"], d["success"], result, error)


# --- stream answers -----------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class FrameAnswer:
    """A ``result`` message: the answer to the stream's frame ``id``; ``success``: the
    frame's (as ``result.success``)."""

    id: int
    result: FrameResult
    success: bool
    type: Literal["result"] = "result"


@dataclass(frozen=True, slots=True)
class ClipAnswer:
    """A ``clip_result`` message: the answer to the stream's clip ``id``."""

    id: int
    clip: ClipResult
    type: Literal["clip_result"] = "clip_result"


@dataclass(frozen=True, slots=True)
class BatchAnswer:
    """A ``batch_result`` message: the answer to the stream's batch ``id``, one entry per
    frame sent, in order, each a result or that entry's own error; ``success``: every
    entry's success."""

    id: int
    results: list[BatchEntryResult]
    success: bool
    type: Literal["batch_result"] = "batch_result"


@dataclass(frozen=True, slots=True)
class Pong:
    """A ``pong`` message: the answer to the stream's ping ``id``."""

    id: int
    type: Literal["pong"] = "pong"


@dataclass(frozen=True, slots=True)
class FkAnswer:
    """An ``fk_result`` message: the answer to the stream's fk ``id``."""

    id: int
    result: FkResult
    type: Literal["fk_result"] = "fk_result"


Answer = FrameAnswer | ClipAnswer | BatchAnswer | FkAnswer | Pong
