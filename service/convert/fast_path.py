"""The WebSocket's per-frame fast path: a decoded ``frame`` message -> solver targets.

A well-formed frame message, decoded by orjson or msgpack, is checked here by hand and
turned into solver targets directly: pydantic's validation plus ``frames.targets`` cost
about 10x more per frame. The checks are those of the schema (``FrameMessage``,
``Target``, ``Vec3``, ``Quaternion``) and of ``frames.targets``; anything else (a
missing or extra key, a wrong type, a bound, an unknown effector, a missing part, ...)
returns None, and the caller takes the pydantic path, which gives the one documented
error. So the fast path only decides how fast a good frame goes, never what an answer
says (tests/service/test_fast_path.py feeds both paths the same messages).
"""

from __future__ import annotations

import math
from typing import TypeGuard

import numpy as np

from schemas.common import MAX_COORDINATE, QUATERNION_NORM_TOLERANCE
from schemas.solve import HARD_MAX_TARGETS, MAX_FRAME_ID
from solver.ik import GIVEN_DIRECTION, GIVEN_POSITION, GIVEN_ROTATION, TARGET_PLACEHOLDER_ROW
from solver.ik import Target as SolverTarget
from solver.model import EffectorMode

from .chains import ChainView
from .geometry import Flat9, rotation_rows

# (frame id, solver targets) of a frame message the fast path accepted.
FastFrame = tuple[int, list[SolverTarget]]
# A target with a pole takes the pydantic path (its bone is checked there).
_TARGET_KEYS = frozenset(
    ("effector", "position", "orientation", "direction", "position_weight", "rotation_weight")
)


def fast_frame(raw: object, view: ChainView) -> FastFrame | None:
    """``(id, targets)`` of a decoded ``frame`` message (orjson or msgpack) that the
    schema and ``frames.targets`` accept, else None (then validate the message with
    pydantic for the error)."""
    try:
        frame = _fast_frame(raw, view.fast_modes)
        if frame is None or view.convention.identity:
            return frame
        return frame[0], view.convention.targets_in(frame[1])
    except Exception:  # never expected; the pydantic path gives the answer
        return None


def _fast_frame(raw: object, modes: dict[str, EffectorMode]) -> FastFrame | None:
    if type(raw) is not dict or len(raw) != 3 or raw.get("type") != "frame":
        return None
    frame_id = raw.get("id")
    if type(frame_id) is not int or not 0 <= frame_id <= MAX_FRAME_ID:
        return None  # also: no "id" key (None), a bool, a float
    targets = _fast_targets(raw.get("targets"), modes)
    return None if targets is None else (frame_id, targets)


def fast_targets(ts: object, view: ChainView) -> list[SolverTarget] | None:
    """The solver targets of a decoded frame's ``targets`` list (a batch entry's) that
    the schema and ``frames.targets`` accept, else None (then validate with pydantic)."""
    try:
        targets = _fast_targets(ts, view.fast_modes)
        if targets is None or view.convention.identity:
            return targets
        return view.convention.targets_in(targets)
    except Exception:  # never expected; the pydantic path gives the answer
        return None


def _fast_targets(ts: object, modes: dict[str, EffectorMode]) -> list[SolverTarget] | None:
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
        parts = (position is not None) + (orientation is not None) + (direction is not None)
        if len(t) == 1 + parts:  # no weights: a stream's usual target
            out.append(SolverTarget.from_row(name, row, given))
            continue
        wp = _fast_weight(t.get("position_weight", 1.0))
        wr = _fast_weight(t.get("rotation_weight", 1.0))
        if wp is None or wr is None:
            return None
        out.append(SolverTarget.from_row(name, row, given, position_weight=wp, rotation_weight=wr))
    return out


# Target's placeholders for a part not given, as plain floats for the fast path.
_NO_POSITION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[0:3].tolist())
_NO_ROTATION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[3:12].tolist())
_NO_DIRECTION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[12:15].tolist())


def _is_number(v: object) -> TypeGuard[float | int]:
    """A JSON / MessagePack number as pydantic's strict float takes it (not a bool)."""
    return type(v) is float or type(v) is int


def _fast_weight(w: object) -> float | None:
    """A ``BlendWeight``: a number (not a bool) in [0, 1]."""
    if not _is_number(w):
        return None
    w = float(w)
    return w if 0.0 <= w <= 1.0 else None  # NaN fails too


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
    return rotation_rows(w, x, y, z)
