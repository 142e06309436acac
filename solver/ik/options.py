"""Per-solve settings of the IK (``IKOptions``) and the defaults for streams."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..errors import InvalidProblem
from ..optim import AnalyzerPolicy, MinimizeOptions
from .continuity import Continuity

# From this many variables a chain with at least as many task rows as variables
# re-seeds H every second iteration by default (``IKOptions.metric_interval``): the
# 7-DOF arms of bench/ik/ keep every iteration, where the metric is cheap.
EVERY_SECOND_METRIC_DOF = 13
# ``IKOptions.ftol``'s default: a solve's and a stream frame's (``IKSolver.track``).
SOLVE_FTOL = 3e-2
STREAM_FTOL = 1e-3


@dataclass(frozen=True, slots=True, kw_only=True)
class IKOptions:
    """Per-solve settings.

    Attributes:
        position_tolerance_m: Success needs every position error at or below this.
        rotation_tolerance_rad: ... and every orientation / aim error at or below this.
        time_budget_us: Wall-clock budget of one solve (None: no limit).
        max_iter: Iterations over all passes and restarts.
        max_restarts: Random restarts the analyzer may order. 126 by default, so
            that the time budget, not the count, ends a default solve that keeps
            missing (the pass log holds 512 passes, about 2 per restart): with 50,
            UR arms' +-pi wrists ended ``not_reached`` with budget left in about 1 of
            3000 random poses (bench/urdf_sweep.py). Streams keep 50.
        restart_radius_rad: Restarts sample within this distance of the seed (per
            variable); inf samples the whole range (TRAC-IK style, may jump).
        full_restart_every: With several targeted effectors, a restart keeps the
            variables that move only effectors already on target (at the best pose
            so far) and re-draws the others (``settled``, ``optim.restart``); every
            this many restarts re-draw every variable (1: all of them, the plain
            random restart; 0: never while an effector is on target). On the URDF
            sweep's many-tip chains (bench/RESULTS.md, issue 26) 8, 4 and 1 solved
            98.6%, 98.5% and 97.3% of the targets within 5 ms of CPU (g1: 73%, 71%,
            40%; the human's hands and head: 99.1%, 99.5%, 98.3%); with 0, some g1
            targets were never solved (the kept joints were what blocked them).
        split_limbs: ``solve`` takes the targeted effectors in groups that share no
            free variable one group at a time, each on its own limb's chain
            (``split``): the same minimum, at a limb's cost per iteration and
            restart. On g1 (legs apart from the torso and arms) the median solve fell
            ~4x, and the targets solved within 5 ms rose from 88.5% to 98.5%
            (bench/history/2026-11-28-limb-split.md). ``track`` solves the whole
            chain at once either way (a warm start needs ~1-2 iterations).
        inner_first: With ``split_limbs``, a group's trunk effectors (too few
            variables beyond the variables every effector of the group moves to meet
            their own target: a humanoid's torso markers, a head's pose on a 2-joint
            neck) are solved first, alone, and the whole group then from there: the
            trunk is placed before the limbs pull it into their own local minima
            (``split.LimbSplit.inner``). On 1000 targets per chain, interleaved, it
            took the alex hands from 94.1% and 97.4% to 99.8% within 5 ms, Baxter
            from 98.3% to 99.4% (bench/history/2026-11-28-limb-split.md).
        freeze_trunk: With ``inner_first``, once the trunk effectors have met their
            targets, the variables they move stay where they are while the group's
            other effectors are solved in the groups that leaves, each on its own
            limb (tiago_pro's and PR2's two arms given the torso lift and head the
            head markers placed); where a limb misses, the whole group goes on from
            there (``split.LimbSplit.limbs_given_trunk``, ``_solve_parts``).
            Interleaved on 600 targets, off / on within 5 ms: tiago_pro 97.8 /
            100%, PR2 99.3 / 100%, g1 99.2 / 100%, Baxter 99.5 / 100%, the human's
            hands and head 98.8 / 99.5% (bench/history/2026-11-29-freeze-trunk.md).
        turn_restarts: The first restart from each new best pose turns the revolute
            joints that a limit stops, whose range is over three quarters of a turn and which move
            an effector off target, the other way round: to the same angle from the
            other side, or to the opposite limit when the range is short of a full
            turn (``settled.variable_periods``, ``optim.restart.turn_values``).
        max_step_rad: Cap on any variable's change per iteration (a step cap keeps a
            cold solve from slamming several joints into their limits).
        posture_weight: Pull towards the reference pose (rest or previous): w sum dq^2.
        limit_weight: Penalty within ``limit_margin`` x range of a limit. Both are
            preferences among poses within the tolerances: a solve that misses with
            them continues without them (``frame.solve_frame``), since the penalised
            minimum can sit off a target that needs a joint inside the band (an arm
            stretched against its elbow stop).
        limit_margin: Width of that band as a fraction of the range.
        stall_window: Multi-pass trigger (iterations); 0 for a single pass.
        ftol: Relative improvement below which an iteration counts as stalled; None
            (default): 3% for a solve, 0.1% for a stream frame (``track``). A damped
            Gauss-Newton pass that reaches its target cuts f by orders of magnitude
            per iteration at the end, so five in a row under 3% is a pass crawling
            into a local minimum, better left for a restart (Tiago's three
            fingertips: at 0.1% a pass crawled for 215 iterations). A stream frame
            that crawls is better finished from the previous answer than restarted,
            which is a jump (bench/history/2026-11-29-stall-restarts.md).
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
            poses of each arm, at the same solve rate (bench/ik/); 0.1 needed more
            restarts. Streams keep 1.0 (their step and jump figures were measured
            with it).
        polish_steps: An answer that ends within a few tolerances of the goal
            (``polish.POLISH_WITHIN``) gets at most this many Levenberg-Marquardt
            steps on the goal's own residuals after the optimizer (0: off). Tail40
            pose streams: 0.28% of frames ended 1.01-1.17 tolerances off after 5000
            iterations, crawling at the edge of the workspace against a limit
            (``polish``).
        metric_every: Re-seed H from the exact Gauss-Newton metric (2 J^T W J + mu I)^-1
            every this many iterations (1: damped Gauss-Newton steps under the same
            line search, multi-pass and analyzer; 0: the article's BFGS, with the
            metric only at the start of each pass). None (the default) chooses by
            the chain (``metric_interval``): 1, which took ~10 iterations against
            ~37 on 7-DOF pose problems (bench/ik/), except 2 for chains of at least
            ``EVERY_SECOND_METRIC_DOF`` variables whose effectors have at least as
            many task rows as there are variables (many tips: g1's 9 effectors, 39
            rows on 29 variables). There the metric is the direct n x n inverse and
            costs several objective evaluations (g1: ~20 us against ~3 us), and
            BFGS's update in between is nearly as good a step; a redundant task
            (Tiago's three fingertips: 18 rows, 27 variables) needed more
            iterations at its p99 without the metric (bench/RESULTS.md, URDF files
            in the wild).
        metric_until: Re-seed only during a pass's first this many iterations, then
            BFGS updates (0: always). Near a singularity damped Gauss-Newton crawls
            (hundreds of iterations per frame, bench/ik/ part (c), iiwa); BFGS
            learns the missing curvature in a few steps. Streams use 8.
        continuity: What a ``track`` frame may do when its target is not reachable near
            the previous answer (``continuity.Continuity``): ``REACH`` solves it anyway,
            jumping if it must; ``SMOOTH`` keeps every variable within
            ``max_joint_step_rad`` of the previous answer and answers NOT_REACHED with
            the closest pose inside that box. ``solve`` ignores it.
        max_joint_step_rad: The per-frame step limit of ``SMOOTH``; under ``REACH`` a
            larger step is reported as a jump (``IKSolver.last_step``).
        policy: The analyzer's table.
    """

    position_tolerance_m: float = 1e-4
    rotation_tolerance_rad: float = 1e-3
    time_budget_us: float | None = 5000.0
    max_iter: int = 5000
    max_restarts: int = 126
    restart_radius_rad: float = math.inf
    full_restart_every: int = 8
    turn_restarts: bool = True
    split_limbs: bool = True
    inner_first: bool = True
    freeze_trunk: bool = True
    max_step_rad: float = 0.5
    posture_weight: float = 0.0
    limit_weight: float = 0.0
    limit_margin: float = 0.05
    stall_window: int = 5
    ftol: float | None = None
    gtol: float = 1e-14
    scale_initial_h: bool = True
    curvature: bool = False
    carry_hessian: bool = False
    metric_every: int | None = None
    metric_until: int = 0
    null_space_step_rad: float = 0.0
    damping: float = 0.0
    damping_redundant_only: bool = False
    damping_scale: float = 0.5
    polish_steps: int = 20
    global_fallback: bool = False
    continuity: Continuity = Continuity.REACH
    max_joint_step_rad: float = 0.1
    policy: AnalyzerPolicy = field(default_factory=AnalyzerPolicy.default)

    def __post_init__(self) -> None:
        try:
            # Frozen: the coercion of a plain string ("smooth") goes through object.
            object.__setattr__(self, "continuity", Continuity(self.continuity))
        except ValueError:
            known = ", ".join(c.value for c in Continuity)
            raise InvalidProblem(
                f"continuity must be one of {known}, got {self.continuity!r}"
            ) from None
        for name in (
            "position_tolerance_m",
            "rotation_tolerance_rad",
            "max_step_rad",
            "restart_radius_rad",
            "max_joint_step_rad",
        ):
            v = getattr(self, name)
            if not v > 0.0 or math.isnan(v):
                raise InvalidProblem(f"{name} must be > 0, got {v!r}")
        if self.ftol is not None and not (math.isfinite(self.ftol) and self.ftol >= 0.0):
            raise InvalidProblem(f"ftol must be finite and >= 0, got {self.ftol!r}")
        for name in (
            "posture_weight",
            "limit_weight",
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
        if (self.metric_every is not None and self.metric_every < 0) or self.metric_until < 0:
            raise InvalidProblem("metric_every and metric_until must be >= 0")
        if self.max_iter < 1 or self.max_restarts < 0 or self.stall_window < 0:
            raise InvalidProblem("max_iter must be >= 1, max_restarts and stall_window >= 0")
        if self.polish_steps < 0:
            raise InvalidProblem(f"polish_steps must be >= 0, got {self.polish_steps!r}")
        if self.full_restart_every < 0:
            raise InvalidProblem(
                f"full_restart_every must be >= 0, got {self.full_restart_every!r}"
            )

    def metric_interval(self, n_dof: int, task_rows: int) -> int:
        """``metric_every`` for a chain of ``n_dof`` variables whose effectors have
        ``task_rows`` rows in all (3 per position effector, 6 per pose or aim)."""
        if self.metric_every is not None:
            return self.metric_every
        return 2 if task_rows >= n_dof >= EVERY_SECOND_METRIC_DOF else 1

    def minimize_options(
        self, n_dof: int = 0, task_rows: int = 0, *, stream: bool = False
    ) -> MinimizeOptions:
        """The optimizer's options for a chain of ``n_dof`` variables and
        ``task_rows`` task rows (they choose ``metric_every`` when it is None), for a
        solve or, with ``stream``, a stream frame (``ftol``'s default)."""
        budget = None if self.time_budget_us is None else self.time_budget_us * 1e-6
        ftol = self.ftol
        if ftol is None:
            ftol = STREAM_FTOL if stream else SOLVE_FTOL
        return MinimizeOptions(
            gtol=self.gtol,
            ftol=ftol,
            stall_window=self.stall_window,
            f_goal=1.0,  # the goal measure is max(error / tolerance)
            max_step=self.max_step_rad,
            curvature=self.curvature,
            max_iter=self.max_iter,
            max_fev=20 * self.max_iter + 100,
            max_restarts=self.max_restarts,
            restart_radius=self.restart_radius_rad,
            full_restart_every=self.full_restart_every,
            turn_restarts=self.turn_restarts,
            time_budget_s=budget,
            scale_initial_h=self.scale_initial_h,
            max_passes=min(4 * (self.max_restarts + 1) + 8, 512),
            metric_every=self.metric_interval(n_dof, task_rows),
            metric_until=self.metric_until,
            final_metric=self.carry_hessian,
        )


# Stream defaults (the user can override every field): local restarts and a light pull
# away from the limits, so a frame that misses usually recovers without a visible jump;
# damped least squares near singularities and a null-space pull towards the rest pose
# against drift; and, when all that fails, one global re-solve (a visible jump) rather
# than a stream that misses every later frame (bench/ik/, iiwa stream 1: 306/599
# frames without it, 598/599 with it and one 4.3 rad jump). metric_until=8: near a
# singularity the damped Gauss-Newton steps crawled (p99 154 iterations per frame on
# the iiwa streams, 3-5 frames out of time); BFGS after 8 steps: p99 15, none missed.
# The damping floor only for redundant tasks: a 6-DOF arm's pose stream has no
# self-motion for it to steady, and with it the answer lagged behind the target at
# singularities (UR5 at 1e-5 m / 1e-4 rad: 33 of 40 streams within twice the
# reference's largest step; 39 without; bench/ik/ --parts c --streams 40).
# SMOOTH at 0.1 rad per frame (6 rad/s at 60 Hz): on bench/tracking.py's streams the
# REACH tracker stepped radians where the reference stepped hundredths (a redundant arm
# drifted along its self-motion into a limit or a singular pose, then the global
# fallback jumped); SMOOTH never steps more than the limit and answers NOT_REACHED on
# the frames it cannot follow (figures: bench/RESULTS.md, tracking without pops).
STREAM_DEFAULTS = IKOptions(
    continuity=Continuity.SMOOTH,
    max_joint_step_rad=0.1,
    restart_radius_rad=0.3,
    limit_weight=1e-3,
    limit_margin=0.02,
    null_space_step_rad=0.005,
    damping=1e-3,
    damping_redundant_only=True,
    global_fallback=True,
    metric_until=8,
    damping_scale=1.0,
    max_restarts=50,
)
