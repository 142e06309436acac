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
    MISC_LIMIT,
    MISC_MARGIN,
    MISC_POSTURE,
    effector_errors,
    ik_goal,
    ik_metric,
    ik_objective,
)
from .termination import Termination
from .types import Matrix, MinimizeOptions, PassRecord, Vector


@jit
def _solve_core(data, x0, lo, hi, h, fopt, iopt, policy, log, trace, out_x, out_g):  # type: ignore[no-untyped-def]
    # fg=None: the core binds the objective registered for this data type (cacheable).
    # The final errors are computed here too: one compiled call per frame, not two.
    out = run_solver(None, None, data, x0, lo, hi, h, fopt, iopt, policy, log, trace, out_x, out_g)
    measure = effector_errors(out_x, data)
    return out, measure


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
    max_iter: int = 1000
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
        for name in ("posture_weight", "limit_weight", "ftol", "gtol"):
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


# Stream defaults: local restarts and a light pull away from the limits, so a frame
# that misses recovers without a visible jump (the user can override every field).
STREAM_DEFAULTS = IKOptions(restart_radius_rad=0.3, limit_weight=1e-3, limit_margin=0.02)


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
class IKResult:
    """Answer to one frame.

    Attributes:
        q: Joint values, shape (n_dof,), in ``dof_names`` order, inside the limits.
        dof_names: Variable names.
        status: SOLVED / NOT_REACHED / BUDGET_EXHAUSTED / NONFINITE.
        success: status is SOLVED.
        termination: How the optimizer's last pass ended.
        effectors: Errors for the effectors that had a target.
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
    effectors: tuple[EffectorError, ...]
    iterations: int
    function_evals: int
    passes: int
    restarts: int
    solve_us: float
    inverse_hessian: Matrix
    raw_pass_log: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, C.N_LOG)))

    @property
    def pass_log(self) -> tuple[PassRecord, ...]:
        return unpack_pass_log(self.raw_pass_log, self.raw_pass_log.shape[0])

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

    def __init__(self, chain: Chain, options: IKOptions | None = None) -> None:
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
        self._misc = np.zeros(4)
        self._data = (cc.ni, cc.nd.copy(), self._ei, self._ed, self._dd, self._misc)
        _register_once(self._data)
        self._chain_dofs = cc.eff_dofs
        self._effector_slot = {name: i for i, name in enumerate(chain.effector_names)}
        self._n_active = 0
        self._every_effector_moves_all = all(d.shape[0] == n for d in cc.eff_dofs)
        self._mid = chain.mid_limits()
        self._identity = np.eye(n)
        self._packed: dict[
            int, tuple[IKOptions, MinimizeOptions, np.ndarray, np.ndarray, np.ndarray]
        ] = {}
        self._rng = np.random.default_rng(0)
        self._seeds = np.empty(0, dtype=np.int64)
        self.q = self._mid.copy()  # the stream's current pose
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
        self._misc[MISC_POSTURE] = opts.posture_weight
        self._misc[MISC_LIMIT] = opts.limit_weight
        self._misc[MISC_MARGIN] = opts.limit_margin
        self._dd[DD_QREF] = q0
        lo, hi = self._free_bounds(q0)
        self._dd[DD_LO] = lo
        self._dd[DD_HI] = hi
        return self._run(q0, lo, hi, opts, rng, initial_inverse_hessian)

    def track(self, targets: Sequence[Target], *, options: IKOptions | None = None) -> IKResult:
        """Solve the next frame of a stream, warm-started from the previous answer.

        The pose (and, with ``carry_hessian``, the BFGS matrix) carries over; the
        posture pull, if any, is towards the previous pose.
        """
        opts = options or self.options
        h0 = self._h if opts.carry_hessian else None
        result = self.solve(targets, self.q, options=opts, initial_inverse_hessian=h0)
        self.q = result.q.copy()
        self._h = result.inverse_hessian
        return result

    def set_pose(self, q: Vector) -> None:
        """Set the stream's current pose (projected into the limits)."""
        self.q = np.clip(self._check_seed(q), self.chain.lower, self.chain.upper)
        self._h = None

    def errors_at(self, q: Vector, targets: Sequence[Target]) -> tuple[EffectorError, ...]:
        """Pose errors of q against targets with the solver's tolerances (no solving)."""
        self._load_targets(targets, self.options)
        effector_errors(self._check_seed(q), self._data)
        return self._effector_report(self.options)

    # -- internals -------------------------------------------------------------
    def _check_seed(self, seed: Vector) -> Vector:
        q = np.array(seed, dtype=np.float64).reshape(-1)
        if q.shape != (self.chain.n_dof,):
            raise DimensionMismatch(f"seed must have {self.chain.n_dof} values, got {q.shape[0]}")
        if not np.isfinite(q).all():
            raise InvalidProblem("seed must be finite")
        return q

    def _load_targets(self, targets: Sequence[Target], opts: IKOptions) -> None:
        chain = self.chain
        ei = self._ei
        ed = self._ed
        ei[:, EI_ACTIVE] = 0
        ed[:, ED_WP : ED_WP + 2] = chain.compiled.ed[:, ED_WP : ED_WP + 2]
        ed[:, ED_TOL_P] = opts.position_tolerance_m
        ed[:, ED_TOL_R] = opts.rotation_tolerance_rad
        self._n_active = 0
        for t in targets:
            i = self._effector_slot.get(t.effector, -1)
            if i < 0:
                chain.effector_index(t.effector)  # raises with the list of names
            if ei[i, EI_ACTIVE]:
                raise InvalidProblem(f"two targets for effector {t.effector!r}")
            eff = chain.effectors[i]
            if t.position is not None:
                ed[i, ED_TPOS : ED_TPOS + 3] = _vec3(t.position, t.effector, "position")
            elif eff.mode is EffectorMode.POSITION:
                raise InvalidProblem(f"target for {t.effector!r} needs a position")
            else:
                ed[i, ED_WP] = 0.0
            if eff.mode is EffectorMode.POSE:
                if t.rotation is None:
                    raise InvalidProblem(f"target for {t.effector!r} (pose) needs a rotation")
                ed[i, ED_TROT : ED_TROT + 9] = _rotation(t.rotation, t.effector).reshape(-1)
            elif eff.mode is EffectorMode.AIM:
                if t.direction is None:
                    raise InvalidProblem(f"target for {t.effector!r} (aim) needs a direction")
                dx, dy, dz = _vec3(t.direction, t.effector, "direction")
                norm = math.sqrt(dx * dx + dy * dy + dz * dz)
                if norm < 1e-12:
                    raise InvalidProblem(f"target direction for {t.effector!r} must not be zero")
                ed[i, ED_TDIR : ED_TDIR + 3] = (dx / norm, dy / norm, dz / norm)
            ei[i, EI_ACTIVE] = 1
            self._n_active += 1

    def _free_bounds(self, q0: Vector) -> tuple[Vector, Vector]:
        """Limits for this frame: variables outside every targeted chain are frozen at q0."""
        lo = self.chain.lower
        hi = self.chain.upper
        if self._every_effector_moves_all and self._n_active > 0:
            return lo, hi
        active = np.flatnonzero(self._ei[:, EI_ACTIVE])
        free = np.zeros(self.chain.n_dof, dtype=bool)
        for i in active:
            free[self._chain_dofs[i]] = True
        q = np.clip(q0, lo, hi)
        return np.where(free, lo, q), np.where(free, hi, q)

    def _packed_options(
        self, opts: IKOptions
    ) -> tuple[MinimizeOptions, np.ndarray, np.ndarray, np.ndarray]:
        """Option vectors and policy table, built once per IKOptions object."""
        hit = self._packed.get(id(opts))
        if hit is None or hit[0] is not opts:
            mopts = opts.minimize_options()
            fopt, iopt = pack_options(mopts, seed=0, started_at=0.0)
            if len(self._packed) > 32:
                self._packed.clear()
            hit = (opts, mopts, fopt, iopt, opts.policy.as_array())
            self._packed[id(opts)] = hit
        return hit[1], hit[2], hit[3], hit[4]

    def _next_seed(self, rng: np.random.Generator | None) -> int:
        if rng is not None:
            return int(rng.integers(0, 2**31 - 1))
        if self._seeds.shape[0] == 0:
            # Drawing one integer costs ~4 us; a batch costs about the same.
            self._seeds = self._rng.integers(0, 2**31 - 1, size=256)
        seed = int(self._seeds[-1])
        self._seeds = self._seeds[:-1]
        return seed

    def _run(
        self,
        q0: Vector,
        lo: Vector,
        hi: Vector,
        opts: IKOptions,
        rng: np.random.Generator | None,
        h0: Matrix | None,
    ) -> IKResult:
        n = self.chain.n_dof
        mopts, fopt, iopt, policy = self._packed_options(opts)
        iopt[C.I_SEED] = self._next_seed(rng)
        budget = opts.time_budget_us
        fopt[C.F_DEADLINE] = math.inf if budget is None else time.perf_counter() + budget * 1e-6
        h = self._identity.copy() if h0 is None else h0.copy()
        log = np.zeros((mopts.max_passes, C.N_LOG))
        out_x = np.empty(n)
        out_g = np.empty(n)
        if n == 0:
            # An all-fixed chain: nothing to solve, only errors to report.
            measure = effector_errors(q0, self._data)
            status = IKStatus.SOLVED if measure <= 1.0 else IKStatus.NOT_REACHED
            code = Termination.GOAL_REACHED if measure <= 1.0 else Termination.GTOL
            return self._result(q0.copy(), status, code, 0, 0, 0, 0, 0.0, log[:0], h, opts)
        (f, _, _, code, nit, nfev, _, npass, nrest, _, elapsed), measure = _solve_core(
            self._data, q0, lo, hi, h, fopt, iopt, policy, log, _NO_TRACE, out_x, out_g
        )
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
            log[: min(int(npass), log.shape[0])],
            h,
            opts,
        )

    def _effector_report(self, opts: IKOptions) -> tuple[EffectorError, ...]:
        out = []
        for i, eff in enumerate(self.chain.effectors):
            if not self._ei[i, EI_ACTIVE]:
                continue
            row = self._ed[i]
            pos = float(row[ED_ERR_P]) if row[ED_WP] > 0.0 else None
            rot = float(row[ED_ERR_R]) if eff.mode is not EffectorMode.POSITION else None
            ok = (pos is None or pos <= opts.position_tolerance_m) and (
                rot is None or rot <= opts.rotation_tolerance_rad
            )
            out.append(EffectorError(eff.name, pos, rot, ok))
        return tuple(out)

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
        opts: IKOptions,
    ) -> IKResult:
        return IKResult(
            q=q,
            dof_names=self.chain.dof_names,
            status=status,
            success=status is IKStatus.SOLVED,
            termination=termination,
            effectors=self._effector_report(opts),
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


def _vec3(v: Vector | Sequence[float], effector: str, name: str) -> list[float]:
    a = np.asarray(v, dtype=np.float64).reshape(-1).tolist()
    if len(a) != 3 or not (math.isfinite(a[0]) and math.isfinite(a[1]) and math.isfinite(a[2])):
        raise InvalidProblem(f"target {name} for {effector!r} must be 3 finite numbers")
    return a


def _rotation(r: Matrix, effector: str) -> Matrix:
    """A finite 3x3 rotation matrix (orthonormal within 1e-6, det +1).

    Checked with plain float arithmetic: np.allclose and np.linalg.det cost ~25 us
    per call, more than a whole compiled solve of a 7-DOF arm.
    """
    m = np.asarray(r, dtype=np.float64)
    if m.shape != (3, 3):
        raise InvalidProblem(f"target rotation for {effector!r} must be a 3x3 matrix")
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    if not all(math.isfinite(v) for v in (a, b, c, d, e, f, g, h, i)):
        raise InvalidProblem(f"target rotation for {effector!r} must be finite")
    rows = ((a, b, c), (d, e, f), (g, h, i))
    worst = 0.0
    for k in range(3):
        for j in range(3):
            dot = rows[k][0] * rows[j][0] + rows[k][1] * rows[j][1] + rows[k][2] * rows[j][2]
            worst = max(worst, abs(dot - (1.0 if k == j else 0.0)))
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if worst > 1e-6 or det < 0.0:
        raise InvalidProblem(f"target rotation for {effector!r} must be orthonormal with det +1")
    return m


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
