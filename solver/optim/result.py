"""What ``minimize`` returns: the best point, its pass log and its accepted steps."""

from __future__ import annotations

from dataclasses import dataclass

from ..arrays import Matrix, Vector
from .termination import Action, GoalStatus, PassStart, Termination


@dataclass(frozen=True, slots=True)
class PassRecord:
    """One pass of the solve and the analyzer's decision after it."""

    start: PassStart
    iterations: int
    termination: Termination
    f_start: float
    f_end: float
    goal: GoalStatus
    action: Action
    function_evals: int


@dataclass(frozen=True, slots=True)
class AcceptedStep:
    """One accepted line-search step (recorded with ``minimize(..., record_steps=True)``).

    Attributes:
        f_before, f_after: f at x and at x+.
        decrease: g(x) . (x+ - x), the predicted first-order change (< 0).
        step_length: lambda.
        bound_slack: min_i min(x+_i - lower_i, upper_i - x+_i); >= 0 inside the box.
    """

    f_before: float
    f_after: float
    decrease: float
    step_length: float
    bound_slack: float


@dataclass(frozen=True, slots=True)
class MinimizeResult:
    """Outcome of ``minimize``: the best point seen and how the solve went.

    Attributes:
        x: Best point, shape (n,), inside the bounds.
        f: f(x).
        projected_gradient_norm: inf-norm of P(x - g) - x at x.
        termination: How the last pass ended.
        goal: Whether f <= f_goal (NO_GOAL when none was set).
        iterations: Accepted steps over all passes.
        function_evals, gradient_evals: Evaluations (finite differences count f calls).
        passes, restarts, skipped_updates: Pass count, random restarts, BFGS updates skipped.
        pass_log: One record per pass, in order.
        elapsed_us: Wall time of the compiled solve, microseconds.
        inverse_hessian: Final H, shape (n, n), to carry curvature into a next solve.
        steps: Accepted steps, in order, when recorded (else empty).
    """

    x: Vector
    f: float
    projected_gradient_norm: float
    termination: Termination
    goal: GoalStatus
    iterations: int
    function_evals: int
    gradient_evals: int
    passes: int
    restarts: int
    skipped_updates: int
    pass_log: tuple[PassRecord, ...]
    elapsed_us: float
    inverse_hessian: Matrix
    steps: tuple[AcceptedStep, ...] = ()
