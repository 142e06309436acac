"""The IK solver object: targets for a chain's effectors -> joint values, frame by frame.

``IKSolver`` is built once per chain (it keeps preallocated arrays for the compiled
core) and solves one frame per call: ``solve`` from a given seed, ``track`` from the
previous answer (a stream). Success is judged from the pose errors against the
tolerances, never from the optimizer's code alone: the core's goal measure is
max(error / tolerance) over effectors, so "goal met" means "IK succeeded".

Its documented surface for code built on it (the planner, ``solver.path``; benchmarks):
``check_seed``, ``judge``, ``load_frame`` (the compiled data for a frame, which the
planner's kernels read), ``free_mask``, ``free_directions``, ``stream_state``, ``restore``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from typing import Any, NamedTuple

import numpy as np

from .._jit import compiled_entry
from ..arrays import Matrix, Vector
from ..errors import DimensionMismatch
from ..model import Chain
from ..optim import Termination, register_objective
from ..optim import codes as C
from .blend import blend_rows, solve_blended
from .continuity import NO_STEP, Continuity, FrameStep, largest_step, narrow_bounds
from .frame import (
    TARGETS_OK,
    check_targets,
    raise_bad_target,
    report_only,
    scratch_size,
    solve_frame,
)
from .kinematics import (
    DD_HI,
    DD_LO,
    DD_REST,
    MISC_DAMPING,
    MISC_DAMPING_SCALE,
    MISC_LIMIT,
    MISC_MARGIN,
    MISC_POLISH_STEPS,
    MISC_POSTURE,
    MISC_SIZE,
    dd_rows,
    ik_goal,
    ik_objective,
)
from .metric import ik_metric
from .options import IKOptions
from .packing import OptionPacks
from .pole_term import pole_block_size
from .poles import SHAPING_FIRST_MAX_ITER, SHAPING_MAX_ITER, PoleShaper
from .reach import ReachBounds
from .result import STATUSES, EffectorError, IKResult, IKStatus
from .settled import settled_variables, variable_periods
from .split import LimbSplit
from .targets import Target
from .task import Task

# The arrays a compiled solve reads: (NI, ND, EI, ED, DD, MISC), see ``kinematics``.
IKData = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


class StreamState(NamedTuple):
    """What ``track`` carries from frame to frame: the pose, the BFGS matrix when
    ``IKOptions.carry_hessian`` is on (else None), whether the stream has an answer to
    stay near since ``set_pose`` (``_MISSES_UNBOXED``) and the frames it missed until then."""

    q: Vector
    inverse_hessian: Matrix | None
    anchored: bool = True
    misses: int = 0


_tuple_new = tuple.__new__


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
        ei = cc.ei.copy()
        self._dd = np.zeros((dd_rows(n), n))
        self._dd[DD_LO] = chain.lower
        self._dd[DD_HI] = chain.upper
        # The IK's entries, then the pole block (pole_term): zero poles switched on.
        self._misc = np.zeros(MISC_SIZE + pole_block_size(len(chain.effectors)))
        self._shaper: PoleShaper | None = None
        self._data: IKData = (cc.ni, cc.nd.copy(), ei, cc.ed.copy(), self._dd, self._misc)
        _register_once(self._data)
        self._task = Task(chain, ei, self._data[3], self._dd)
        self._misc_for: IKOptions | None = None
        self._mid = chain.mid_limits()
        self._identity = np.eye(n)
        self._shape = (n,)
        self._packs = OptionPacks(chain, np.random.default_rng(0 if seed is None else seed))
        self.q = self._mid.copy()  # the stream's current pose
        self._dd[DD_REST] = self._mid
        self._h: Matrix | None = None
        self._solve_call: Callable[..., tuple[Any, ...]] = solve_frame
        # solve_frame's work space (it allocates nothing: see _jit.jit_leaf).
        self._scratch = np.empty(scratch_size(n, ei.shape[0]))
        self._ints = np.empty(3, dtype=np.int64)
        self._largest_step: Callable[..., float] = largest_step
        self._narrow_bounds: Callable[..., None] = narrow_bounds
        self.last_step: FrameStep = NO_STEP  # how far the last ``track`` frame moved
        self._anchored = False  # an answer to stay near since the pose was set?
        self._misses = 0  # frames missed since the pose was set, until anchored
        self._split = LimbSplit(chain, lambda limb: IKSolver(limb, self.options, seed=seed))
        self._reach = ReachBounds(chain)  # a target beyond it: not_reached, no global search

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
        q0 = self._mid if seed is None else self.check_seed(seed)
        # Several targets: independent groups, or a trunk to place first (``split``).
        if len(targets) > 1 and opts.split_limbs and initial_inverse_hessian is None:
            split = self._split
            groups = split.groups(targets)
            if (
                groups
                and (len(groups) > 1 or (opts.inner_first and split.inner(groups[0])))
                and np.isfinite(q0).all()  # else the whole solve words the error
            ):
                packed = self._packs.get(opts)
                out = split.solve(groups, targets, q0, opts, rng, packed.layout, packed.out_size)
                return self._reach.judged(out, targets, opts)
        out = self._frame(targets, q0, opts, rng, initial_inverse_hessian, 0.0)
        return self._reach.judged(out, targets, opts)

    def solve_within(
        self,
        targets: Sequence[Target],
        seed: Vector,
        options: IKOptions,
        rng: np.random.Generator | None,
        time_left_us: float | None,
        *,
        frozen: np.ndarray | None = None,
    ) -> IKResult:
        """``solve`` of one group of effectors (``split``) in what the frame's budget
        has left (None: no limit), without looking for groups; the variables
        ``frozen`` marks (bool, shape (n_dof,)) stay at the seed."""
        q0 = self.check_seed(seed)
        return self._frame(
            targets, q0, options, rng, None, 0.0, time_left_us=time_left_us, frozen=frozen
        )

    def track(
        self,
        targets: Sequence[Target],
        *,
        options: IKOptions | None = None,
        rng: np.random.Generator | None = None,
    ) -> IKResult:
        """Solve the next frame of a stream, warm-started from the previous answer.

        The pose (and, with ``carry_hessian``, the BFGS matrix) carries over; the
        posture pull, if any, is towards the previous pose. ``options.continuity``: what
        a frame whose target is not reachable nearby does (``continuity``; until one is
        solved after ``set_pose``, as under REACH); ``last_step``: how far it moved.
        ``targets`` may be a ``TargetRows`` (rows packed by the caller: loaded without
        building a ``Target`` each).
        """
        opts = options or self.options
        h0 = self._h if opts.carry_hessian else None
        started = time.perf_counter()
        # float(): an int here would make numba compile another specialisation.
        step = float(opts.null_space_step_rad)
        # ``q`` is public: check it as a seed (length, dtype, layout) every frame.
        q0 = self.check_seed(self.q)
        # No answer to stay near (a stream's first frame, or all missed so far): REACH.
        smooth = opts.continuity is Continuity.SMOOTH and self._anchored
        box = float(opts.max_joint_step_rad) if smooth else 0.0
        fallback = not smooth and opts.global_fallback and math.isfinite(opts.restart_radius_rad)
        budget = opts.time_budget_us
        # With a global search to follow, the local one gets half a finite budget.
        local = budget * 0.5 if fallback and budget is not None else None
        result = self._frame(targets, q0, opts, rng, h0, step, box, time_left_us=local, stream=True)
        if fallback and not result.success and not self._reach.beyond(targets, opts):
            left = None if budget is None else budget - (time.perf_counter() - started) * 1e6
            if left is None or left > 0.0:
                wide = replace(opts, restart_radius_rad=_GLOBAL_RADIUS, time_budget_us=left)
                retry = self._frame(targets, q0, wide, rng, None, step, stream=True)
                if retry.success:
                    result = retry
        result = self._reach.judged(result, targets, opts)
        self.q = result.q.copy()
        if not self._anchored:  # is this an answer to stay near? (_MISSES_UNBOXED)
            self._misses += 1
            self._anchored = result.success or self._misses >= _MISSES_UNBOXED
            self._anchored = self._anchored or self._reach.only_beyond_missed(result, targets, opts)
        # A copy: the result's block is the caller's to keep (and to write to).
        self._h = result.inverse_hessian.copy() if opts.carry_hessian else None
        largest = self._largest_step(result.q, q0)
        if self._largest_step is largest_step:
            self._largest_step = compiled_entry(largest_step, (result.q, q0))
        # + 1e-9: under SMOOTH, (q0 + box) - q0 may round one ulp above the box.
        # tuple.__new__: the NamedTuple's own __new__ is Python code (every frame).
        self.last_step = _tuple_new(FrameStep, (largest, largest > opts.max_joint_step_rad + 1e-9))
        return result

    def set_pose(self, q: Vector) -> None:
        """Set the stream's current pose and its rest pose (projected into the limits).

        The rest pose is where ``null_space_step_rad`` steers a redundant chain's
        self-motion; by default it is the middle of the limits.
        """
        self.q = np.clip(self.check_seed(q), self.chain.lower, self.chain.upper)
        self._dd[DD_REST] = self.q
        self._h = None
        self.last_step = NO_STEP
        self._anchored, self._misses = False, 0

    def errors_at(self, q: Vector, targets: Sequence[Target]) -> tuple[EffectorError, ...]:
        """Pose errors of q against targets with the solver's tolerances (no solving)."""
        return self.judge(q, targets).effectors

    def check_seed(self, seed: Vector) -> Vector:
        """``seed`` as the compiled solve takes it: float64, C-contiguous, shape
        (n_dof,); the array itself when it already is one (no copy).

        Raises:
            DimensionMismatch: a seed of the wrong length.
        """
        # ``carray`` (C-contiguous, aligned, writeable) matters: numba compiles a new
        # specialisation, tens of seconds, for any other array layout. Finiteness is
        # checked in compiled code.
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

    def judge(
        self,
        q: Vector,
        targets: Sequence[Target],
        *,
        options: IKOptions | None = None,
        solve_us: float = 0.0,
    ) -> IKResult:
        """A result for q as it is (no solving): errors against the targets, SOLVED
        (goal_reached) within the tolerances of ``options`` (default: the solver's),
        else NOT_REACHED (gtol). ``solve_us`` is recorded as the result's time.

        Raises:
            InvalidProblem: as ``solve`` for bad targets or a non-finite q.
        """
        opts = options or self.options
        self._task.load(targets, opts)
        packed = self._packs.get(opts)
        raw = np.full(packed.out_size, math.nan)
        q = self.check_seed(q)
        bad, measure = report_only(self._data, q, raw)
        raise_bad_target(self.chain, bad)
        ok = measure <= 1.0
        status = IKStatus.SOLVED if ok else IKStatus.NOT_REACHED
        code = Termination.GOAL_REACHED if ok else Termination.GTOL
        return IKResult(q, status, code, 0, 0, 0, 0, solve_us, raw, packed.layout)

    def load_frame(
        self, targets: Sequence[Target], q0: Vector, *, options: IKOptions | None = None
    ) -> IKData:
        """Load a frame's targets and its bounds as a solve from q0 does (variables
        outside every targeted chain frozen at q0; aim directions normalised), and
        return the compiled data the frame's solve would read. For compiled code
        built on the IK (the planner's kernels; ``kinematics.ik_objective(q, g,
        need_grad, data)`` in a benchmark). The arrays are the solver's own: valid
        until its next call. Targets are not checked here (``judge`` checks them)."""
        task = self._task
        task.load(targets, options or self.options)
        check_targets(self._data)
        if not (task.bounds_are_limits and task.every_effector_moves_all and task.pulling):
            task.set_free_bounds(q0)
        return self._data

    def free_mask(self) -> np.ndarray:
        """For the targets loaded last: 1.0 for each variable they may move (unlocked,
        in the chain of a targeted effector with a part above weight 0), else 0.0."""
        return self._task.free_mask()

    def free_directions(self) -> int:
        """For the targets loaded last: free joints of the targeted effectors minus
        their target rows (the self-motion's dimension; a 7-DOF arm under a pose: 1)."""
        return self._task.free_directions()

    def stream_state(self) -> StreamState:
        """The pose and carried BFGS matrix the next ``track`` starts from."""
        return StreamState(self.q, self._h, self._anchored, self._misses)

    def restore(self, state: StreamState) -> None:
        """Continue a stream from ``state`` (the rest pose is kept: see ``set_pose``)."""
        self.q = state.q
        self._h = state.inverse_hessian
        self._anchored, self._misses = state.anchored, state.misses

    # -- internals -------------------------------------------------------------
    def _frame(
        self,
        targets: Sequence[Target],
        q0: Vector,
        opts: IKOptions,
        rng: np.random.Generator | None,
        h0: Matrix | None,
        null_space_step_rad: float,
        box: float = 0.0,
        *,
        time_left_us: float | None = None,
        frozen: np.ndarray | None = None,
        stream: bool = False,
    ) -> IKResult:
        task = self._task
        task.load(targets, opts)
        if task.blended:  # weights strictly between 0 and 1 (blend)
            blend_rows(self.chain, q0, task.target_rows, task.blended)
        if self._misc_for is not opts:
            self._misc[MISC_POSTURE] = opts.posture_weight
            self._misc[MISC_LIMIT] = opts.limit_weight
            self._misc[MISC_MARGIN] = opts.limit_margin
            self._misc[MISC_DAMPING_SCALE] = opts.damping_scale
            self._misc[MISC_POLISH_STEPS] = opts.polish_steps
            self._misc_for = opts
        # Per frame: the target set (and with it the redundancy) can change under the
        # same options.
        self._misc[MISC_DAMPING] = (
            opts.damping if task.redundant or not opts.damping_redundant_only else 0.0
        )
        if frozen is not None or not (
            task.bounds_are_limits and task.every_effector_moves_all and task.pulling
        ):
            task.set_free_bounds(q0, frozen)
        if box > 0.0:  # SMOOTH: the limits within box of q0 (reset by the next frame)
            call_narrow = self._narrow_bounds
            call_narrow(self._dd, q0, box)
            if call_narrow is narrow_bounds:
                self._narrow_bounds = compiled_entry(narrow_bounds, (self._dd, q0, box))
            task.bounds_are_limits = False
        packed = self._packs.last
        if packed is None or packed.options is not opts or packed.stream != stream:
            packed = self._packs.get(opts, stream)
        if rng is not None:
            packed.iopt[C.I_SEED] = int(rng.integers(0, 2**31 - 1))
        fopt = packed.fopt
        if time_left_us is not None:  # a group of a split frame: what the others left
            fopt = fopt.copy()
            fopt[C.F_BUDGET] = max(time_left_us, 0.0) * 1e-6
        out = np.empty(packed.out_size)
        if self._n == 0:
            # An all-fixed chain: nothing to solve, only errors to report.
            bad, measure = report_only(self._data, q0, out)
            raise_bad_target(self.chain, bad)
            ok = measure <= 1.0
            judged = IKStatus.SOLVED if ok else IKStatus.NOT_REACHED
            why = Termination.GOAL_REACHED if ok else Termination.GTOL
            return IKResult(q0.copy(), judged, why, 0, 0, 0, 0, 0.0, out, packed.layout)
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
            fopt,
            packed.iopt,
            packed.policy,
            out_x,
            out,
            null_space_step_rad,
            self._scratch,
            self._ints,
        )
        call = self._solve_call
        usual: Callable[..., tuple[Any, ...]]
        if task.blended:  # soft parts: aim at them, then judge full weights only (blend)
            usual = partial(solve_blended, call, relax_soft_parts=task.relax_soft_parts)
        else:
            usual = call
        if task.poles:  # a shaping pass first (poles)
            if self._shaper is None:
                self._shaper = PoleShaper(self.chain, MISC_SIZE)
            # A stream's later frame carries on the swing of the one before it.
            first = not (stream and self._anchored)
            cap = SHAPING_FIRST_MAX_ITER if first else SHAPING_MAX_ITER
            solved = self._shaper.solve(args, task.poles, usual, cap)
        else:
            solved = usual(*args)
        bad, status, code, nit, nfev, npass, nrest, elapsed = solved
        if call is solve_frame:
            self._solve_call = compiled_entry(solve_frame, args)
        if bad != TARGETS_OK:
            raise_bad_target(self.chain, bad)
        # tuple.__new__ directly: the NamedTuple's generated __new__ is Python code.
        return _tuple_new(
            IKResult,
            (
                out_x,
                STATUSES[status],
                C.TERMINATIONS[code],
                nit,
                nfev,
                npass,
                nrest,
                elapsed * 1e6,
                out,
                packed.layout,
            ),
        )


_REGISTERED = False
# Under SMOOTH, frames are solved as under REACH until the stream is anchored: a frame
# solved after set_pose, one whose only misses are targets beyond reach (every other
# target met), or the tenth missed in a row (a target out of reach keeps the step limit).
_MISSES_UNBOXED = 10
# ``track``'s global fallback samples a full turn either side of the seed. Not inf: the
# optimizer samples an unbounded side within 10 x |seed| (PR2's wrist went to 20,000 rad).
_GLOBAL_RADIUS = 2.0 * math.pi


def _register_once(data: tuple[np.ndarray, ...]) -> None:
    """Bind the IK objective to the IK data tuple's type (every chain shares it)."""
    global _REGISTERED
    if not _REGISTERED:
        register_objective(
            ik_objective, ik_goal, data, ik_metric, settled_variables, variable_periods
        )
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
