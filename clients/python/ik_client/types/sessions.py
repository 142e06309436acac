"""What the service says of a session, typed: its chain's summary (DOFs, effectors,
followers, warnings), its options, pose, conventions and counters."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .enums import Continuity, EffectorMode


@dataclass(frozen=True, slots=True)
class Pose:
    """Schema ``Pose``: joint values in DOF order and by name [rad] or [m]; ``clipped``
    names the DOFs whose value the client sent (``set_pose``, ``initial_pose``) was
    outside the limits and was set to the nearest limit."""

    q: list[float]
    joints: dict[str, float]
    clipped: list[str]

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Pose:
        return cls(d["q"], d["joints"], d.get("clipped", []))


@dataclass(frozen=True, slots=True)
class Dof:
    """Schema ``DofInfo``: one degree of freedom and its limits (None: unbounded)."""

    name: str
    lower: float | None
    upper: float | None


@dataclass(frozen=True, slots=True)
class Effector:
    """Schema ``EffectorInfo``."""

    name: str
    mode: EffectorMode


@dataclass(frozen=True, slots=True)
class Follower:
    """Schema ``FollowerInfo``: a mimic joint, ``multiplier * leader + offset``; not a
    DOF (not in ``q``), its value is in results' ``joints``."""

    name: str
    leader: str
    multiplier: float
    offset: float


@dataclass(frozen=True, slots=True)
class ModelWarning:
    """Schema ``ModelWarning``: the chain's file read by a convention or a default."""

    code: str
    joint: str
    field: str
    message: str


@dataclass(frozen=True, slots=True, kw_only=True)
class SolverOptions:
    """Schema ``SolverOptions``: the effective options of a session."""

    position_tolerance_m: float
    rotation_tolerance_rad: float
    time_budget_us: float
    max_iter: int
    max_restarts: int
    restart_radius_rad: float
    max_step_rad: float
    posture_weight: float
    limit_weight: float
    limit_margin: float
    continuity: Continuity
    max_joint_step_rad: float

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SolverOptions:
        values = {name: d[name] for name in cls.__dataclass_fields__}
        values["continuity"] = Continuity(values["continuity"])
        return cls(**values)


@dataclass(frozen=True, slots=True)
class SessionCounters:
    """Schema ``SessionCounters``."""

    frames: int
    solved: int
    not_solved: int


@dataclass(frozen=True, slots=True, kw_only=True)
class ConventionsOut:
    """Schema ``ConventionsOut``: the coordinates a session speaks."""

    up: str
    handedness: str
    unit_m: float

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> ConventionsOut:
        return cls(up=d["up"], handedness=d["handedness"], unit_m=d["unit_m"])


@dataclass(frozen=True, slots=True, kw_only=True)
class _SessionSummary:
    """What ``Session`` and ``SessionInfo`` both carry: the chain's summary, the options,
    the pose and the conventions."""

    id: str
    n_dof: int
    dof: list[Dof]
    effectors: list[Effector]
    followers: list[Follower]
    warnings: list[ModelWarning]
    options: SolverOptions
    pose: Pose
    idle_ttl_s: float
    conventions: ConventionsOut

    @staticmethod
    def _summary(d: dict[str, Any]) -> dict[str, Any]:
        return {
            "id": d["id"],
            "n_dof": d["n_dof"],
            "dof": [Dof(x["name"], x["lower"], x["upper"]) for x in d["dof"]],
            "effectors": [Effector(x["name"], EffectorMode(x["mode"])) for x in d["effectors"]],
            "followers": [
                Follower(x["name"], x["leader"], x["multiplier"], x["offset"])
                for x in d["followers"]
            ],
            "warnings": [
                ModelWarning(x["code"], x["joint"], x["field"], x["message"]) for x in d["warnings"]
            ],
            "options": SolverOptions.from_json(d["options"]),
            "pose": Pose.from_json(d["pose"]),
            "idle_ttl_s": d["idle_ttl_s"],
            "conventions": ConventionsOut.from_json(d["conventions"]),
        }


@dataclass(frozen=True, slots=True, kw_only=True)
class Session(_SessionSummary):
    """Schema ``SessionCreated``: a new session. ``token`` is shown only once; every call
    on the session takes this object (or any object with ``id`` and ``token``)."""

    token: str

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Session:
        return cls(token=d["token"], **cls._summary(d))


@dataclass(frozen=True, slots=True, kw_only=True)
class SessionInfo(_SessionSummary):
    """Schema ``SessionInfo``: a session's chain summary, options, pose and counters."""

    counters: SessionCounters
    created_at: float
    idle_s: float
    websockets: int

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> SessionInfo:
        c = d["counters"]
        return cls(
            counters=SessionCounters(c["frames"], c["solved"], c["not_solved"]),
            created_at=d["created_at"],
            idle_s=d["idle_s"],
            websockets=d["websockets"],
            **cls._summary(d),
        )
