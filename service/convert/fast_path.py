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
from collections.abc import Sequence
from typing import Any

import numpy as np

from schemas.common import MAX_COORDINATE, QUATERNION_NORM_TOLERANCE
from schemas.solve import HARD_MAX_TARGETS, MAX_FRAME_ID
from solver.ik import (
    GIVEN_DIRECTION,
    GIVEN_POSITION,
    GIVEN_ROTATION,
    TARGET_PLACEHOLDER_ROW,
    TargetRows,
)
from solver.ik import Target as SolverTarget
from solver.model import EffectorMode

from .chains import ChainView
from .geometry import Flat9, rotation_rows

# (frame id, solver targets) of a frame message the fast path accepted.
FastFrame = tuple[int, Sequence[SolverTarget]]
# A target with a pole takes the pydantic path (its bone is checked there).
_TARGET_KEYS = frozenset(
    ("effector", "position", "orientation", "direction", "position_weight", "rotation_weight")
)


def fast_frame(raw: object, view: ChainView) -> FastFrame | None:
    """``(id, targets)`` of a decoded ``frame`` message (orjson or msgpack) that the
    schema and ``frames.targets`` accept, else None (then validate the message with
    pydantic for the error)."""
    try:
        if type(raw) is not dict or len(raw) != 3 or raw.get("type") != "frame":
            return None
        frame_id = raw.get("id")
        if type(frame_id) is not int or not 0 <= frame_id <= MAX_FRAME_ID:
            return None  # also: no "id" key (None), a bool, a float
        targets = _fast_targets(raw.get("targets"), view.fast_modes)
        if targets is None:
            return None
        if not view.convention.identity:
            targets = view.convention.targets_in(targets)
        return frame_id, targets
    except Exception:  # never expected; the pydantic path gives the answer
        return None


def fast_targets(ts: object, view: ChainView) -> Sequence[SolverTarget] | None:
    """The solver targets of a decoded frame's ``targets`` list (a batch entry's) that
    the schema and ``frames.targets`` accept, else None (then validate with pydantic)."""
    try:
        targets = _fast_targets(ts, view.fast_modes)
        if targets is None or view.convention.identity:
            return targets
        return view.convention.targets_in(targets)
    except Exception:  # never expected; the pydantic path gives the answer
        return None


def _fast_targets(ts: object, modes: dict[str, EffectorMode]) -> Sequence[SolverTarget] | None:
    if type(ts) is not list or not 0 < len(ts) <= HARD_MAX_TARGETS:
        return None
    names: list[str] = []
    rows: list[list[float]] = []
    bits: list[int] = []
    weights: list[tuple[float, float]] | None = None  # once a target has weights
    seen: set[str] = set()
    for t in ts:
        if type(t) is not dict or not _TARGET_KEYS.issuperset(t):  # also: an unknown key
            return None
        name = t.get("effector")
        if type(name) is not str:
            return None
        mode = modes.get(name)
        if mode is None or name in seen:
            return None
        seen.add(name)
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
        # The target's packed row (all of them in one np.array call, below): the
        # dataclass constructor's checks and copies cost more than the rest of the fast
        # path (measured). Placeholders as Target's own. Numbers go in as they came (an
        # int too: np.array converts it as float()).
        given = 0
        if position is None:
            values = list(_NO_POSITION)
        else:
            if (p := _fast_vec3(position)) is None:
                return None
            values = p
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
        names.append(name)
        rows.append(values)
        bits.append(given)
        parts = (position is not None) + (orientation is not None) + (direction is not None)
        if len(t) == 1 + parts and weights is None:  # no weights: a stream's usual target
            continue
        wp = _fast_weight(t.get("position_weight", 1.0))
        wr = _fast_weight(t.get("rotation_weight", 1.0))
        if wp is None or wr is None:
            return None
        if weights is None:  # the targets before this one had none
            weights = [(1.0, 1.0)] * (len(rows) - 1)
        weights.append((wp, wr))
    if weights is None:  # plain targets: their rows as they are (no Target each)
        return TargetRows(tuple(names), np.array(rows, dtype=np.float64), tuple(bits))
    return [
        SolverTarget.from_row(
            name, np.array(values, dtype=np.float64), given, position_weight=wp, rotation_weight=wr
        )
        for name, values, given, (wp, wr) in zip(names, rows, bits, weights, strict=True)
    ]


# Target's placeholders for a part not given, as plain floats for the fast path.
_NO_POSITION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[0:3].tolist())
_NO_ROTATION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[3:12].tolist())
_NO_DIRECTION: tuple[float, ...] = tuple(TARGET_PLACEHOLDER_ROW[12:15].tolist())


# A JSON / MessagePack number as pydantic's strict float takes it (not a bool): tested
# as ``type(v) in _NUMBERS``, inline, per number (a helper's call per number was a
# seventh of the fast path).
_NUMBERS = frozenset((float, int))


def _fast_weight(w: object) -> float | None:
    """A ``BlendWeight``: a number (not a bool) in [0, 1]."""
    if type(w) not in _NUMBERS:
        return None
    value = float(w)  # type: ignore[arg-type]  # a float or an int
    return value if 0.0 <= value <= 1.0 else None  # NaN fails too


def _fast_vec3(v: object) -> list[float] | None:
    """A ``Vec3`` (exactly x, y, z, each a number, not a bool, within +-MAX_COORDINATE)
    as a new list, the start of a packed row."""
    if type(v) is not dict or len(v) != 3:
        return None
    x: Any = v.get("x")
    y: Any = v.get("y")
    z: Any = v.get("z")
    numbers = _NUMBERS
    if not (type(x) in numbers and type(y) in numbers and type(z) in numbers):
        return None  # also: a key missing (None) or another key instead
    lim = MAX_COORDINATE
    if -lim <= x <= lim and -lim <= y <= lim and -lim <= z <= lim:
        return [x, y, z]  # NaN fails above
    return None


def _fast_rotation(q: object) -> Flat9 | None:
    """A ``Quaternion`` (exactly w, x, y, z, finite, unit norm within the tolerance) as
    the matrix ``targets`` would build, row after row."""
    if type(q) is not dict or len(q) != 4:
        return None
    w: Any = q.get("w")
    x: Any = q.get("x")
    y: Any = q.get("y")
    z: Any = q.get("z")
    numbers = _NUMBERS
    if not (type(w) in numbers and type(x) in numbers and type(y) in numbers):
        return None
    if type(z) not in numbers:
        return None
    # The schema's test, computed the same way (hypot: no overflow). Written so that a
    # non-finite part fails it too: hypot is inf with an inf part, else NaN with a NaN
    # part, and neither is within the tolerance of 1.
    if not abs(math.hypot(w, x, y, z) - 1.0) <= QUATERNION_NORM_TOLERANCE:
        return None
    return rotation_rows(w, x, y, z)
