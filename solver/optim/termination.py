"""Termination codes of a pass and of a whole solve, and the analyzer's actions.

The string values are the JSON contract of the service (stable, documented); the
compiled core works with the small integers in ``solver.optim.codes`` and the public
API converts them back to these enums, so no magic int ever leaves ``solver``.
"""

from __future__ import annotations

import enum


class Termination(enum.StrEnum):
    """Why a pass (and, for the final pass, the whole solve) ended."""

    GOAL_REACHED = "goal_reached"
    GTOL = "gtol"
    STEP_SMALL = "step_small"
    STALLED = "stalled"
    LINE_SEARCH_FAILED = "line_search_failed"
    MAX_ITER = "max_iter"
    MAX_FEV = "max_fev"
    DEADLINE = "deadline"
    NONFINITE = "nonfinite"

    @property
    def message(self) -> str:
        return TERMINATION_MESSAGES[self]

    @property
    def converged(self) -> bool:
        """The optimizer believes it sits at a (local) minimum or met the goal."""
        return self in (Termination.GOAL_REACHED, Termination.GTOL, Termination.STEP_SMALL)

    @property
    def budget_exhausted(self) -> bool:
        """A resource ran out; no further pass can start."""
        return self in (Termination.MAX_ITER, Termination.MAX_FEV, Termination.DEADLINE)


# One place for the meanings (websockets' CLOSE_CODE_EXPLANATIONS, scipy's _status_message).
TERMINATION_MESSAGES: dict[Termination, str] = {
    Termination.GOAL_REACHED: "f fell to or below the goal value f_goal",
    Termination.GTOL: "projected gradient inf-norm fell to or below gtol (a stationary point)",
    Termination.STEP_SMALL: "the accepted step was below xtol relative to x (no further progress)",
    Termination.STALLED: (
        "f improved by less than ftol over stall_window consecutive iterations "
        "(the multi-pass trigger: the analyzer normally resets H and continues)"
    ),
    Termination.LINE_SEARCH_FAILED: (
        "the backtracking line search reached its minimum step length without sufficient decrease"
    ),
    Termination.MAX_ITER: "the iteration budget (shared by all passes) is spent",
    Termination.MAX_FEV: "the function-evaluation budget is spent",
    Termination.DEADLINE: "the time budget ran out; the best point so far is returned",
    Termination.NONFINITE: "the objective or its gradient returned NaN or infinity",
}


class Action(enum.StrEnum):
    """What the analyzer does after a pass ends."""

    ACCEPT = "accept"  # the pass's result is the answer
    RESET_H = "reset_h"  # H <- I, recompute the gradient, continue from the current point
    RESTART_RANDOM = "restart_random"  # new pass from a seeded random point inside the bounds
    STOP = "stop"  # give up; return the best point seen so far


class GoalStatus(enum.StrEnum):
    """Whether the pass met the caller's goal f <= f_goal."""

    NO_GOAL = "no_goal"  # the caller set no goal (plain minimization)
    MET = "met"
    MISSED = "missed"


class PassStart(enum.StrEnum):
    """How a pass began."""

    INITIAL = "initial"
    RESET_H = "reset_h"
    RESTART_RANDOM = "restart_random"
    # A restart that kept the variables the objective called settled (``restart``).
    RESTART_PARTIAL = "restart_partial"
    # A restart from the best point with its periodic variables that a bound stops
    # turned the other way round, to (or towards) the same angle (``restart``).
    RESTART_TURN = "restart_turn"
