"""What an effector should reach in a frame: ``Target``, packed once into one row.

A packed row is what a solve copies into the compiled arrays (``model.layout``'s ED
target columns): position (3), rotation (9, row-major), direction (3).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import overload

import numpy as np

from ..arrays import Matrix, Vector
from ..errors import InvalidProblem
from ..model import Chain, EffectorMode
from ..model.forward import effector_poses

# Bits of Target.given.
GIVEN_POSITION = 1
GIVEN_ROTATION = 2
GIVEN_DIRECTION = 4
# A packed target row: position (3), rotation (9, row-major), direction (3). Parts a
# target leaves out keep these finite placeholders (the compiled check rejects
# non-finite numbers anywhere in the row; a missing part's weight is zero).
TARGET_ROW = 15
_FLOAT64 = np.dtype(np.float64)
# A target row's values where a part is not given (position, rotation, direction).
TARGET_PLACEHOLDER_ROW = np.array([0.0, 0.0, 0.0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0.0, 0.0, 1.0])
TARGET_PLACEHOLDER_ROW.setflags(write=False)


@dataclass(frozen=True, slots=True)
class Pole:
    """A point that a mid-chain link (a knee, an elbow) should bend towards: soft, it
    chooses the bend side and never makes a reachable frame fail (``poles``).

    Attributes:
        point: World point (root frame of the chain) [m], shape (3,), finite.
        link: The link whose origin is pulled towards ``point`` (for a skeleton, the
            bone whose joint is the knee or elbow: the shin or forearm bone); on the
            effector's path to the root. None: the middle of the effector's limb
            (``poles.default_pole_link``).
    """

    point: Vector
    link: str | None = None

    def __post_init__(self) -> None:
        try:
            point = np.array(self.point, dtype=np.float64).reshape(3)
        except (ValueError, TypeError):
            raise InvalidProblem("a pole point needs 3 numbers") from None
        if not np.isfinite(point).all():
            raise InvalidProblem("a pole point must be finite")
        point.setflags(write=False)
        object.__setattr__(self, "point", point)


def check_weight(value: object, name: str) -> float:
    """A blend weight as a float in [0, 1].

    Raises:
        InvalidProblem: not a number (bools are not), NaN, or outside [0, 1].
    """
    if type(value) is not float and type(value) is not int:
        raise InvalidProblem(f"{name} must be a number in [0, 1], got {value!r}")
    w = float(value)
    if not 0.0 <= w <= 1.0:  # NaN fails too
        raise InvalidProblem(f"{name} must be in [0, 1], got {value!r}")
    return w


@dataclass(frozen=True, slots=True, kw_only=True)
class Target:
    """What one effector should reach in this frame (world frame of the chain's root).

    Attributes:
        effector: Effector name.
        position: Target tip position [m], shape (3,). Required for POSITION; for
            POSE and AIM optional (None drops the position term this frame).
        rotation: Target tip orientation, 3x3 rotation matrix (POSE).
        direction: Unit direction the aim axis should point along (AIM).
        position_weight: Blend weight of the position part in [0, 1]: 1 exact (as
            without weights), 0 free (not pulled, not judged), in between a soft
            pull towards the point that fraction of the way from where the tip was
            at the frame's start; a part below 1 never makes the frame fail
            (``blend``).
        rotation_weight: The same for the rotation (POSE) or direction (AIM) part.
        pole: Where the effector's limb should bend (``Pole``), or None.
        packed: The numbers as one read-only float64 row (position, rotation,
            direction), built once here so that a solve copies one row per target;
            a target reused across solves (a benchmark, a replayed clip) is packed
            once. The given parts then read as views of this row: a Target is a
            snapshot, later edits to the arrays it was built from do not reach it.
        given: Which parts were given (GIVEN_* bits).
        plain: Both weights 1 and no pole (what a solve can load with one row copy).

    Raises:
        InvalidProblem: a part of the wrong shape (finiteness and orthonormality
            are checked in the compiled solve), a weight outside [0, 1].
    """

    effector: str
    position: Vector | None = None
    rotation: Matrix | None = None
    direction: Vector | None = None
    position_weight: float = 1.0
    rotation_weight: float = 1.0
    pole: Pole | None = None
    packed: np.ndarray = field(init=False, repr=False, compare=False)
    given: int = field(init=False, repr=False, compare=False)
    plain: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._set_extras(self.position_weight, self.rotation_weight, self.pole)
        try:
            fast = _pack_sequences(self.position, self.rotation, self.direction)
        except (ValueError, TypeError):
            fast = None  # the array path below names the problem
        if fast is not None:
            self._freeze(*fast)
            return
        row = TARGET_PLACEHOLDER_ROW.copy()
        given = 0
        try:
            if self.position is not None:
                row[0:3] = _exact_shape(self.position, (3,))
                given |= GIVEN_POSITION
            if self.rotation is not None:
                row[3:12] = _exact_shape(self.rotation, (3, 3)).reshape(9)
                given |= GIVEN_ROTATION
            if self.direction is not None:
                row[12:15] = _exact_shape(self.direction, (3,))
                given |= GIVEN_DIRECTION
        except (ValueError, TypeError):
            raise InvalidProblem(
                f"target for {self.effector!r}: position and direction need 3 numbers, "
                "rotation a 3x3 matrix"
            ) from None
        self._freeze(row, given)

    @classmethod
    def from_row(
        cls,
        effector: str,
        row: np.ndarray,
        given: int,
        *,
        position_weight: float = 1.0,
        rotation_weight: float = 1.0,
        pole: Pole | None = None,
    ) -> Target:
        """A Target from a row its caller packed: TARGET_ROW float64 values (position,
        rotation, direction; ``TARGET_PLACEHOLDER_ROW``'s values where a part is not given)
        and the GIVEN_* bits of the parts given. The row must own its data (not a view
        of another array, which could still change it); it is kept, not copied, and
        made read-only.

        For a caller that builds a row per target per frame (the service's fast path):
        the dataclass ``__init__`` with its sequence checks costs about 2.8 us warm,
        this about 1.5 us. The numbers are checked as in any solve (finiteness,
        orthonormality: in the compiled code).

        Raises:
            InvalidProblem: a row of the wrong shape or dtype, a view, unknown bits,
                or a weight outside [0, 1].
        """
        if (
            type(row) is not np.ndarray
            or row.shape != (TARGET_ROW,)
            or row.dtype != _FLOAT64  # also rejects a byte-swapped float64
            or row.base is not None
            or type(given) is not int
            or not 0 <= given <= GIVEN_POSITION | GIVEN_ROTATION | GIVEN_DIRECTION
        ):
            raise InvalidProblem(
                f"target for {effector!r}: a packed row is {TARGET_ROW} float64 values "
                "in an array of its own, with GIVEN_* bits"
            )
        target = object.__new__(cls)
        set_field = object.__setattr__
        set_field(target, "effector", effector)
        set_field(target, "position", None)
        set_field(target, "rotation", None)
        set_field(target, "direction", None)
        if (
            pole is None
            and type(position_weight) is float
            and type(rotation_weight) is float
            and position_weight == 1.0
            and rotation_weight == 1.0
        ):
            set_field(target, "position_weight", 1.0)
            set_field(target, "rotation_weight", 1.0)
            set_field(target, "pole", None)
            set_field(target, "plain", True)
        else:
            target._set_extras(position_weight, rotation_weight, pole)
        target._freeze(row, given)
        return target

    def _set_extras(self, position_weight: object, rotation_weight: object, pole: object) -> None:
        """Check and keep the weights and the pole; ``plain`` when they change nothing."""
        set_field = object.__setattr__
        wp = check_weight(position_weight, f"target for {self.effector!r}: position_weight")
        wr = check_weight(rotation_weight, f"target for {self.effector!r}: rotation_weight")
        if pole is not None and not isinstance(pole, Pole):
            raise InvalidProblem(f"target for {self.effector!r}: pole must be a Pole")
        set_field(self, "position_weight", wp)
        set_field(self, "rotation_weight", wr)
        set_field(self, "pole", pole)
        set_field(self, "plain", wp == 1.0 and wr == 1.0 and pole is None)

    def _freeze(self, row: np.ndarray, given: int) -> None:
        """Keep the packed row, read-only, and show the given parts as views of it: a
        Target is a snapshot (later edits to the arrays it was built from do not
        reach it), and what it shows is exactly what a solve copies."""
        row.setflags(write=False)  # half the time of ``row.flags.writeable = False``
        set_field = object.__setattr__
        set_field(self, "packed", row)
        set_field(self, "given", given)
        if given & GIVEN_POSITION:
            set_field(self, "position", row[0:3])
        if given & GIVEN_ROTATION:
            set_field(self, "rotation", row[3:12].reshape(3, 3))
        if given & GIVEN_DIRECTION:
            set_field(self, "direction", row[12:15])


class TargetRows(Sequence[Target]):
    """A frame's targets, each plain (both weights 1, no pole), as the rows of one
    packed array: what a caller that builds targets for every frame (the service's fast
    path) hands ``IKSolver.track`` instead of building a ``Target`` per target.

    A solve copies the rows straight into its arrays (``Task.load``); anything else
    reads it as the sequence of targets it stands for: indexing builds a row's
    ``Target`` (``Target.from_row`` of a copy of the row), so the two compare alike.
    For a stream of one target per frame this costs a fifth of ``Target.from_row``.

    Attributes:
        effectors: Effector names, one per row.
        rows: Shape (len(effectors), TARGET_ROW) float64, read-only: position,
            rotation, direction (``TARGET_PLACEHOLDER_ROW``'s values where a part is not
            given), as ``Target.packed``.
        given: The GIVEN_* bits of each row.

    Raises:
        InvalidProblem: rows of the wrong shape or dtype, a view, as many bit sets
            as names. The numbers are checked as in any solve (in compiled code).
    """

    __slots__ = ("effectors", "given", "rows")

    def __init__(
        self, effectors: tuple[str, ...], rows: np.ndarray, given: tuple[int, ...]
    ) -> None:
        """``rows`` must own its data (not a view of another array, which could still
        change it): it is kept, not copied, and made read-only."""
        if (
            type(rows) is not np.ndarray
            or rows.shape != (len(effectors), TARGET_ROW)
            or rows.dtype != _FLOAT64
            or rows.base is not None
            or len(given) != len(effectors)
        ):
            raise InvalidProblem(
                f"target rows are {TARGET_ROW} float64 values per effector in an array "
                "of their own, with the GIVEN_* bits of each"
            )
        rows.setflags(write=False)
        self.effectors = effectors
        self.rows = rows
        self.given = given

    def __len__(self) -> int:
        return len(self.effectors)

    @overload
    def __getitem__(self, index: int) -> Target: ...

    @overload
    def __getitem__(self, index: slice) -> list[Target]: ...

    def __getitem__(self, index: int | slice) -> Target | list[Target]:
        if isinstance(index, slice):
            return [self[i] for i in range(len(self.effectors))[index]]
        return Target.from_row(self.effectors[index], self.rows[index].copy(), self.given[index])

    def __repr__(self) -> str:
        return f"TargetRows({list(self)!r})"


_SEQUENCES = (tuple, list)
_NO_POSITION = [0.0, 0.0, 0.0]
_NO_ROTATION = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
_NO_DIRECTION = [0.0, 0.0, 1.0]


def _pack_sequences(
    position: object, rotation: object, direction: object
) -> tuple[np.ndarray, int] | None:
    """The packed row in one ``np.array`` call when every given part is a tuple or list
    of the right lengths (the service builds targets this way for every frame, where
    three ``np.asarray`` calls and slice copies cost ~6 us warm, ~30 us under load);
    None for anything else (arrays), which takes the general path."""
    given = 0
    if position is None:
        values = _NO_POSITION.copy()
    elif type(position) in _SEQUENCES and len(position) == 3:  # type: ignore[arg-type]
        values = list(position)  # type: ignore[call-overload]
        given = GIVEN_POSITION
    else:
        return None
    if rotation is None:
        values += _NO_ROTATION
    elif type(rotation) in _SEQUENCES and len(rotation) == 3:  # type: ignore[arg-type]
        for row in rotation:  # type: ignore[attr-defined]
            if type(row) not in _SEQUENCES or len(row) != 3:
                return None
            values += row
        given |= GIVEN_ROTATION
    else:
        return None
    if direction is None:
        values += _NO_DIRECTION
    elif type(direction) in _SEQUENCES and len(direction) == 3:  # type: ignore[arg-type]
        values += direction  # type: ignore[arg-type]
        given |= GIVEN_DIRECTION
    else:
        return None
    row = np.array(values, dtype=np.float64)
    if row.shape != (TARGET_ROW,):  # e.g. nested sequences where numbers belong
        return None
    return row, given


def _exact_shape(value: object, shape: tuple[int, ...]) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(shape)
    return a


def pose_targets(chain: Chain, q: Vector) -> list[Target]:
    """Targets that the pose q reaches exactly (for tests and benchmarks)."""
    out = []
    for eff, pose in zip(chain.effectors, effector_poses(chain, q), strict=True):
        rot = pose[:3, :3]
        out.append(
            Target(
                effector=eff.name,
                position=pose[:3, 3].copy(),
                rotation=rot.copy() if eff.mode is EffectorMode.POSE else None,
                direction=(rot @ eff.aim_axis) if eff.mode is EffectorMode.AIM else None,
            )
        )
    return out
