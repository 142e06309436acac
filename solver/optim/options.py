"""The optimizer's settings: ``MinimizeOptions`` and the gradient source."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidProblem

# Dennis & Schnabel's default step tolerance, machine eps^(2/3).
_STEPTOL = float(np.finfo(np.float64).eps) ** (2.0 / 3.0)


class GradientMode(enum.StrEnum):
    """Where the gradient comes from."""

    ANALYTIC = "analytic"  # the objective fills g itself
    FORWARD = "forward"  # forward differences, step sqrt(eps) * max(|x_i|, 1)
    CENTRAL = "central"  # central differences, step eps^(1/3) * max(|x_i|, 1)


@dataclass(frozen=True, slots=True, kw_only=True)
class MinimizeOptions:
    """Settings of the multi-pass bound-constrained BFGS.

    Attributes:
        gtol: Stop a pass when the projected gradient's inf-norm is at most this.
        xtol: Stop a pass when an accepted step is at most this, relative to
            max(|x_i|, 1) in each component (Dennis & Schnabel's steptol).
        line_search_min_step: The line search gives up (LINE_SEARCH_FAILED) when
            lambda * max_i |d_i| / max(|x_i|, 1) falls below this.
        ftol: Relative improvement of f below which an iteration counts as stalled.
        stall_window: K, stalled iterations in a row that end a pass (STALLED, the
            multi-pass trigger). 0 disables the trigger (single pass).
        f_goal: Goal value; a pass ends with GOAL_REACHED at f <= f_goal and the
            analyzer knows whether the goal was met. None: plain minimization.
        max_step: Cap on max_i |d_i| of a search direction (same unit as x).
        armijo_c1: Sufficient-decrease constant (alpha in the article, 1e-4).
        curvature: Add the article's directional-derivative (curvature) condition.
        curvature_c2: Its constant: accept when g(x+).d >= c2 g(x).d.
        max_iter: Iterations shared by all passes and restarts; never extended.
        max_fev: Function evaluations shared likewise (finite differences count).
        gradient: Analytic or finite differences.
        max_restarts: Random restarts the analyzer may order.
        restart_radius: Random restarts sample the box intersected with x0 +- this
            (same unit as x); inf samples the whole box. A side that stays
            infinite uses x0 +- 10 max(|x0_i|, 1).
        full_restart_every: With an objective that says which variables are settled
            (its ``restart_keep_fn``, see ``register_objective``), a restart keeps
            their values at the best point and re-draws the others (a partial
            restart, ``restart``), except every this many restarts, which re-draw
            every variable (1: all restarts do, as without such an objective; 0:
            only those where nothing is settled).
        turn_restarts: With an objective that says which variables are periodic
            (its ``restart_period_fn``), the first restart from each new best point
            turns the unsettled periodic variables that a bound stops the other way
            round (``restart.turn_values``) instead of drawing a random point.
        time_budget_s: Wall-clock budget of the whole solve; None for no limit.
        scale_initial_h: Scale H0 = I by y.s / y.y after the first step of a pass
            (Nocedal & Wright eq. 6.20); off by default, as in the article.
        skip_update_eps: Skip the BFGS update unless y.s > eps * |s| |y|.
        max_passes: Upper bound on passes (also the pass log's length).
        metric_every: With an objective that supplies a metric (the IK's
            Gauss-Newton matrix), re-seed H from it every this many iterations
            instead of the BFGS update; 0 uses it only at the start of each pass.
        metric_until: Re-seed only during a pass's first this many iterations,
            then let BFGS updates refine H (0: no limit). Damped Gauss-Newton
            converges linearly, at rate mu / (sigma^2 + mu), along a direction the
            model barely moves (near a singularity): hundreds of iterations, where
            BFGS learns that curvature from a few steps.
        final_metric: Also re-seed H at the point that meets the goal. Off, the
            last step's metric is skipped (the solve ends there, one metric per
            solve saved); on for a caller that starts its next solve from this H.
    """

    gtol: float = 1e-8
    xtol: float = _STEPTOL
    line_search_min_step: float = _STEPTOL
    ftol: float = 1e-8
    stall_window: int = 5
    f_goal: float | None = None
    max_step: float = math.inf
    armijo_c1: float = 1e-4
    curvature: bool = False
    curvature_c2: float = 0.9
    max_iter: int = 1000
    max_fev: int = 100_000
    gradient: GradientMode = GradientMode.ANALYTIC
    max_restarts: int = 0
    restart_radius: float = math.inf
    full_restart_every: int = 1
    turn_restarts: bool = True
    time_budget_s: float | None = None
    scale_initial_h: bool = False
    skip_update_eps: float = 1e-10
    max_passes: int = 64
    metric_every: int = 0
    metric_until: int = 0
    final_metric: bool = False

    def __post_init__(self) -> None:
        if not 0.0 < self.armijo_c1 < 0.5:
            raise InvalidProblem(f"armijo_c1 must be in (0, 0.5), got {self.armijo_c1!r}")
        if not self.armijo_c1 < self.curvature_c2 < 1.0:
            raise InvalidProblem(
                f"curvature_c2 must be in (armijo_c1, 1), got {self.curvature_c2!r}"
            )
        for name in ("gtol", "xtol", "line_search_min_step", "ftol", "skip_update_eps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise InvalidProblem(f"{name} must be finite and >= 0, got {value!r}")
        if not self.max_step > 0.0:
            raise InvalidProblem(f"max_step must be > 0, got {self.max_step!r}")
        if not self.restart_radius > 0.0:
            raise InvalidProblem(f"restart_radius must be > 0, got {self.restart_radius!r}")
        if self.f_goal is not None and math.isnan(self.f_goal):
            raise InvalidProblem("f_goal must not be NaN")
        if self.time_budget_s is not None and not self.time_budget_s >= 0.0:
            raise InvalidProblem(f"time_budget_s must be >= 0, got {self.time_budget_s!r}")
        for name in ("max_iter", "max_fev", "max_passes"):
            if getattr(self, name) < 1:
                raise InvalidProblem(f"{name} must be >= 1, got {getattr(self, name)!r}")
        for name in (
            "stall_window",
            "max_restarts",
            "full_restart_every",
            "metric_every",
            "metric_until",
        ):
            if getattr(self, name) < 0:
                raise InvalidProblem(f"{name} must be >= 0, got {getattr(self, name)!r}")
