"""Mimic joints (URDF ``<mimic>``): a follower's value is ``multiplier * leader +
offset``. It has no variable of its own: ``resolve_mimics`` finds each follower's
leader (composing a follower of a follower), ``narrow_leaders`` intersects the
leader's range with the follower's, mapped back through the affine map, and
``Followers`` gives the followers' values for a q. Limits that leave the leader no
room (files written for the other sense of the map, e.g. PR2's grippers) are
ignored with a ``mimic_limits_ignored`` note, as ROS and pinocchio ignore them. How
a follower moves in the compiled kinematics is ``chain._compile``'s business
(``layout.ND_RATE``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..arrays import Vector
from ..errors import InvalidModel
from .joints import Joint, JointKind, Mimic
from .notes import ModelNote, NoteKind

# Mimic chains longer than this are a cycle (a follower of a follower of ... itself).
_MAX_MIMIC_DEPTH = 64
# A multiplier or offset beyond this, alone or composed along a chain of mimics, is
# refused: each is finite, but two followers at 1e200 compose to inf, and every frame
# would then end ``nonfinite``. The schemas bound coordinates at 1e6 for the same reason.
MAX_MIMIC_FACTOR = 1e6
# The kinds with one variable: a mimic joint and the leader it follows are one of them.
_SINGLE_DOF = frozenset({JointKind.REVOLUTE, JointKind.CONTINUOUS, JointKind.PRISMATIC})


@dataclass(frozen=True, slots=True)
class Followers:
    """The mimic joints of a chain, resolved to variables: follower i's value is
    ``multiplier[i] * q[leader[i]] + offset[i]`` (chains of mimics composed)."""

    names: tuple[str, ...] = ()
    leader: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    multiplier: Vector = field(default_factory=lambda: np.zeros(0))
    offset: Vector = field(default_factory=lambda: np.zeros(0))

    def values(self, q: Vector) -> Vector:
        """The followers' values for joint values q, in ``names`` order."""
        values: Vector = (
            self.multiplier * np.asarray(q, dtype=np.float64)[self.leader] + self.offset
        )
        return values


def check_mimic(j: Joint) -> None:
    m = j.mimic
    assert m is not None
    if j.kind not in _SINGLE_DOF:
        raise InvalidModel(
            f"a {j.kind.value} joint cannot mimic another: only revolute, continuous and "
            "prismatic joints can",
            joint=j.name,
            field="mimic",
        )
    if m.joint == j.name:
        raise InvalidModel("a joint cannot mimic itself", joint=j.name, field="mimic")
    for name in ("multiplier", "offset"):
        _check_factor(float(getattr(m, name)), name, j.name, composed=False)


def _check_factor(value: float, name: str, joint: str, *, composed: bool) -> None:
    if math.isfinite(value) and abs(value) <= MAX_MIMIC_FACTOR:
        return
    where = " (composed along its chain of mimic joints)" if composed else ""
    raise InvalidModel(
        f"mimic {name} must be a finite number within +-{MAX_MIMIC_FACTOR:g}{where}, not {value:g}",
        joint=joint,
        field=f"mimic.{name}",
    )


def resolve_mimics(checked: list[Joint]) -> dict[str, Mimic]:
    """Each follower's leader as a joint with a variable of its own, the affine maps of
    a chain of mimics composed (URDF allows a follower of a follower)."""
    by_name = {j.name: j for j in checked}
    resolved: dict[str, Mimic] = {}
    for j in checked:
        if j.mimic is None:
            continue
        multiplier, offset, leader = 1.0, 0.0, j
        for _ in range(_MAX_MIMIC_DEPTH):
            m = leader.mimic
            if m is None:
                break
            nxt = by_name.get(m.joint)
            if nxt is None:
                raise InvalidModel(
                    f"mimicked joint {m.joint!r} is not in the chain",
                    joint=leader.name,
                    field="mimic",
                )
            # leader = m.multiplier * nxt + m.offset, so j = multiplier * leader + offset.
            multiplier, offset = multiplier * m.multiplier, multiplier * m.offset + offset
            leader = nxt
        else:
            raise InvalidModel("the mimic joints form a cycle", joint=j.name, field="mimic")
        if leader.kind not in _SINGLE_DOF:
            raise InvalidModel(
                f"mimicked joint {leader.name!r} is {leader.kind.value}: a follower needs a "
                "revolute, continuous or prismatic leader",
                joint=j.name,
                field="mimic",
            )
        _check_factor(multiplier, "multiplier", j.name, composed=True)
        _check_factor(offset, "offset", j.name, composed=True)
        resolved[j.name] = Mimic(leader.name, float(multiplier), float(offset))
    return resolved


def _ignored(joint: str, why: str) -> ModelNote:
    return ModelNote(
        NoteKind.MIMIC_LIMITS_IGNORED,
        joint,
        "limit",
        f"its limits are ignored: {why} (a mimic joint's limits contradicting its map; "
        "ROS and pinocchio ignore them too)",
    )


def narrow_leaders(
    checked: list[Joint],
    mimics: dict[str, Mimic],
    lower: Vector,
    upper: Vector,
    var: dict[str, int],
) -> list[ModelNote]:
    """Intersect each leader's range with its followers' ranges mapped back through
    ``follower = multiplier * leader + offset`` (a negative multiplier swaps the ends)."""
    notes: list[ModelNote] = []
    for j in checked:
        m = mimics.get(j.name)
        if m is None or not j.lower:
            continue
        lo_f, hi_f = j.lower[0], j.upper[0]
        i = var[m.joint]
        if m.multiplier == 0.0:
            if not lo_f <= m.offset <= hi_f:
                notes.append(_ignored(j.name, f"its offset {m.offset!r} is outside them"))
            continue
        a, b = (lo_f - m.offset) / m.multiplier, (hi_f - m.offset) / m.multiplier
        # + 0.0: no -0.0 bound (numpy's uniform refuses high - low = -0.0).
        lo, hi = max(lower[i], min(a, b)) + 0.0, min(upper[i], max(a, b)) + 0.0
        if lo > hi or (lo == hi and lower[i] < upper[i]):
            notes.append(
                _ignored(
                    j.name,
                    f"mapped through the mimic they leave leader {m.joint!r} "
                    f"[{max(lo, hi):.6g}, {min(lo, hi):.6g}] of [{lower[i]:.6g}, {upper[i]:.6g}]",
                )
            )
            continue
        if (lo, hi) != (lower[i], upper[i]):
            notes.append(
                ModelNote(
                    NoteKind.MIMIC_NARROWS_LEADER,
                    j.name,
                    "mimic",
                    f"its limits narrow leader {m.joint!r} from [{lower[i]:.6g}, "
                    f"{upper[i]:.6g}] to [{lo:.6g}, {hi:.6g}]",
                )
            )
        lower[i], upper[i] = lo, hi
    return notes
