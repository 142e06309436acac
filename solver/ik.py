"""Inverse kinematics: targets for a chain's effectors -> joint values.

``IKSolver`` is built once per chain (it keeps preallocated arrays for the compiled
core) and solves one frame per call: ``solve`` from a given seed, ``track`` from the
previous answer (a stream). Success is judged from the pose errors against the
tolerances, never from the optimizer's code alone: the core's goal measure is
max(error / tolerance) over effectors, so "goal met" means "IK succeeded".
"""

from __future__ import annotations

import enum
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numba
import numpy as np

from . import _codes as C
from ._core import WORK_ROWS, run_solver_leaf
from ._dispatch import register_objective
from ._jit import jit, jit_leaf
from .analyzer import AnalyzerPolicy
from .bfgs import pack_options, unpack_pass_log
from .chain import Chain, EffectorMode
from .errors import DimensionMismatch, InvalidProblem
from .kinematics import (
    DD_HI,
    DD_LO,
    DD_QREF,
    DD_REST,
    ED_ERR_P,
    ED_ERR_R,
    ED_TDIR,
    ED_TOL_P,
    ED_TOL_R,
    ED_TPOS,
    ED_TROT,
    ED_WP,
    ED_WR,
    EI_ACTIVE,
    EI_MODE,
    MISC_DAMPING,
    MISC_DAMPING_SCALE,
    MISC_GOAL,
    MISC_LIMIT,
    MISC_MARGIN,
    MISC_POSTURE,
    MISC_SIZE,
    MODE_AIM,
    MODE_POSE,
    MODE_POSITION,
    dd_rows,
    effector_errors,
    ik_goal,
    ik_metric,
    ik_objective,
    is_last_point,
    null_space_step,
)
from .termination import Termination
from .types import Matrix, MinimizeOptions, PassRecord, Vector

if TYPE_CHECKING:
    from .path import PathOptions, PlannedPath

TERMINATIONS = C.TERMINATIONS  # _solve_frame's termination codes, in order
SEED_NOT_FINITE = -2  # _solve_frame's "bad" code for a seed with NaN or inf


@jit_leaf
def _check_targets(data):  # type: ignore[no-untyped-def]
    """-1 if the loaded targets are valid, else 3 * effector + problem (0 non-finite,
    1 rotation not orthonormal with det +1, 2 zero direction); normalises directions.

    Checked here, in compiled code, because the same checks in numpy cost ~25 us per
    target (np.allclose, det), more than a 7-DOF solve.
    """
    ei = data[2]
    ed = data[3]
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        for k in range(ED_TPOS, ED_TDIR + 3):
            if not math.isfinite(ed[e, k]):
                return 3 * e
        if ei[e, EI_MODE] == MODE_POSE:
            t = ED_TROT
            worst = 0.0
            for a in range(3):
                for b in range(3):
                    dot = 0.0
                    for c in range(3):
                        dot += ed[e, t + 3 * a + c] * ed[e, t + 3 * b + c]
                    worst = max(worst, abs(dot - (1.0 if a == b else 0.0)))
            r = ed[e, t : t + 9]
            det = (
                r[0] * (r[4] * r[8] - r[5] * r[7])
                - r[1] * (r[3] * r[8] - r[5] * r[6])
                + r[2] * (r[3] * r[7] - r[4] * r[6])
            )
            if worst > 1e-6 or det < 0.0:
                return 3 * e + 1
        elif ei[e, EI_MODE] == MODE_AIM:
            d = ED_TDIR
            norm = math.sqrt(ed[e, d] ** 2 + ed[e, d + 1] ** 2 + ed[e, d + 2] ** 2)
            if norm < 1e-12:
                return 3 * e + 2
            for c in range(3):
                ed[e, d + c] /= norm
    return -1


def scratch_size(n: int, m: int) -> int:
    """Length of ``_solve_frame``'s float scratch for n variables and m effectors."""
    return WORK_ROWS * n + 3 * n + 3 * m + n * n


@jit_leaf
def _solve_frame(  # type: ignore[no-untyped-def]
    data, x0, h0, fopt, iopt, policy, out_x, out, null_space_step_rad, scratch, ints
):
    """One compiled call per frame: validate targets and seed, solve, report errors,
    and (``null_space_step_rad`` > 0, solved frames only) take the null-space step
    towards the rest pose (DD_REST).

    One call and flat outputs because at ~20-40 us per solve, every Python-level
    step around it showed up in bench/ik.py: a numba dispatch type-checks each
    array argument, and each returned array or nested tuple is boxed.

    Writes the pose into ``out_x`` and, into ``out``: per-effector errors (m x 3:
    position error, nan if not targeted; rotation error, nan if not constrained;
    1.0 if targeted), the final inverse Hessian (n x n), then the pass log.
    ``h0`` (the initial H) is read, never written.

    ``scratch`` (float64[scratch_size(n, m)]) and ``ints`` (int64[3]) are work space,
    the caller's: compiled without reference counting (``jit_leaf``), this function
    and everything it calls allocate nothing.

    Returns (bad_target, status, termination code, iterations, evaluations,
    passes, restarts, solve seconds); status indexes ``STATUSES``.
    """
    bad = _check_targets(data)
    ei = data[2]
    dd = data[4]
    n = x0.shape[0]
    m = ei.shape[0]
    for i in range(n):
        if not math.isfinite(x0[i]):
            bad = SEED_NOT_FINITE
    if bad != -1:
        return bad, 0, 0, 0, 0, 0, 0, 0.0
    for i in range(n):
        dd[DD_QREF, i] = x0[i]  # the posture pull is towards the seed
    errors = out[: 3 * m].reshape((m, 3))
    h = out[3 * m : 3 * m + n * n].reshape((n, n))
    log = out[3 * m + n * n :].reshape((-1, C.N_LOG))
    for i in range(n):
        for j in range(n):
            h[i, j] = h0[i, j]
    # The scratch, cut into its parts (views: nothing is allocated).
    work = scratch[: WORK_ROWS * n].reshape((WORK_ROWS, n))
    k = WORK_ROWS * n
    out_g = scratch[k : k + n]
    moved = scratch[k + n : k + 2 * n]
    ns_g = scratch[k + 2 * n : k + 3 * n]
    k += 3 * n
    moved_errors = scratch[k : k + 3 * m].reshape((m, 3))
    ns_h = scratch[k + 3 * m : k + 3 * m + n * n].reshape((n, n))
    trace = scratch[:0].reshape((0, 5))  # records nothing
    # fg=None: the core binds the objective registered for this data type (cacheable).
    # The build without reference counting: the IK objective and metric allocate
    # nothing (their scratch is DD's rows), see _jit.jit_leaf.
    res = run_solver_leaf(
        None, None, data, x0, dd[DD_LO], dd[DD_HI], h, fopt, iopt, policy, log, trace, out_x, out_g,
        work, ints,
    )  # fmt: skip
    code = res[3]
    # The solve's answer is usually the point it evaluated last (ED holds its errors,
    # MISC its goal measure): reuse that instead of one more FK.
    if is_last_point(out_x, dd):
        measure = data[5][MISC_GOAL]
        _copy_errors(data, errors)
    else:
        measure = _report(data, out_x, errors)
    if measure <= 1.0 and null_space_step_rad > 0.0:
        if null_space_step(out_x, data, dd[DD_REST], null_space_step_rad, moved, ns_h, ns_g):
            if _report(data, moved, moved_errors) <= 1.0:
                # Loops, not slice assignment: that needs numba's runtime (a copy in case
                # the two overlap), which this build does not have.
                for i in range(n):
                    out_x[i] = moved[i]
                for e in range(m):
                    for c in range(3):
                        errors[e, c] = moved_errors[e, c]
    if measure <= 1.0:
        status = 0
    elif code == C.NONFINITE or not math.isfinite(measure):
        status = 3
    elif code == C.MAX_ITER or code == C.MAX_FEV or code == C.DEADLINE:
        status = 2
    else:
        status = 1
    return bad, status, code, res[4], res[5], res[7], res[8], res[10]


@jit_leaf
def _report(data, q, errors):  # type: ignore[no-untyped-def]
    """Errors at q into ``errors`` (see ``_solve_frame``); returns the goal measure."""
    measure = effector_errors(q, data)
    _copy_errors(data, errors)
    return measure


@jit_leaf
def _copy_errors(data, errors):  # type: ignore[no-untyped-def]
    """The errors in ED (those of the last q evaluated) into ``errors`` (m x 3)."""
    ei = data[2]
    ed = data[3]
    for e in range(ei.shape[0]):
        active = ei[e, EI_ACTIVE] != 0
        errors[e, 0] = ed[e, ED_ERR_P] if active and ed[e, ED_WP] > 0.0 else math.nan
        errors[e, 1] = ed[e, ED_ERR_R] if active and ei[e, EI_MODE] != MODE_POSITION else math.nan
        errors[e, 2] = 1.0 if active else 0.0


@jit
def _report_only(data, q, out):  # type: ignore[no-untyped-def]
    """Validate targets and report errors at q into the head of ``out`` (the errors
    block of ``_solve_frame``'s layout) without solving."""
    m = data[2].shape[0]
    errors = out[: 3 * m].reshape((m, 3))
    bad = _check_targets(data)
    for i in range(q.shape[0]):
        if not math.isfinite(q[i]):
            bad = SEED_NOT_FINITE
    if bad != -1:
        return bad, 0.0
    return bad, _report(data, q, errors)


class IKStatus(enum.StrEnum):
    """The IK outcome a client acts on."""

    SOLVED = "solved"  # every effector within its tolerances
    # Converged outside tolerance (unreachable, or a local minimum): closest pose returned.
    NOT_REACHED = "not_reached"
    BUDGET_EXHAUSTED = "budget_exhausted"  # time or iterations ran out first; best pose returned
    NONFINITE = "nonfinite"  # the model produced NaN/inf (bad numbers); best finite pose returned


# _solve_frame's status codes, in order.
STATUSES: tuple[IKStatus, ...] = (
    IKStatus.SOLVED,
    IKStatus.NOT_REACHED,
    IKStatus.BUDGET_EXHAUSTED,
    IKStatus.NONFINITE,
)

# Bits of Target.given, and what each effector mode needs.
GIVEN_POSITION = 1
GIVEN_ROTATION = 2
GIVEN_DIRECTION = 4
_NEEDS = {
    EffectorMode.POSITION: GIVEN_POSITION,
    EffectorMode.POSE: GIVEN_ROTATION,
    EffectorMode.AIM: GIVEN_DIRECTION,
}
# Task rows a mode adds to a targeted position's three (an aim fixes a direction: two).
_MODE_ROWS = {EffectorMode.POSITION: 0, EffectorMode.POSE: 3, EffectorMode.AIM: 2}
# A packed target row: position (3), rotation (9, row-major), direction (3). Parts a
# target leaves out keep these finite placeholders (the compiled check rejects
# non-finite numbers anywhere in the row; a missing part's weight is zero).
TARGET_ROW = 15
_FLOAT64 = np.dtype(np.float64)
# A target row's values where a part is not given (position, rotation, direction).
TARGET_PLACEHOLDER_ROW = np.array([0.0, 0.0, 0.0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0.0, 0.0, 1.0])
TARGET_PLACEHOLDER_ROW.setflags(write=False)


@dataclass(frozen=True, slots=True, kw_only=True)
class Target:
    """What one effector should reach in this frame (world frame of the chain's root).

    Attributes:
        effector: Effector name.
        position: Target tip position [m], shape (3,). Required for POSITION; for
            POSE and AIM optional (None drops the position term this frame).
        rotation: Target tip orientation, 3x3 rotation matrix (POSE).
        direction: Unit direction the aim axis should point along (AIM).
        packed: The numbers as one read-only float64 row (position, rotation,
            direction), built once here so that a solve copies one row per target;
            a target reused across solves (a benchmark, a replayed clip) is packed
            once. The given parts then read as views of this row: a Target is a
            snapshot, later edits to the arrays it was built from do not reach it.
        given: Which parts were given (GIVEN_* bits).

    Raises:
        InvalidProblem: a part of the wrong shape (finiteness and orthonormality
            are checked in the compiled solve).
    """

    effector: str
    position: Vector | None = None
    rotation: Matrix | None = None
    direction: Vector | None = None
    packed: np.ndarray = field(init=False, repr=False, compare=False)
    given: int = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
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
    def from_row(cls, effector: str, row: np.ndarray, given: int) -> Target:
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
            InvalidProblem: a row of the wrong shape or dtype, a view, or unknown bits.
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
        target._freeze(row, given)
        return target

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


@dataclass(frozen=True, slots=True, kw_only=True)
class IKOptions:
    """Per-solve settings.

    Attributes:
        position_tolerance_m: Success needs every position error at or below this.
        rotation_tolerance_rad: ... and every orientation / aim error at or below this.
        time_budget_us: Wall-clock budget of one solve (None: no limit).
        max_iter: Iterations over all passes and restarts.
        max_restarts: Random restarts the analyzer may order.
        restart_radius_rad: Restarts sample within this distance of the seed (per
            variable); inf samples the whole range (TRAC-IK style, may jump).
        max_step_rad: Cap on any variable's change per iteration (a step cap keeps a
            cold solve from slamming several joints into their limits).
        posture_weight: Pull towards the reference pose (rest or previous): w sum dq^2.
        limit_weight: Penalty within ``limit_margin`` x range of a limit.
        limit_margin: Width of that band as a fraction of the range.
        stall_window: Multi-pass trigger (iterations); 0 for a single pass.
        ftol: Relative improvement below which an iteration counts as stalled.
        gtol: Projected-gradient tolerance (a stationary point ends the pass).
        scale_initial_h: Nocedal-Wright initial scaling of H at each pass.
        curvature: The article's curvature condition in the line search.
        carry_hessian: ``track`` starts each frame from the last frame's H (the
            metric is then also computed at each answer, for the next frame).
        null_space_step_rad: After a solved ``track`` frame, move at most this far
            (per variable) towards the rest pose through the chain's self-motion,
            keeping the effectors within tolerance (0: off). Stops a redundant arm's
            slow drift into its limits over a long stream.
        global_fallback: When a ``track`` frame fails with local restarts, retry it with
            restarts over the whole range inside the remaining budget: a stream stuck
            on a branch that cannot follow the target jumps once instead of missing
            every later frame.
        damping: Floor of the Gauss-Newton damping mu (mu = damping_scale x f): damped least
            squares near singularities takes small joint steps where pure Gauss-Newton
            swings joints by radians for a millimetre (streams use 1e-3).
        damping_redundant_only: Apply the ``damping`` floor only while the task is
            redundant: more free joints (unlocked, lower < upper) than target rows (3
            per position, 3 per orientation, 2 per aim direction; a part whose weight
            is 0 adds none). Without a self-motion the floor has nothing to steady,
            and near a singularity it only makes a tracked answer lag the target and
            catch up later in one larger step (UR5 pose streams at 1e-5 m / 1e-4 rad:
            33 of 40 within twice the reference's largest step with the floor, 39
            without; at 1e-4 m / 1e-3 rad: 22 and 23).
        damping_scale: mu = damping_scale x f (Levenberg-Marquardt's damping relative
            to the current error, Sugihara 2011). 0.5 took 9-12 median iterations
            against 10-15 with 1.0 (Chan's choice, as in ``ik_LM``) on 10,000 random
            poses of each arm, at the same solve rate (bench/ik.py); 0.1 needed more
            restarts. Streams keep 1.0 (their step and jump figures were measured
            with it).
        metric_every: Re-seed H from the exact Gauss-Newton metric (2 J^T W J + mu I)^-1
            every this many iterations (1: damped Gauss-Newton steps under the same
            line search, multi-pass and analyzer; 0: the article's BFGS, with the
            metric only at the start of each pass). 1 is the default because it
            took ~10 iterations against ~37 on 7-DOF pose problems (bench/ik.py).
        metric_until: Re-seed only during a pass's first this many iterations, then
            BFGS updates (0: always). Near a singularity damped Gauss-Newton crawls
            (hundreds of iterations per frame, bench/ik.py part (c), iiwa); BFGS
            learns the missing curvature in a few steps. Streams use 8.
        policy: The analyzer's table.
    """

    position_tolerance_m: float = 1e-4
    rotation_tolerance_rad: float = 1e-3
    time_budget_us: float | None = 5000.0
    max_iter: int = 5000
    max_restarts: int = 50
    restart_radius_rad: float = math.inf
    max_step_rad: float = 0.5
    posture_weight: float = 0.0
    limit_weight: float = 0.0
    limit_margin: float = 0.05
    stall_window: int = 5
    ftol: float = 1e-3
    gtol: float = 1e-14
    scale_initial_h: bool = True
    curvature: bool = False
    carry_hessian: bool = False
    metric_every: int = 1
    metric_until: int = 0
    null_space_step_rad: float = 0.0
    damping: float = 0.0
    damping_redundant_only: bool = False
    damping_scale: float = 0.5
    global_fallback: bool = False
    policy: AnalyzerPolicy = field(default_factory=AnalyzerPolicy.default)

    def __post_init__(self) -> None:
        for name in (
            "position_tolerance_m",
            "rotation_tolerance_rad",
            "max_step_rad",
            "restart_radius_rad",
        ):
            v = getattr(self, name)
            if not v > 0.0 or math.isnan(v):
                raise InvalidProblem(f"{name} must be > 0, got {v!r}")
        for name in (
            "posture_weight",
            "limit_weight",
            "ftol",
            "gtol",
            "damping",
            "damping_scale",
            "null_space_step_rad",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise InvalidProblem(f"{name} must be finite and >= 0, got {v!r}")
        if not 0.0 <= self.limit_margin < 0.5:
            raise InvalidProblem(f"limit_margin must be in [0, 0.5), got {self.limit_margin!r}")
        if self.time_budget_us is not None and not self.time_budget_us >= 0.0:
            raise InvalidProblem(f"time_budget_us must be >= 0, got {self.time_budget_us!r}")
        if self.metric_every < 0 or self.metric_until < 0:
            raise InvalidProblem("metric_every and metric_until must be >= 0")
        if self.max_iter < 1 or self.max_restarts < 0 or self.stall_window < 0:
            raise InvalidProblem("max_iter must be >= 1, max_restarts and stall_window >= 0")

    def minimize_options(self) -> MinimizeOptions:
        budget = None if self.time_budget_us is None else self.time_budget_us * 1e-6
        return MinimizeOptions(
            gtol=self.gtol,
            ftol=self.ftol,
            stall_window=self.stall_window,
            f_goal=1.0,  # the goal measure is max(error / tolerance)
            max_step=self.max_step_rad,
            curvature=self.curvature,
            max_iter=self.max_iter,
            max_fev=20 * self.max_iter + 100,
            max_restarts=self.max_restarts,
            restart_radius=self.restart_radius_rad,
            time_budget_s=budget,
            scale_initial_h=self.scale_initial_h,
            max_passes=min(4 * (self.max_restarts + 1) + 8, 512),
            metric_every=self.metric_every,
            metric_until=self.metric_until,
            final_metric=self.carry_hessian,
        )


# Stream defaults (the user can override every field): local restarts and a light pull
# away from the limits, so a frame that misses usually recovers without a visible jump;
# damped least squares near singularities and a null-space pull towards the rest pose
# against drift; and, when all that fails, one global re-solve (a visible jump) rather
# than a stream that misses every later frame (bench/ik.py, iiwa stream 1: 306/599
# frames without it, 598/599 with it and one 4.3 rad jump). metric_until=8: near a
# singularity the damped Gauss-Newton steps crawled (p99 154 iterations per frame on
# the iiwa streams, 3-5 frames out of time); BFGS after 8 steps: p99 15, none missed.
# The damping floor only for redundant tasks: a 6-DOF arm's pose stream has no
# self-motion for it to steady, and with it the answer lagged behind the target at
# singularities (UR5 at 1e-5 m / 1e-4 rad: 33 of 40 streams within twice the
# reference's largest step; 39 without; bench/ik.py --parts c --streams 40).
STREAM_DEFAULTS = IKOptions(
    restart_radius_rad=0.3,
    limit_weight=1e-3,
    limit_margin=0.02,
    null_space_step_rad=0.005,
    damping=1e-3,
    damping_redundant_only=True,
    global_fallback=True,
    metric_until=8,
    damping_scale=1.0,
)


@dataclass(frozen=True, slots=True)
class EffectorError:
    """Pose error of one effector after a solve.

    Attributes:
        name: Effector name.
        position_error_m: Distance from the target position (None if not targeted).
        rotation_error_rad: Orientation / aim error (None for position-only).
        within_tolerance: Both errors within the tolerances.
    """

    name: str
    position_error_m: float | None
    rotation_error_rad: float | None
    within_tolerance: bool


@dataclass(frozen=True, slots=True)
class ResultLayout:
    """What every result of one solver under one set of options shares: names,
    tolerances, and where the parts of the core's output block lie."""

    dof_names: tuple[str, ...]
    effector_names: tuple[str, ...]
    tolerances: tuple[float, float]  # position [m], rotation [rad]
    n_dof: int
    n_effectors: int

    @property
    def hessian_start(self) -> int:
        return 3 * self.n_effectors

    @property
    def log_start(self) -> int:
        return 3 * self.n_effectors + self.n_dof * self.n_dof


class IKResult(NamedTuple):
    """Answer to one frame (immutable).

    A NamedTuple of the few values every caller reads; the rest (errors per effector,
    the final H, the pass log) stay in the core's output block ``raw`` and are built on
    access. Building a frozen dataclass per frame cost ~8 us, and a 15-field tuple
    with converted arrays another ~5 us, of a ~40 us solve (bench/ik.py).

    Attributes:
        q: Joint values, shape (n_dof,), in ``dof_names`` order, inside the limits.
        status: SOLVED / NOT_REACHED / BUDGET_EXHAUSTED / NONFINITE.
        termination: How the optimizer's last pass ended.
        iterations, function_evals, passes, restarts: Work done.
        solve_us: Time inside the compiled solve [us].
        raw: The core's output block (layout in ``ResultLayout`` / ``_solve_frame``).
        layout: Names and tolerances shared by this solver's results.

    Properties: success (status is SOLVED), dof_names, effector_names, tolerances,
    effectors (errors of the targeted effectors), raw_errors, inverse_hessian (final
    BFGS matrix, carried between frames if asked), pass_log (the analyzer's
    decisions, pass by pass), joint_values.
    """

    q: Vector
    status: IKStatus
    termination: Termination
    iterations: int
    function_evals: int
    passes: int
    restarts: int
    solve_us: float
    raw: np.ndarray
    layout: ResultLayout

    @property
    def success(self) -> bool:
        return self.status is IKStatus.SOLVED

    @property
    def dof_names(self) -> tuple[str, ...]:
        return self.layout.dof_names

    @property
    def effector_names(self) -> tuple[str, ...]:
        return self.layout.effector_names

    @property
    def tolerances(self) -> tuple[float, float]:
        return self.layout.tolerances

    @property
    def raw_errors(self) -> np.ndarray:
        """Rows of (position error, rotation error, targeted flag), one per effector."""
        m = self.layout.n_effectors
        return self.raw[: 3 * m].reshape(m, 3)

    @property
    def inverse_hessian(self) -> Matrix:
        n = self.layout.n_dof
        start = self.layout.hessian_start
        return self.raw[start : start + n * n].reshape(n, n)

    @property
    def raw_pass_log(self) -> np.ndarray:
        return self.raw[self.layout.log_start :].reshape(-1, C.N_LOG)

    @property
    def pass_log(self) -> tuple[PassRecord, ...]:
        return unpack_pass_log(self.raw_pass_log, self.passes)

    @property
    def effectors(self) -> tuple[EffectorError, ...]:
        tol_p, tol_r = self.layout.tolerances
        out = []
        for name, (pos, rot, targeted) in zip(
            self.layout.effector_names, self.raw_errors.tolist(), strict=True
        ):
            if not targeted:
                continue
            p = None if math.isnan(pos) else pos
            r = None if math.isnan(rot) else rot
            ok = (p is None or p <= tol_p) and (r is None or r <= tol_r)
            out.append(EffectorError(name, p, r, ok))
        return tuple(out)

    @property
    def joint_values(self) -> dict[str, float]:
        return dict(zip(self.layout.dof_names, self.q.tolist(), strict=True))

    @property
    def max_position_error_m(self) -> float:
        return max((e.position_error_m or 0.0 for e in self.effectors), default=0.0)

    @property
    def max_rotation_error_rad(self) -> float:
        return max((e.rotation_error_rad or 0.0 for e in self.effectors), default=0.0)


_tuple_new = tuple.__new__


class _Packed(NamedTuple):
    """One IKOptions object as the core takes it, built once per solver and options."""

    options: IKOptions
    fopt: np.ndarray
    iopt: np.ndarray  # iopt[I_SEED] carries this solver's restart generator along
    policy: np.ndarray
    out_size: int  # length of a frame's output block
    layout: ResultLayout


_F64 = np.dtype(np.float64)


class IKSolver:
    """Solves frames for one chain; holds the compiled core's preallocated arrays.

    Not thread-safe: one solver per session, frames one at a time (the service
    serialises a session's frames with a lock).
    """

    def __init__(
        self, chain: Chain, options: IKOptions | None = None, *, seed: int | None = None
    ) -> None:
        """Args:
        chain: The model.
        options: Default options of every call.
        seed: Seed of the solver's own restart generator (None: 0, reproducible);
            give sessions their own if their random restarts should differ.
        """
        self.chain = chain
        self.options = options or IKOptions()
        cc = chain.compiled
        n = chain.n_dof
        self._n = n
        self._ei = cc.ei.copy()
        self._ed = cc.ed.copy()
        self._dd = np.zeros((dd_rows(n), n))
        self._dd[DD_LO] = chain.lower
        self._dd[DD_HI] = chain.upper
        self._misc = np.zeros(MISC_SIZE)
        self._data = (cc.ni, cc.nd.copy(), self._ei, self._ed, self._dd, self._misc)
        _register_once(self._data)
        self._chain_dofs = cc.eff_dofs
        # One row per effector: what a Target's ``packed`` row is copied into.
        self._target_rows = self._ed[:, ED_TPOS : ED_TDIR + 3]
        assert self._target_rows.shape[1] == TARGET_ROW
        self._target_rows[:] = TARGET_PLACEHOLDER_ROW
        assert np.shares_memory(self._target_rows, self._ed)
        self._effector_names = chain.effector_names
        self._effector_slot = {name: i for i, name in enumerate(self._effector_names)}
        self._needs = tuple(_NEEDS[e.mode] for e in chain.effectors)
        # Target rows each effector adds, for the redundancy test: a part whose weight is
        # zero in the model constrains nothing.
        static = chain.compiled.ed
        self._position_rows = tuple(
            3 if static[i, ED_WP] > 0.0 else 0 for i in range(len(self._needs))
        )
        self._mode_rows = tuple(
            _MODE_ROWS[e.mode] if static[i, ED_WR] > 0.0 else 0
            for i, e in enumerate(chain.effectors)
        )
        self._movable = chain.lower < chain.upper  # a joint with lower == upper is locked
        self._redundant = True  # more free joints than target rows (set per target set)
        self._static_weights = chain.compiled.ed[:, ED_WP].copy()
        self._active: list[int] = []
        self._zeroed: list[int] = []
        self._tol_for: IKOptions | None = None
        self._misc_for: IKOptions | None = None
        self._bounds_are_limits = True
        self._every_effector_moves_all = all(d.shape[0] == n for d in cc.eff_dofs)
        self._mid = chain.mid_limits()
        self._identity = np.eye(n)
        self._shape = (n,)
        self._packed: dict[int, _Packed] = {}
        self._last_packed: _Packed | None = None
        self._rng = np.random.default_rng(0 if seed is None else seed)
        self.q = self._mid.copy()  # the stream's current pose
        self._dd[DD_REST] = self._mid
        self._h: Matrix | None = None
        self._solve_call: Callable[..., tuple[Any, ...]] = _solve_frame
        # _solve_frame's work space (it allocates nothing: see _jit.jit_leaf).
        self._scratch = np.empty(scratch_size(n, self._ei.shape[0]))
        self._ints = np.empty(3, dtype=np.int64)

    # -- public API ------------------------------------------------------------
    def solve(
        self,
        targets: Sequence[Target],
        seed: Vector | None = None,
        *,
        options: IKOptions | None = None,
        rng: np.random.Generator | None = None,
        initial_inverse_hessian: Matrix | None = None,
    ) -> IKResult:
        """Solve one frame from ``seed`` (default: mid-limits).

        Args:
            targets: At most one per effector; effectors without one are not pulled.
            seed: Start, shape (n_dof,); projected into the limits.
            options: Overrides the solver's options for this call.
            rng: Source of the restart seed; default the solver's own generator,
                which carries on from call to call.
            initial_inverse_hessian: Start H (shape (n_dof, n_dof)); default I.

        Raises:
            InvalidProblem: unknown effector, missing or malformed target fields.
            DimensionMismatch: seed of the wrong length.
        """
        opts = options or self.options
        q0 = self._mid if seed is None else self._check_seed(seed)
        return self._frame(targets, q0, opts, rng, initial_inverse_hessian, 0.0)

    def track(
        self,
        targets: Sequence[Target],
        *,
        options: IKOptions | None = None,
        rng: np.random.Generator | None = None,
    ) -> IKResult:
        """Solve the next frame of a stream, warm-started from the previous answer.

        The pose (and, with ``carry_hessian``, the BFGS matrix) carries over; the
        posture pull, if any, is towards the previous pose.
        """
        opts = options or self.options
        h0 = self._h if opts.carry_hessian else None
        started = time.perf_counter()
        # float(): an int here would make numba compile another specialisation.
        step = float(opts.null_space_step_rad)
        # ``q`` is public: check it as a seed (length, dtype, layout) every frame.
        q0 = self._check_seed(self.q)
        result = self._frame(targets, q0, opts, rng, h0, step)
        if not result.success and opts.global_fallback and math.isfinite(opts.restart_radius_rad):
            budget = opts.time_budget_us
            left = None if budget is None else budget - (time.perf_counter() - started) * 1e6
            if left is None or left > 0.0:
                wide = replace(opts, restart_radius_rad=math.inf, time_budget_us=left)
                retry = self._frame(targets, q0, wide, rng, None, step)
                if retry.success:
                    result = retry
        self.q = result.q.copy()
        # A copy: the result's block is the caller's to keep (and to write to).
        self._h = result.inverse_hessian.copy() if opts.carry_hessian else None
        return result

    def set_pose(self, q: Vector) -> None:
        """Set the stream's current pose and its rest pose (projected into the limits).

        The rest pose is where ``null_space_step_rad`` steers a redundant chain's
        self-motion; by default it is the middle of the limits.
        """
        self.q = np.clip(self._check_seed(q), self.chain.lower, self.chain.upper)
        self._dd[DD_REST] = self.q
        self._h = None

    def errors_at(self, q: Vector, targets: Sequence[Target]) -> tuple[EffectorError, ...]:
        """Pose errors of q against targets with the solver's tolerances (no solving)."""
        return self._judge(q, targets, self.options, 0.0).effectors

    def plan(
        self,
        frames: Sequence[Sequence[Target]],
        *,
        options: IKOptions | None = None,
        path_options: PathOptions | None = None,
    ) -> PlannedPath:
        """Solve a whole clip of frames at once, from the current pose: the path whose
        largest joint step between consecutive frames is smallest (``solver.path``).

        Where ``track`` answers each frame knowing only the past, this knows the whole
        clip. The current pose becomes the last frame's answer, as after tracking.
        """
        from .path import plan_path  # path.py builds on this module

        return plan_path(self, frames, options=options, path_options=path_options)

    def _judge(
        self, q: Vector, targets: Sequence[Target], opts: IKOptions, solve_us: float
    ) -> IKResult:
        """A result for q as it is (no solving): errors against the targets, SOLVED
        (goal_reached) within the tolerances of ``opts``, else NOT_REACHED (gtol)."""
        self._load_targets(targets, opts)
        packed = self._packed_options(opts)
        raw = np.full(packed.out_size, math.nan)
        q = self._check_seed(q)
        bad, measure = _report_only(self._data, q, raw)
        self._raise_bad_target(bad)
        ok = measure <= 1.0
        return IKResult(
            q,
            IKStatus.SOLVED if ok else IKStatus.NOT_REACHED,
            Termination.GOAL_REACHED if ok else Termination.GTOL,
            0,
            0,
            0,
            0,
            solve_us,
            raw,
            packed.layout,
        )

    # -- internals -------------------------------------------------------------
    def _check_seed(self, seed: Vector) -> Vector:
        # No copy: the core reads the seed and never writes it. ``carray`` (C-contiguous,
        # aligned, writeable) matters: numba compiles a new specialisation, tens of
        # seconds, for any other array layout. Finiteness is checked in compiled code.
        if (
            type(seed) is np.ndarray
            and seed.dtype == _F64
            and seed.shape == self._shape
            and seed.flags.carray
        ):
            return seed
        q = np.array(seed, dtype=np.float64).reshape(-1)
        if q.shape != self._shape:
            raise DimensionMismatch(f"seed must have {self._n} values, got {q.shape[0]}")
        return q

    def _load_targets(self, targets: Sequence[Target], opts: IKOptions) -> None:
        """Copy targets into the compiled arrays (shapes were checked by Target, values
        are checked in compiled code)."""
        if self._tol_for is not opts:
            self._ed[:, ED_TOL_P] = opts.position_tolerance_m
            self._ed[:, ED_TOL_R] = opts.rotation_tolerance_rad
            self._tol_for = opts
        active = self._active
        if len(targets) == 1 and len(active) == 1 and not self._zeroed:
            # A stream's usual frame: one target for the effector of the last frame.
            t = targets[0]
            i = active[0]
            need = self._needs[i]
            if (
                t.effector == self._effector_names[i]
                and t.given & need == need
                and t.given & GIVEN_POSITION
            ):
                self._target_rows[i] = t.packed
                return
        ei = self._ei
        ed = self._ed
        for i in active:
            ei[i, EI_ACTIVE] = 0
        for i in self._zeroed:
            ed[i, ED_WP] = self._static_weights[i]
        self._active = active = []
        self._zeroed = []
        try:
            for t in targets:
                i = self._effector_slot.get(t.effector, -1)
                if i < 0:
                    self.chain.effector_index(t.effector)  # raises with the list of names
                if ei[i, EI_ACTIVE]:
                    raise InvalidProblem(f"two targets for effector {t.effector!r}")
                need = self._needs[i]
                if t.given & need != need:
                    part = {GIVEN_POSITION: "a position", GIVEN_ROTATION: "a rotation"}.get(
                        need, "a direction"
                    )
                    mode = self.chain.effectors[i].mode.value
                    raise InvalidProblem(f"target for {t.effector!r} ({mode}) needs {part}")
                if not t.given & GIVEN_POSITION:
                    ed[i, ED_WP] = 0.0
                    self._zeroed.append(i)
                self._target_rows[i] = t.packed
                ei[i, EI_ACTIVE] = 1
                active.append(i)
        finally:
            # Also when a target is rejected: the effectors loaded before it stay active,
            # and the next frame's fast path keeps this answer.
            self._redundant = self._task_is_redundant()

    def _task_is_redundant(self) -> bool:
        """More free (unlocked) joints than target rows among the active effectors."""
        return self._free_directions() > 0

    def _free_mask(self) -> np.ndarray:
        """1.0 for each variable the loaded targets may move: unlocked, and in the
        chain of a targeted effector; else 0.0."""
        if self._every_effector_moves_all or not self._active:
            reach = self._movable
        else:
            reach = np.zeros(self._n, dtype=bool)
            for i in self._active:
                reach[self._chain_dofs[i]] = True
            reach &= self._movable
        return reach.astype(np.float64)

    def _free_directions(self) -> int:
        """Free (unlocked) joints of the targeted effectors minus their target rows: the
        dimension of the self-motion where the Jacobian has full rank (a 7-DOF arm
        under a 6-D pose: 1; <= 0: no self-motion)."""
        active = self._active
        rows = sum(
            self._mode_rows[i] + (0 if i in self._zeroed else self._position_rows[i])
            for i in active
        )
        if self._every_effector_moves_all or not active:
            free = int(self._movable.sum())
        else:
            dofs = np.unique(np.concatenate([self._chain_dofs[i] for i in active]))
            free = int(self._movable[dofs].sum())
        return free - rows

    def _set_free_bounds(self, q0: Vector) -> None:
        """Limits for this frame (DD rows): variables outside every targeted chain are
        frozen at q0."""
        lo = self.chain.lower
        hi = self.chain.upper
        if self._every_effector_moves_all and self._active:
            if not self._bounds_are_limits:
                self._dd[DD_LO] = lo
                self._dd[DD_HI] = hi
                self._bounds_are_limits = True
            return
        free = np.zeros(self._n, dtype=bool)
        for i in self._active:
            free[self._chain_dofs[i]] = True
        q = np.clip(q0, lo, hi)
        self._dd[DD_LO] = np.where(free, lo, q)
        self._dd[DD_HI] = np.where(free, hi, q)
        self._bounds_are_limits = False

    def _packed_options(self, opts: IKOptions) -> _Packed:
        """Option vectors, policy table and result layout, built once per IKOptions."""
        last = self._last_packed
        if last is not None and last.options is opts:
            return last
        hit = self._packed.get(id(opts))
        if hit is None or hit.options is not opts:
            mopts = opts.minimize_options()
            seed = int(self._rng.integers(0, 2**31 - 1))
            fopt, iopt = pack_options(mopts, seed=seed)
            if len(self._packed) > 32:
                self._packed.clear()
            n = self._n
            m = len(self._effector_names)
            layout = ResultLayout(
                self.chain.dof_names,
                self._effector_names,
                (opts.position_tolerance_m, opts.rotation_tolerance_rad),
                n,
                m,
            )
            out_size = 3 * m + n * n + mopts.max_passes * C.N_LOG
            hit = _Packed(opts, fopt, iopt, opts.policy.as_array(), out_size, layout)
            self._packed[id(opts)] = hit
        self._last_packed = hit
        return hit

    def _prepare(self, targets: Sequence[Target], opts: IKOptions, q0: Vector) -> None:
        """Load a frame's targets and its bounds (variables outside every targeted
        chain frozen at q0), as a solve from q0 does; aim directions normalised as a
        solve normalises them (the caller has checked the targets)."""
        self._load_targets(targets, opts)
        _check_targets(self._data)
        if not (self._bounds_are_limits and self._every_effector_moves_all and self._active):
            self._set_free_bounds(q0)

    def _frame(
        self,
        targets: Sequence[Target],
        q0: Vector,
        opts: IKOptions,
        rng: np.random.Generator | None,
        h0: Matrix | None,
        null_space_step_rad: float,
    ) -> IKResult:
        self._load_targets(targets, opts)
        if self._misc_for is not opts:
            self._misc[MISC_POSTURE] = opts.posture_weight
            self._misc[MISC_LIMIT] = opts.limit_weight
            self._misc[MISC_MARGIN] = opts.limit_margin
            self._misc[MISC_DAMPING_SCALE] = opts.damping_scale
            self._misc_for = opts
        # Per frame: the target set (and with it the redundancy) can change under the
        # same options.
        self._misc[MISC_DAMPING] = (
            opts.damping if self._redundant or not opts.damping_redundant_only else 0.0
        )
        if not (self._bounds_are_limits and self._every_effector_moves_all and self._active):
            self._set_free_bounds(q0)
        packed = self._last_packed
        if packed is None or packed.options is not opts:
            packed = self._packed_options(opts)
        if rng is not None:
            packed.iopt[C.I_SEED] = int(rng.integers(0, 2**31 - 1))
        out = np.empty(packed.out_size)
        if self._n == 0:
            # An all-fixed chain: nothing to solve, only errors to report.
            bad, measure = _report_only(self._data, q0, out)
            self._raise_bad_target(bad)
            ok = measure <= 1.0
            return IKResult(
                q0.copy(),
                IKStatus.SOLVED if ok else IKStatus.NOT_REACHED,
                Termination.GOAL_REACHED if ok else Termination.GTOL,
                0,
                0,
                0,
                0,
                0.0,
                out,
                packed.layout,
            )
        if h0 is None:
            h0 = self._identity
        elif not (type(h0) is np.ndarray and h0.dtype == _F64 and h0.flags.carray):
            h0 = np.array(h0, dtype=np.float64, order="C")  # one layout: one compilation
        if h0.shape != self._identity.shape:
            raise DimensionMismatch(f"initial_inverse_hessian must be {self._n}x{self._n}")
        out_x = np.empty(self._n)
        args = (
            self._data,
            q0,
            h0,
            packed.fopt,
            packed.iopt,
            packed.policy,
            out_x,
            out,
            null_space_step_rad,
            self._scratch,
            self._ints,
        )
        call = self._solve_call
        bad, status, code, nit, nfev, npass, nrest, elapsed = call(*args)
        if call is _solve_frame:
            self._solve_call = _compiled_entry(_solve_frame, args)
        if bad != -1:
            self._raise_bad_target(bad)
        # tuple.__new__ directly: the NamedTuple's generated __new__ is Python code.
        return _tuple_new(
            IKResult,
            (
                out_x,
                STATUSES[status],
                TERMINATIONS[code],
                nit,
                nfev,
                npass,
                nrest,
                elapsed * 1e6,
                out,
                packed.layout,
            ),
        )

    def _raise_bad_target(self, bad: int) -> None:
        if bad == SEED_NOT_FINITE:
            raise InvalidProblem("seed must be finite")
        if bad >= 0:
            name = self.chain.effectors[bad // 3].name
            what = (
                "numbers must be finite",
                "rotation must be orthonormal with det +1",
                "direction must not be zero",
            )[bad % 3]
            raise InvalidProblem(f"target for {name!r}: {what}")


_REGISTERED = False


def _compiled_entry(dispatcher: Any, args: tuple[Any, ...]) -> Callable[..., Any]:
    """The compiled overload of ``dispatcher`` for these arguments' types, called
    directly: skips the dispatcher's per-call type resolution (~0.3 us of a ~20 us
    solve). Only for callers whose argument types never change, as an IKSolver's
    (its arrays are its own; seeds and H pass ``_check_seed`` / the H check, which
    fix dtype, layout and writeability). The dispatcher itself if there is no such
    overload (``NUMBA_DISABLE_JIT``).
    """
    overloads = getattr(dispatcher, "overloads", None)
    if overloads is None:
        return cast(Callable[..., Any], dispatcher)
    compiled = overloads.get(tuple(numba.typeof(a) for a in args))
    return cast(Callable[..., Any], dispatcher if compiled is None else compiled.entry_point)


def _register_once(data: tuple[np.ndarray, ...]) -> None:
    """Bind the IK objective to the IK data tuple's type (every chain shares it)."""
    global _REGISTERED
    if not _REGISTERED:
        register_objective(ik_objective, ik_goal, data, ik_metric)
        _REGISTERED = True


def solve(
    chain: Chain,
    targets: Sequence[Target],
    seed: Vector | None = None,
    *,
    options: IKOptions | None = None,
    rng: np.random.Generator | None = None,
) -> IKResult:
    """One-shot IK (builds a throwaway ``IKSolver``; keep one per chain for streams)."""
    return IKSolver(chain, options).solve(targets, seed, rng=rng)


def pose_targets(chain: Chain, q: Vector) -> list[Target]:
    """Targets that the pose q reaches exactly (for tests and benchmarks)."""
    from .fk import effector_poses

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


def with_options(options: IKOptions, **changes: object) -> IKOptions:
    """A copy of options with fields changed (validated)."""
    return replace(options, **changes)  # type: ignore[arg-type]
