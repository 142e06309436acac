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
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from . import _codes as C
from ._core import run_solver
from ._dispatch import register_objective
from ._jit import jit
from .analyzer import AnalyzerPolicy
from .bfgs import pack_options, unpack_pass_log
from .chain import Chain, EffectorMode
from .errors import DimensionMismatch, InvalidProblem
from .kinematics import (
    DD_HI,
    DD_LO,
    DD_QREF,
    DD_ROWS,
    ED_ERR_P,
    ED_ERR_R,
    ED_TDIR,
    ED_TOL_P,
    ED_TOL_R,
    ED_TPOS,
    ED_TROT,
    ED_WP,
    EI_ACTIVE,
    EI_MODE,
    MISC_DAMPING,
    MISC_LIMIT,
    MISC_MARGIN,
    MISC_POSTURE,
    MISC_SIZE,
    MODE_AIM,
    MODE_POSE,
    MODE_POSITION,
    effector_errors,
    ik_goal,
    ik_metric,
    ik_objective,
    null_space_step,
)
from .termination import Termination
from .types import Matrix, MinimizeOptions, PassRecord, Vector

SEED_NOT_FINITE = -2  # _solve_core's "bad" code for a seed with NaN or inf


@jit
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


@jit
def _solve_core(data, x0, h, fopt, iopt, policy, log, out_x, errors):  # type: ignore[no-untyped-def]
    """One compiled call per frame: validate targets, solve, report errors.

    Returns (bad_target, solver outputs, goal measure); ``errors`` receives, per
    effector, the position error (nan if not targeted), the rotation error (nan if
    not constrained) and 1.0 when it was targeted.
    """
    bad = _check_targets(data)
    dd = data[4]
    n = x0.shape[0]
    out_g = np.empty(n)
    for i in range(n):
        if not math.isfinite(x0[i]):
            bad = SEED_NOT_FINITE
    if bad != -1:
        return bad, (0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 0, 0.0), 0.0
    trace = np.empty((0, 5))
    # fg=None: the core binds the objective registered for this data type (cacheable).
    out = run_solver(
        None, None, data, x0, dd[DD_LO], dd[DD_HI], h, fopt, iopt, policy, log, trace, out_x, out_g
    )
    return bad, out, _report(data, out_x, errors)


@jit
def _report(data, q, errors):  # type: ignore[no-untyped-def]
    """Errors at q into ``errors`` (see ``_solve_core``); returns the goal measure."""
    measure = effector_errors(q, data)
    ei = data[2]
    ed = data[3]
    for e in range(ei.shape[0]):
        active = ei[e, EI_ACTIVE] != 0
        errors[e, 0] = ed[e, ED_ERR_P] if active and ed[e, ED_WP] > 0.0 else math.nan
        errors[e, 1] = ed[e, ED_ERR_R] if active and ei[e, EI_MODE] != MODE_POSITION else math.nan
        errors[e, 2] = 1.0 if active else 0.0
    return measure


@jit
def _null_space_frame(data, q, rest, max_step, out, errors):  # type: ignore[no-untyped-def]
    """Null-space step from q towards rest into out; True if the pose stays in tolerance."""
    if not null_space_step(q, data, rest, max_step, out):
        return False
    return _report(data, out, errors) <= 1.0


@jit
def _report_only(data, q, errors):  # type: ignore[no-untyped-def]
    """Validate targets and report errors at q without solving (chains with no variables)."""
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


@dataclass(frozen=True, slots=True, kw_only=True)
class Target:
    """What one effector should reach in this frame (world frame of the chain's root).

    Attributes:
        effector: Effector name.
        position: Target tip position [m], shape (3,). Required for POSITION; for
            POSE and AIM optional (None drops the position term this frame).
        rotation: Target tip orientation, 3x3 rotation matrix (POSE).
        direction: Unit direction the aim axis should point along (AIM).
    """

    effector: str
    position: Vector | None = None
    rotation: Matrix | None = None
    direction: Vector | None = None


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
        carry_hessian: ``track`` starts each frame from the last frame's H.
        null_space_step_rad: After a solved ``track`` frame, move at most this far
            (per variable) towards the rest pose through the chain's self-motion,
            keeping the effectors within tolerance (0: off). Stops a redundant arm's
            slow drift into its limits over a long stream.
        global_fallback: When a ``track`` frame fails with local restarts, retry it with
            restarts over the whole range inside the remaining budget: a stream stuck
            on a branch that cannot follow the target jumps once instead of missing
            every later frame.
        damping: Floor of the Gauss-Newton damping mu (default mu = f): damped least
            squares near singularities takes small joint steps where pure Gauss-Newton
            swings joints by radians for a millimetre (streams use 1e-3).
        metric_every: Re-seed H from the exact Gauss-Newton metric (2 J^T W J + mu I)^-1
            every this many iterations (1: damped Gauss-Newton steps under the same
            line search, multi-pass and analyzer; 0: the article's BFGS, with the
            metric only at the start of each pass). 1 is the default because it
            took ~10 iterations against ~37 on 7-DOF pose problems (bench/ik.py).
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
    null_space_step_rad: float = 0.0
    damping: float = 0.0
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
            "null_space_step_rad",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise InvalidProblem(f"{name} must be finite and >= 0, got {v!r}")
        if not 0.0 <= self.limit_margin < 0.5:
            raise InvalidProblem(f"limit_margin must be in [0, 0.5), got {self.limit_margin!r}")
        if self.time_budget_us is not None and not self.time_budget_us >= 0.0:
            raise InvalidProblem(f"time_budget_us must be >= 0, got {self.time_budget_us!r}")
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
        )


# Stream defaults (the user can override every field): local restarts and a light pull
# away from the limits, so a frame that misses usually recovers without a visible jump;
# damped least squares near singularities and a null-space pull towards the rest pose
# against drift; and, when all that fails, one global re-solve (a visible jump) rather
# than a stream that misses every later frame (bench/ik.py, iiwa stream 1: 306/599
# frames without it, 598/599 with it and one 4.3 rad jump).
STREAM_DEFAULTS = IKOptions(
    restart_radius_rad=0.3,
    limit_weight=1e-3,
    limit_margin=0.02,
    null_space_step_rad=0.005,
    damping=1e-3,
    global_fallback=True,
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


class IKResult(NamedTuple):
    """Answer to one frame (immutable).

    A NamedTuple rather than a frozen dataclass: it is built once per frame, and a
    frozen dataclass's __init__ (object.__setattr__ per field) cost ~8 us of a
    ~100 us frame.

    Attributes:
        q: Joint values, shape (n_dof,), in ``dof_names`` order, inside the limits.
        dof_names: Variable names.
        status: SOLVED / NOT_REACHED / BUDGET_EXHAUSTED / NONFINITE.
        success: status is SOLVED.
        termination: How the optimizer's last pass ended.
        effectors: Errors for the effectors that had a target (built on access from
            ``raw_errors``: rows of position error, rotation error (nan where not
            constrained) and a targeted flag, one per effector of the chain).
        iterations, function_evals, passes, restarts: Work done.
        solve_us: Time inside the compiled solve [us].
        inverse_hessian: Final BFGS matrix (carried between frames if asked).
        pass_log: The analyzer's decisions, pass by pass (built on first access from
            the raw rows: most frames never look at it, and building it costs ~15 us).
    """

    q: Vector
    dof_names: tuple[str, ...]
    status: IKStatus
    success: bool
    termination: Termination
    raw_errors: np.ndarray
    effector_names: tuple[str, ...]
    tolerances: tuple[float, float]
    iterations: int
    function_evals: int
    passes: int
    restarts: int
    solve_us: float
    inverse_hessian: Matrix
    raw_pass_log: np.ndarray

    @property
    def pass_log(self) -> tuple[PassRecord, ...]:
        return unpack_pass_log(self.raw_pass_log, self.passes)

    @property
    def effectors(self) -> tuple[EffectorError, ...]:
        tol_p, tol_r = self.tolerances
        out = []
        for name, (pos, rot, targeted) in zip(
            self.effector_names, self.raw_errors.tolist(), strict=True
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
        return dict(zip(self.dof_names, (float(v) for v in self.q), strict=True))

    @property
    def max_position_error_m(self) -> float:
        return max((e.position_error_m or 0.0 for e in self.effectors), default=0.0)

    @property
    def max_rotation_error_rad(self) -> float:
        return max((e.rotation_error_rad or 0.0 for e in self.effectors), default=0.0)


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
            give each session its own so their random restarts differ.
        """
        self.chain = chain
        self.options = options or IKOptions()
        cc = chain.compiled
        n = chain.n_dof
        self._ei = cc.ei.copy()
        self._ed = cc.ed.copy()
        self._ed[:, ED_TROT : ED_TROT + 9] = np.eye(3).reshape(-1)
        self._ed[:, ED_TDIR + 2] = 1.0
        self._dd = np.zeros((DD_ROWS, n))
        self._dd[DD_LO] = chain.lower
        self._dd[DD_HI] = chain.upper
        self._misc = np.zeros(MISC_SIZE)
        self._data = (cc.ni, cc.nd.copy(), self._ei, self._ed, self._dd, self._misc)
        _register_once(self._data)
        self._chain_dofs = cc.eff_dofs
        # Views into ed: assigning a (3, 3) rotation to a view row costs ~1 us where
        # np.reshape(rotation, 9) into a slice cost ~7 us (line profile of solve()).
        n_eff = len(chain.effectors)
        self._tpos = self._ed[:, ED_TPOS : ED_TPOS + 3]
        self._trot = self._ed[:, ED_TROT : ED_TROT + 9].reshape(n_eff, 3, 3)
        self._tdir = self._ed[:, ED_TDIR : ED_TDIR + 3]
        assert np.shares_memory(self._trot, self._ed)
        self._effector_names = chain.effector_names
        self._effector_slot = {name: i for i, name in enumerate(self._effector_names)}
        self._modes = tuple(e.mode for e in chain.effectors)
        self._static_weights = chain.compiled.ed[:, ED_WP].copy()
        self._active: list[int] = []
        self._zeroed: list[int] = []
        self._tol_for: IKOptions | None = None
        self._misc_for: IKOptions | None = None
        self._bounds_are_limits = True
        self._n_active = 0
        self._every_effector_moves_all = all(d.shape[0] == n for d in cc.eff_dofs)
        self._mid = chain.mid_limits()
        self._identity = np.eye(n)
        self._shape = (n,)
        self._packed: dict[
            int, tuple[IKOptions, MinimizeOptions, np.ndarray, np.ndarray, np.ndarray]
        ] = {}
        self._rng = np.random.default_rng(0 if seed is None else seed)
        self._seeds: list[int] = []
        self._last_packed: (
            tuple[IKOptions, MinimizeOptions, np.ndarray, np.ndarray, np.ndarray] | None
        ) = None
        self.q = self._mid.copy()  # the stream's current pose
        self._rest = self._mid.copy()
        self._h: Matrix | None = None

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
            rng: Source of the restart seed; default a generator owned by the solver.
            initial_inverse_hessian: Start H (shape (n_dof, n_dof)); default I.

        Raises:
            InvalidProblem: unknown effector, missing or malformed target fields.
            DimensionMismatch: seed of the wrong length.
        """
        opts = options or self.options
        q0 = self._mid if seed is None else self._check_seed(seed)
        self._load_targets(targets, opts)
        if self._misc_for is not opts:
            self._misc[MISC_POSTURE] = opts.posture_weight
            self._misc[MISC_LIMIT] = opts.limit_weight
            self._misc[MISC_MARGIN] = opts.limit_margin
            self._misc[MISC_DAMPING] = opts.damping
            self._misc_for = opts
        self._dd[DD_QREF] = q0
        self._set_free_bounds(q0)
        return self._run(q0, opts, rng, initial_inverse_hessian)

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
        result = self.solve(targets, self.q, options=opts, rng=rng, initial_inverse_hessian=h0)
        if not result.success and opts.global_fallback and math.isfinite(opts.restart_radius_rad):
            budget = opts.time_budget_us
            left = None if budget is None else budget - (time.perf_counter() - started) * 1e6
            if left is None or left > 0.0:
                wide = replace(opts, restart_radius_rad=math.inf, time_budget_us=left)
                retry = self.solve(targets, self.q, options=wide, rng=rng)
                if retry.success:
                    result = retry
        if result.success and opts.null_space_step_rad > 0.0:
            moved = np.empty(self.chain.n_dof)
            errors = np.empty_like(result.raw_errors)
            if _null_space_frame(
                self._data, result.q, self._rest, opts.null_space_step_rad, moved, errors
            ):
                result = result._replace(q=moved, raw_errors=errors)
        self.q = result.q.copy()
        self._h = result.inverse_hessian
        return result

    def set_pose(self, q: Vector) -> None:
        """Set the stream's current pose and its rest pose (projected into the limits).

        The rest pose is where ``null_space_step_rad`` steers a redundant chain's
        self-motion; by default it is the middle of the limits.
        """
        self.q = np.clip(self._check_seed(q), self.chain.lower, self.chain.upper)
        self._rest = self.q.copy()
        self._h = None

    def errors_at(self, q: Vector, targets: Sequence[Target]) -> tuple[EffectorError, ...]:
        """Pose errors of q against targets with the solver's tolerances (no solving)."""
        self._load_targets(targets, self.options)
        errors = np.empty((len(self.chain.effectors), 3))
        q = self._check_seed(q)
        bad, _ = _report_only(self._data, q, errors)
        self._raise_bad_target(bad)
        empty = np.zeros((0, C.N_LOG))
        result = self._result(
            q,
            IKStatus.SOLVED,
            Termination.GOAL_REACHED,
            0,
            0,
            0,
            0,
            0.0,
            empty,
            np.eye(0),
            errors,
            self.options,
        )
        return result.effectors

    # -- internals -------------------------------------------------------------
    def _check_seed(self, seed: Vector) -> Vector:
        # No copy: the core projects the seed into its own buffer and never writes it.
        # Finiteness is checked in the compiled call (``_solve_core``), not here.
        if type(seed) is np.ndarray and seed.dtype == np.float64 and seed.shape == self._shape:
            return seed
        q = np.asarray(seed, dtype=np.float64).reshape(-1)
        if q.shape != (self.chain.n_dof,):
            raise DimensionMismatch(f"seed must have {self.chain.n_dof} values, got {q.shape[0]}")
        return q

    def _load_targets(self, targets: Sequence[Target], opts: IKOptions) -> None:
        """Copy targets into the compiled arrays (shapes checked here, values compiled)."""
        ei = self._ei
        ed = self._ed
        for i in self._active:
            ei[i, EI_ACTIVE] = 0
        for i in self._zeroed:
            ed[i, ED_WP] = self._static_weights[i]
        self._active = active = []
        self._zeroed = []
        if self._tol_for is not opts:
            ed[:, ED_TOL_P] = opts.position_tolerance_m
            ed[:, ED_TOL_R] = opts.rotation_tolerance_rad
            self._tol_for = opts
        for t in targets:
            i = self._effector_slot.get(t.effector, -1)
            if i < 0:
                self.chain.effector_index(t.effector)  # raises with the list of names
            if ei[i, EI_ACTIVE]:
                raise InvalidProblem(f"two targets for effector {t.effector!r}")
            mode = self._modes[i]
            try:
                if t.position is not None:
                    self._tpos[i] = t.position
                elif mode is EffectorMode.POSITION:
                    raise InvalidProblem(f"target for {t.effector!r} needs a position")
                else:
                    ed[i, ED_WP] = 0.0
                    self._zeroed.append(i)
                if mode is EffectorMode.POSE:
                    if t.rotation is None:
                        raise InvalidProblem(f"target for {t.effector!r} (pose) needs a rotation")
                    self._trot[i] = t.rotation
                elif mode is EffectorMode.AIM:
                    if t.direction is None:
                        raise InvalidProblem(f"target for {t.effector!r} (aim) needs a direction")
                    self._tdir[i] = t.direction
            except (ValueError, TypeError) as err:
                if isinstance(err, InvalidProblem):
                    raise
                raise InvalidProblem(
                    f"target for {t.effector!r}: position and direction need 3 numbers, "
                    "rotation a 3x3 matrix"
                ) from None
            ei[i, EI_ACTIVE] = 1
            active.append(i)
        self._n_active = len(active)

    def _set_free_bounds(self, q0: Vector) -> None:
        """Limits for this frame (DD rows): variables outside every targeted chain are
        frozen at q0."""
        lo = self.chain.lower
        hi = self.chain.upper
        if self._every_effector_moves_all and self._n_active > 0:
            if not self._bounds_are_limits:
                self._dd[DD_LO] = lo
                self._dd[DD_HI] = hi
                self._bounds_are_limits = True
            return
        free = np.zeros(self.chain.n_dof, dtype=bool)
        for i in self._active:
            free[self._chain_dofs[i]] = True
        q = np.clip(q0, lo, hi)
        self._dd[DD_LO] = np.where(free, lo, q)
        self._dd[DD_HI] = np.where(free, hi, q)
        self._bounds_are_limits = False

    def _packed_options(
        self, opts: IKOptions
    ) -> tuple[MinimizeOptions, np.ndarray, np.ndarray, np.ndarray]:
        """Option vectors and policy table, built once per IKOptions object."""
        last = self._last_packed
        if last is not None and last[0] is opts:
            return last[1], last[2], last[3], last[4]
        hit = self._packed.get(id(opts))
        if hit is None or hit[0] is not opts:
            mopts = opts.minimize_options()
            fopt, iopt = pack_options(mopts, seed=0)
            if len(self._packed) > 32:
                self._packed.clear()
            hit = (opts, mopts, fopt, iopt, opts.policy.as_array())
            self._packed[id(opts)] = hit
        self._last_packed = hit
        return hit[1], hit[2], hit[3], hit[4]

    def _next_seed(self, rng: np.random.Generator | None) -> int:
        if rng is not None:
            return int(rng.integers(0, 2**31 - 1))
        if not self._seeds:
            # Drawing one integer costs ~4 us; a batch of 256 costs about the same.
            self._seeds = self._rng.integers(0, 2**31 - 1, size=256).tolist()
        return self._seeds.pop()

    def _run(
        self,
        q0: Vector,
        opts: IKOptions,
        rng: np.random.Generator | None,
        h0: Matrix | None,
    ) -> IKResult:
        n = self.chain.n_dof
        mopts, fopt, iopt, policy = self._packed_options(opts)
        iopt[C.I_SEED] = self._next_seed(rng)
        h = self._identity.copy() if h0 is None else h0.copy()
        log = np.empty((mopts.max_passes, C.N_LOG))  # the core fills the rows it reports
        out_x = np.empty(n)
        errors = np.empty((len(self.chain.effectors), 3))
        if n == 0:
            # An all-fixed chain: nothing to solve, only errors to report.
            bad, measure = _report_only(self._data, q0, errors)
            self._raise_bad_target(bad)
            status = IKStatus.SOLVED if measure <= 1.0 else IKStatus.NOT_REACHED
            code = Termination.GOAL_REACHED if measure <= 1.0 else Termination.GTOL
            return self._result(q0.copy(), status, code, 0, 0, 0, 0, 0.0, log[:0], h, errors, opts)
        bad, (f, _, _, code, nit, nfev, _, npass, nrest, _, elapsed), measure = _solve_core(
            self._data, q0, h, fopt, iopt, policy, log, out_x, errors
        )
        if bad != -1:
            self._raise_bad_target(bad)
        termination = C.TERMINATIONS[int(code)]
        if measure <= 1.0:
            status = IKStatus.SOLVED
        elif termination is Termination.NONFINITE or not math.isfinite(measure):
            status = IKStatus.NONFINITE
        elif termination.budget_exhausted:
            status = IKStatus.BUDGET_EXHAUSTED
        else:
            status = IKStatus.NOT_REACHED
        return self._result(
            out_x,
            status,
            termination,
            int(nit),
            int(nfev),
            int(npass),
            int(nrest),
            float(elapsed) * 1e6,
            log,
            h,
            errors,
            opts,
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

    def _result(
        self,
        q: Vector,
        status: IKStatus,
        termination: Termination,
        nit: int,
        nfev: int,
        npass: int,
        nrest: int,
        solve_us: float,
        raw_log: np.ndarray,
        h: Matrix,
        errors: np.ndarray,
        opts: IKOptions,
    ) -> IKResult:
        return IKResult(
            q=q,
            dof_names=self.chain.dof_names,
            status=status,
            success=status is IKStatus.SOLVED,
            termination=termination,
            raw_errors=errors,
            effector_names=self._effector_names,
            tolerances=(opts.position_tolerance_m, opts.rotation_tolerance_rad),
            iterations=nit,
            function_evals=nfev,
            passes=npass,
            restarts=nrest,
            solve_us=solve_us,
            raw_pass_log=raw_log,
            inverse_hessian=h,
        )


_REGISTERED = False
_NO_TRACE = np.empty((0, 5))


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
