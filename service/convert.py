"""schemas <-> solver: the only module that imports both.

Every solver exception raised while turning a request into solver objects becomes a
``ServiceError("invalid_problem")`` naming the request field (``chain.joints[2].lower``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, TypeGuard, cast

import numpy as np
import orjson

import schemas as S
from schemas.chain import MAX_NAME_LENGTH
from schemas.common import MAX_COORDINATE, QUATERNION_NORM_TOLERANCE
from schemas.solve import HARD_MAX_TARGETS, MAX_FRAME_ID
from solver.arrays import Vector
from solver.errors import IKError, InvalidModel
from solver.ik import (
    GIVEN_DIRECTION,
    GIVEN_POSITION,
    GIVEN_ROTATION,
    STREAM_DEFAULTS,
    TARGET_PLACEHOLDER_ROW,
    IKOptions,
    IKResult,
)
from solver.ik import Target as SolverTarget
from solver.model import (
    Chain,
    Effector,
    EffectorMode,
    Joint,
    JointKind,
    Transform,
    build_chain,
)
from solver.model.examples import EXAMPLES
from solver.model.urdf import chain_from_urdf
from solver.path import PlannedPath

from .config import Settings
from .errors import invalid_problem

_EFFECTOR_FIELDS = frozenset(
    {"link", "tip_offset", "tip_rotation", "aim_axis", "position_weight", "rotation_weight", "mode"}
)
_URDF_REQUEST_FIELDS = frozenset({"base_link", "tip_links", "mode"})


@dataclass(frozen=True, slots=True)
class ChainView:
    """A chain plus the lookups the service needs on every frame."""

    chain: Chain
    effector_modes: dict[str, EffectorMode]
    dof_index: dict[str, int]
    summary: dict[str, Any]  # n_dof, dof (with limits), effectors: JSON-ready
    mid_limits: Vector  # the default seed: middle of each range, 0 if unbounded
    # The effectors a target may name (a valid Name) -> mode: the fast path's lookup.
    fast_modes: dict[str, EffectorMode]

    @classmethod
    def of(cls, chain: Chain) -> ChainView:
        modes = {e.name: e.mode for e in chain.effectors}
        dof = [
            {"name": n, "lower": _finite_or_none(lo), "upper": _finite_or_none(hi)}
            for n, lo, hi in zip(chain.dof_names, chain.lower, chain.upper, strict=True)
        ]
        summary = {
            "n_dof": chain.n_dof,
            "dof": dof,
            "effectors": [{"name": e.name, "mode": e.mode.value} for e in chain.effectors],
        }
        index = {n: i for i, n in enumerate(chain.dof_names)}
        finite = np.isfinite(chain.lower) & np.isfinite(chain.upper)
        mid = np.where(
            finite,
            0.5 * (np.where(finite, chain.lower, 0.0) + np.where(finite, chain.upper, 0.0)),
            0.0,
        )
        fast = {n: m for n, m in modes.items() if 1 <= len(n) <= MAX_NAME_LENGTH}
        return cls(chain, modes, index, summary, mid, fast)


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


# --- chains ----------------------------------------------------------------------------
def chain_from_spec(
    spec: S.HierarchyChain | S.UrdfChain | S.ExampleChain, settings: Settings
) -> ChainView:
    """Build and validate the chain a request describes, within the server's limits.

    Raises:
        ServiceError: ``invalid_problem`` naming the field (``chain.joints[i].<field>``).
    """
    if isinstance(spec, S.ExampleChain):
        factory = cast(Callable[[], Chain], EXAMPLES[spec.name])
        chain = factory()
    elif isinstance(spec, S.UrdfChain):
        chain = _urdf_chain(spec, settings)
    else:
        chain = _hierarchy_chain(spec, settings)
    if chain.n_dof > settings.max_dof:
        raise invalid_problem(
            f"too many degrees of freedom: {chain.n_dof} > {settings.max_dof}", "chain"
        )
    if len(chain.joints) > settings.max_joints:
        raise invalid_problem(
            f"too many joints: {len(chain.joints)} > {settings.max_joints}", "chain"
        )
    return ChainView.of(chain)


def _urdf_chain(spec: S.UrdfChain, settings: Settings) -> Chain:
    if len(spec.tip_links) > settings.max_effectors:
        raise invalid_problem(
            f"too many tip links: {len(spec.tip_links)} > {settings.max_effectors}",
            "chain.tip_links",
        )
    try:
        return chain_from_urdf(
            spec.urdf,
            base_link=spec.base_link,
            tip_links=spec.tip_links,
            mode=EffectorMode(spec.mode),
            max_dof=settings.max_dof,
            max_bytes=settings.max_urdf_bytes,
        )
    except InvalidModel as e:
        field = f"chain.{e.field}" if e.field in _URDF_REQUEST_FIELDS else "chain.urdf"
        raise invalid_problem(str(e), field) from None


def _vec(v: S.Vec3) -> Vector:
    return np.array((v.x, v.y, v.z), dtype=np.float64)


def _rotation(q: S.Quaternion) -> Vector:
    """Rotation matrix of the normalised quaternion."""
    return np.array(_rotation_flat(q.w, q.x, q.y, q.z)).reshape(3, 3)


Flat9 = tuple[float, float, float, float, float, float, float, float, float]


def _rotation_flat(qw: float, qx: float, qy: float, qz: float) -> Flat9:
    """Rotation matrix of the normalised quaternion (w, x, y, z), row after row as
    plain floats: this is per frame, and the fast path packs them into the target's
    row as they are."""
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, x, y, z = qw / n, qx / n, qy / n, qz / n
    return (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )  # fmt: skip


def _hierarchy_chain(spec: S.HierarchyChain, settings: Settings) -> Chain:
    if len(spec.joints) > settings.max_joints:
        raise invalid_problem(
            f"too many joints: {len(spec.joints)} > {settings.max_joints}", "chain.joints"
        )
    if len(spec.effectors) > settings.max_effectors:
        raise invalid_problem(
            f"too many effectors: {len(spec.effectors)} > {settings.max_effectors}",
            "chain.effectors",
        )
    joints = [
        Joint(
            name=j.name,
            parent=j.parent,
            child=j.child,
            kind=JointKind(j.kind),
            origin=Transform(_vec(j.origin.translation), _rotation(j.origin.rotation)),
            pivot=_vec(j.pivot),
            axis=_vec(j.axis),
            axes=j.axes,
            lower=tuple(j.lower),
            upper=tuple(j.upper),
            terminator=j.terminator,
        )
        for j in spec.joints
    ]
    effectors = [
        Effector(
            name=e.name,
            link=e.link,
            tip_offset=_vec(e.tip_offset),
            tip_rotation=_rotation(e.tip_rotation),
            mode=EffectorMode(e.mode),
            aim_axis=_vec(e.aim_axis),
            position_weight=e.position_weight,
            rotation_weight=e.rotation_weight,
        )
        for e in spec.effectors
    ]
    try:
        return build_chain(joints, effectors, max_dof=settings.max_dof)
    except InvalidModel as e:
        raise invalid_problem(str(e), _hierarchy_field(spec, e)) from None


def _hierarchy_field(spec: S.HierarchyChain, e: InvalidModel) -> str:
    """The request path of the joint / effector field an InvalidModel names."""
    field = e.field or ""
    if field in ("rotation", "translation"):
        field = f"origin.{field}"
    if e.joint is not None:
        if field in _EFFECTOR_FIELDS or (
            field == "name" and not any(j.name == e.joint for j in spec.joints)
        ):
            for i, eff in enumerate(spec.effectors):
                if eff.name == e.joint:
                    return f"chain.effectors[{i}].{field}" if field else f"chain.effectors[{i}]"
        indexed = list(enumerate(spec.joints))
        if field == "name":  # a duplicate: the later joint is the one at fault
            indexed.reverse()
        for i, j in indexed:
            # A duplicate variable is named "<joint>.<axis>" for rotational joints.
            if e.joint in (j.name, *(f"{j.name}.{a}" for a in j.axes)):
                return f"chain.joints[{i}].{field}" if field else f"chain.joints[{i}]"
    if field in ("joints", "effectors"):
        return f"chain.{field}"
    if field in ("parent", "name", "child"):
        return "chain.joints"
    return f"chain.{field}" if field else "chain"


# --- options ---------------------------------------------------------------------------
def session_defaults(settings: Settings) -> IKOptions:
    """Stream defaults (local restarts, light limit pull) with the server's settings."""
    return replace(
        STREAM_DEFAULTS,
        time_budget_us=settings.default_time_budget_us,
        position_tolerance_m=settings.default_position_tolerance_m,
        rotation_tolerance_rad=settings.default_rotation_tolerance_rad,
        max_iter=settings.default_max_iter,
        max_restarts=settings.default_max_restarts,
    )


def oneshot_defaults(settings: Settings) -> IKOptions:
    """One-shot defaults (restarts anywhere in the limits) with the server's settings."""
    return replace(
        IKOptions(),
        time_budget_us=settings.default_time_budget_us,
        position_tolerance_m=settings.default_position_tolerance_m,
        rotation_tolerance_rad=settings.default_rotation_tolerance_rad,
        max_iter=settings.default_max_iter,
        max_restarts=settings.default_max_restarts,
    )


def apply_options(
    patch: S.OptionsPatch | None, base: IKOptions, settings: Settings, *, field: str = "options"
) -> IKOptions:
    """``base`` with the fields ``patch`` sets, validated by the solver and the server caps."""
    if patch is None:
        return base
    changes = patch.model_dump(exclude_none=True)
    budget = changes.get("time_budget_us")
    if budget is not None and budget > settings.max_time_budget_us:
        raise invalid_problem(
            f"time_budget_us must be at most {settings.max_time_budget_us:g} "
            "(IK_MAX_TIME_BUDGET_US)",
            f"{field}.time_budget_us",
        )
    try:
        return replace(base, **changes)
    except IKError as e:
        raise invalid_problem(str(e), field) from None


def options_dict(o: IKOptions) -> dict[str, Any]:
    """The SolverOptions view of IKOptions (JSON-ready)."""
    return {
        "position_tolerance_m": o.position_tolerance_m,
        "rotation_tolerance_rad": o.rotation_tolerance_rad,
        "time_budget_us": o.time_budget_us,
        "max_iter": o.max_iter,
        "max_restarts": o.max_restarts,
        "restart_radius_rad": o.restart_radius_rad if math.isfinite(o.restart_radius_rad) else 1e9,
        "max_step_rad": o.max_step_rad,
        "posture_weight": o.posture_weight,
        "limit_weight": o.limit_weight,
        "limit_margin": o.limit_margin,
    }


# --- targets and poses -----------------------------------------------------------------
def clip_jobs(
    frames: Sequence[S.Frame], view: ChainView, limit: int
) -> list[tuple[int | None, list[SolverTarget]]]:
    """(frame id, solver targets) per frame of a clip, at most ``limit`` frames
    (IK_MAX_FRAMES_PER_REQUEST); the same over HTTP and WebSocket.

    Raises:
        ServiceError: too many frames (``frames``), or a frame's targets (``targets``).
    """
    if len(frames) > limit:
        raise invalid_problem(
            f"at most {limit} frames per request (IK_MAX_FRAMES_PER_REQUEST)", "frames"
        )
    return [(f.id, targets(f.targets, view, f"frames[{i}].targets")) for i, f in enumerate(frames)]


def targets(ts: Sequence[S.Target], view: ChainView, field: str) -> list[SolverTarget]:
    """Solver targets for one frame, checked against the chain's effectors.

    Raises:
        ServiceError: unknown effector, two targets for one effector, or a target that
            lacks (or adds) what the effector's mode uses; ``field`` names it.
    """
    out: list[SolverTarget] = []
    seen: set[str] = set()
    for j, t in enumerate(ts):
        where = f"{field}[{j}]"
        mode = view.effector_modes.get(t.effector)
        if mode is None:
            raise invalid_problem(
                f"unknown effector {t.effector!r} (effectors: {sorted(view.effector_modes)})",
                f"{where}.effector",
            )
        if t.effector in seen:
            raise invalid_problem(f"two targets for effector {t.effector!r}", f"{where}.effector")
        seen.add(t.effector)
        if mode is EffectorMode.POSITION:
            _require(
                t.position is not None, "a position effector needs 'position'", where, "position"
            )
            _require(
                t.orientation is None,
                "a position effector takes no 'orientation'",
                where,
                "orientation",
            )
            _require(
                t.direction is None, "a position effector takes no 'direction'", where, "direction"
            )
        elif mode is EffectorMode.POSE:
            _require(
                t.orientation is not None,
                "a pose effector needs 'orientation'",
                where,
                "orientation",
            )
            _require(
                t.direction is None, "a pose effector takes no 'direction'", where, "direction"
            )
        else:
            _require(
                t.direction is not None, "an aim effector needs 'direction'", where, "direction"
            )
            _require(
                t.orientation is None,
                "an aim effector takes no 'orientation'",
                where,
                "orientation",
            )
        direction = None
        if t.direction is not None:
            d = t.direction
            if not math.sqrt(d.x * d.x + d.y * d.y + d.z * d.z) > 1e-9:
                raise invalid_problem("direction must not be zero", f"{where}.direction")
            direction = _vec(d)
        out.append(
            SolverTarget(
                effector=t.effector,
                position=None if t.position is None else _vec(t.position),
                rotation=None if t.orientation is None else _rotation(t.orientation),
                direction=direction,
            )
        )
    return out


def _require(ok: bool, message: str, where: str, name: str) -> None:
    if not ok:
        raise invalid_problem(message, f"{where}.{name}")


# --- the per-frame fast path -----------------------------------------------------------
# A well-formed frame message, decoded by orjson or msgpack, is checked here by hand and
# turned into solver targets directly: pydantic's validation plus ``targets`` cost about
# 10x more per frame. The checks are those of the schema (``FrameMessage``, ``Target``,
# ``Vec3``, ``Quaternion``) and of ``targets``; anything else (a missing or extra key,
# a wrong type, a bound, an unknown effector, a missing part, ...) returns None, and the
# caller takes the pydantic path, which gives the one documented error. So the fast path
# only decides how fast a good frame goes, never what an answer says
# (tests/service/test_fast_path.py feeds both paths the same messages).
FastFrame = tuple[int, list[SolverTarget]]
_TARGET_KEYS = frozenset(("effector", "position", "orientation", "direction"))


def fast_frame(raw: object, view: ChainView) -> FastFrame | None:
    """``(id, targets)`` of a decoded ``frame`` message that the schema and ``targets``
    accept, else None (then validate the message with pydantic for the error)."""
    try:
        return _fast_frame(raw, view.fast_modes)
    except Exception:  # never expected; the pydantic path gives the answer
        return None


def fast_frame_json(text: str | bytes, view: ChainView) -> FastFrame | None:
    """``fast_frame`` of a JSON text (None when orjson cannot read it)."""
    try:
        raw = orjson.loads(text)
    except orjson.JSONDecodeError:
        return None
    return fast_frame(raw, view)


def _fast_frame(raw: object, modes: dict[str, EffectorMode]) -> FastFrame | None:
    if type(raw) is not dict or len(raw) != 3 or raw.get("type") != "frame":
        return None
    frame_id = raw.get("id")
    ts = raw.get("targets")
    if type(frame_id) is not int or not 0 <= frame_id <= MAX_FRAME_ID:
        return None  # also: no "id" key (None), a bool, a float
    if type(ts) is not list or not 0 < len(ts) <= HARD_MAX_TARGETS:
        return None
    out: list[SolverTarget] = []
    seen: set[str] = set()
    for t in ts:
        if type(t) is not dict:
            return None
        name = t.get("effector")
        if type(name) is not str:
            return None
        mode = modes.get(name)
        if mode is None or name in seen:
            return None
        seen.add(name)
        for key in t:
            if key not in _TARGET_KEYS:
                return None
        position = t.get("position")
        orientation = t.get("orientation")
        direction = t.get("direction")
        if mode is EffectorMode.POSITION:
            if position is None or orientation is not None or direction is not None:
                return None
        elif mode is EffectorMode.POSE:
            if orientation is None or direction is not None:
                return None
        elif direction is None or orientation is not None:
            return None
        # The target's packed row, built here in one list and one np.array call
        # (Target.from_row): the dataclass constructor's checks and copies cost more
        # than the rest of the fast path (measured). Placeholders as Target's own.
        given = 0
        if position is None:
            values = list(_NO_POSITION)
        else:
            if (p := _fast_vec3(position)) is None:
                return None
            values = list(p)
            given = GIVEN_POSITION
        if orientation is None:
            values += _NO_ROTATION
        else:
            if (r := _fast_rotation(orientation)) is None:
                return None
            values += r
            given |= GIVEN_ROTATION
        if direction is None:
            values += _NO_DIRECTION
        else:
            if (d := _fast_vec3(direction)) is None:
                return None
            dx, dy, dz = d
            if not math.sqrt(dx * dx + dy * dy + dz * dz) > 1e-9:
                return None
            values += d
            given |= GIVEN_DIRECTION
        row = np.array(values, dtype=np.float64)
        out.append(SolverTarget.from_row(name, row, given))
    return frame_id, out


# Target's placeholders for a part not given, as plain floats for the fast path.
_NO_POSITION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[0:3].tolist())
_NO_ROTATION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[3:12].tolist())
_NO_DIRECTION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[12:15].tolist())


def _is_number(v: object) -> TypeGuard[float | int]:
    """A JSON / MessagePack number as pydantic's strict float takes it (not a bool)."""
    return type(v) is float or type(v) is int


def _fast_vec3(v: object) -> tuple[float, float, float] | None:
    """A ``Vec3``: exactly x, y, z, each a number (not a bool) within +-MAX_COORDINATE."""
    if type(v) is not dict or len(v) != 3:
        return None
    x = v.get("x")
    y = v.get("y")
    z = v.get("z")
    if not (_is_number(x) and _is_number(y) and _is_number(z)):
        return None  # also: a key missing (None) or another key instead
    x = float(x)
    y = float(y)
    z = float(z)
    lim = MAX_COORDINATE
    if -lim <= x <= lim and -lim <= y <= lim and -lim <= z <= lim:  # NaN fails too
        return x, y, z
    return None


def _fast_rotation(q: object) -> Flat9 | None:
    """A ``Quaternion`` (exactly w, x, y, z, finite, unit norm within the tolerance) as
    the matrix ``targets`` would build, row after row."""
    if type(q) is not dict or len(q) != 4:
        return None
    w = q.get("w")
    x = q.get("x")
    y = q.get("y")
    z = q.get("z")
    if not (_is_number(w) and _is_number(x) and _is_number(y) and _is_number(z)):
        return None
    w = float(w)
    x = float(x)
    y = float(y)
    z = float(z)
    isfinite = math.isfinite
    if not (isfinite(w) and isfinite(x) and isfinite(y) and isfinite(z)):
        return None
    # The schema's test, computed the same way (hypot: no overflow).
    if abs(math.hypot(w, x, y, z) - 1.0) > QUATERNION_NORM_TOLERANCE:
        return None
    return _rotation_flat(w, x, y, z)


def pose_vector(pose: S.PoseIn, view: ChainView, current: Vector, field: str) -> Vector:
    """A full q from a PoseIn (``joints`` fills in ``current``), clipped into the limits."""
    chain = view.chain
    if pose.q is not None:
        if len(pose.q) != chain.n_dof:
            raise invalid_problem(
                f"q must have {chain.n_dof} values (one per DOF), got {len(pose.q)}", f"{field}.q"
            )
        q = np.array(pose.q, dtype=np.float64)
    else:
        assert pose.joints is not None
        q = np.array(current, dtype=np.float64)
        for name, value in pose.joints.items():
            i = view.dof_index.get(name)
            if i is None:
                raise invalid_problem(
                    f"unknown DOF {name!r} (DOFs: {list(chain.dof_names)})",
                    f"{field}.joints.{name}",
                )
            q[i] = value
    return np.clip(q, chain.lower, chain.upper)


def pose_dict(view: ChainView, q: Vector) -> dict[str, Any]:
    values = q.tolist()
    return {"q": values, "joints": dict(zip(view.chain.dof_names, values, strict=True))}


# --- results ---------------------------------------------------------------------------
ResultBuilder = Callable[[IKResult, int | None, float], dict[str, Any]]


def result_dict(r: IKResult, frame_id: int | None, server_us: float) -> dict[str, Any]:
    """A FrameResult as a JSON/MessagePack-ready dict (the hot path: no re-validation;
    tests check the shape against ``schemas.FrameResult``).

    The per-effector errors are read from the result's raw rows (position error or NaN,
    rotation error or NaN, targeted flag) with the names and tolerances the solver's
    ``layout`` holds once per session and options, not through ``IKResult.effectors``,
    which builds an object per effector first (the same values; tests compare them).
    """
    layout = r.layout
    values = r.q.tolist()
    tol_p, tol_r = layout.tolerances
    isnan = math.isnan
    effectors = []
    for name, (pos, rot, targeted) in zip(
        layout.effector_names, r.raw_errors.tolist(), strict=True
    ):
        if not targeted:
            continue
        p = None if isnan(pos) else pos
        e = None if isnan(rot) else rot
        effectors.append(
            {
                "name": name,
                "position_error_m": p,
                "rotation_error_rad": e,
                "within_tolerance": (p is None or p <= tol_p) and (e is None or e <= tol_r),
            }
        )
    return {
        "id": frame_id,
        "success": r.success,
        "status": r.status.value,
        "termination": r.termination.value,
        "joints": dict(zip(layout.dof_names, values, strict=True)),
        "q": values,
        "effectors": effectors,
        "iterations": r.iterations,
        "function_evals": r.function_evals,
        "passes": r.passes,
        "restarts": r.restarts,
        "solve_us": r.solve_us,
        "server_us": server_us,
    }


def plan_summary(plan: PlannedPath) -> dict[str, Any]:
    """A PlanSummary's fields."""
    return {
        "largest_step_rad": plan.largest_step,
        "tracked_largest_step_rad": plan.tracked_largest_step,
        "candidates": plan.nodes,
        "plan_us": plan.plan_us,
    }


def compact_result_dict(r: IKResult, frame_id: int | None, server_us: float) -> dict[str, Any]:
    """A CompactFrameResult (``?results=compact``): no ``joints`` by name and no
    per-effector errors, which a stream reading ``q`` does not need. About a third of
    a panda answer's bytes and less work to build and encode; tests check the shape
    against ``schemas.CompactFrameResult``."""
    return {
        "id": frame_id,
        "success": r.success,
        "status": r.status.value,
        "termination": r.termination.value,
        "q": r.q.tolist(),
        "iterations": r.iterations,
        "function_evals": r.function_evals,
        "passes": r.passes,
        "restarts": r.restarts,
        "solve_us": r.solve_us,
        "server_us": server_us,
    }


_RESULT_BUILDERS: dict[S.ResultView, ResultBuilder] = {
    S.ResultView.FULL: result_dict,
    S.ResultView.COMPACT: compact_result_dict,
}


def result_builder(view: S.ResultView) -> ResultBuilder:
    """What turns an IKResult into the answer ``view`` asks for."""
    return _RESULT_BUILDERS[view]
