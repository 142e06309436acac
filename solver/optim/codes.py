"""Integer mirrors of the enums in ``termination`` for the compiled core, and the
layout of the option vectors and the pass log it reads and writes.

numba folds module-level ints into constants; the order here must match the
tuples below, which the Python layer uses to turn ints back into enums.
"""

from __future__ import annotations

import enum

from .termination import Action, GoalStatus, PassStart, Termination

GOAL_REACHED = 0
GTOL = 1
STEP_SMALL = 2
STALLED = 3
LINE_SEARCH_FAILED = 4
MAX_ITER = 5
MAX_FEV = 6
DEADLINE = 7
NONFINITE = 8
RUNNING = -1  # internal only: the pass has not ended

TERMINATIONS: tuple[Termination, ...] = (
    Termination.GOAL_REACHED,
    Termination.GTOL,
    Termination.STEP_SMALL,
    Termination.STALLED,
    Termination.LINE_SEARCH_FAILED,
    Termination.MAX_ITER,
    Termination.MAX_FEV,
    Termination.DEADLINE,
    Termination.NONFINITE,
)
N_CODES = len(TERMINATIONS)

ACCEPT = 0
RESET_H = 1
RESTART_RANDOM = 2
STOP = 3
ACTIONS: tuple[Action, ...] = (Action.ACCEPT, Action.RESET_H, Action.RESTART_RANDOM, Action.STOP)

NO_GOAL = 0
MET = 1
MISSED = 2
GOAL_STATUSES: tuple[GoalStatus, ...] = (GoalStatus.NO_GOAL, GoalStatus.MET, GoalStatus.MISSED)

START_INITIAL = 0
START_RESET_H = 1
START_RESTART = 2
START_RESTART_PARTIAL = 3
START_RESTART_TURN = 4
PASS_STARTS: tuple[PassStart, ...] = (
    PassStart.INITIAL,
    PassStart.RESET_H,
    PassStart.RESTART_RANDOM,
    PassStart.RESTART_PARTIAL,
    PassStart.RESTART_TURN,
)


class LineSearchStatus(enum.IntEnum):
    """How a line search ended (``line_search.line_search``); never leaves the core."""

    ACCEPTED = 0  # a step with sufficient decrease (and curvature, if asked) was found
    STEP_TOO_SMALL = 1  # lambda fell below its minimum: the pass ends LINE_SEARCH_FAILED
    BUDGET_SPENT = 2  # the evaluation budget ran out: the pass ends MAX_FEV


# The same values as plain ints, which numba folds into the compiled code.
LS_ACCEPTED = int(LineSearchStatus.ACCEPTED)
LS_STEP_TOO_SMALL = int(LineSearchStatus.STEP_TOO_SMALL)
LS_BUDGET_SPENT = int(LineSearchStatus.BUDGET_SPENT)


class MetricKind(enum.IntEnum):
    """What an objective's metric wrote into H (``objective.call_metric``); never
    leaves the core."""

    NONE = 0  # no metric here: H is as it was (or, after a failed factorisation, not)
    INVERSE = 1  # H itself: the inverse of the metric's matrix A
    FACTOR = 2  # A's lower Cholesky factor L (A = L L^T) in H's lower triangle


METRIC_NONE = int(MetricKind.NONE)
METRIC_INVERSE = int(MetricKind.INVERSE)
METRIC_FACTOR = int(MetricKind.FACTOR)


GRAD_ANALYTIC = 0
GRAD_FORWARD = 1
GRAD_CENTRAL = 2

# Layout of the float and int option vectors handed to the core (one array each,
# because every extra argument of a numba dispatch costs type-checking time).
F_GTOL = 0
F_XTOL = 1
F_FTOL = 2
F_F_GOAL = 3
F_MAX_STEP = 4
F_C1 = 5
F_C2 = 6
F_STEPTOL = 7
F_BUDGET = 8  # seconds from the start of the compiled solve; inf for none
F_RESTART_RADIUS = 9
F_CURVATURE_EPS = 10
N_FOPT = 11

I_MAX_ITER = 0
I_MAX_FEV = 1
I_STALL_WINDOW = 2
I_GRAD_MODE = 3
I_CURVATURE = 4
I_MAX_RESTARTS = 5
I_SEED = 6  # in: restart seed; out: the generator state, as the seed that continues it
I_HAS_GOAL = 7
I_SCALE_H0 = 8
I_MAX_PASSES = 9
I_METRIC_EVERY = 10
I_METRIC_UNTIL = 11  # 0: no limit
I_FINAL_METRIC = 12  # 1: re-seed H at the answer too (the caller carries H to its next solve)
# Every this many restarts re-draws every variable (1: all of them do; 0: only those
# where the objective keeps nothing), see ``restart``.
I_FULL_RESTART_EVERY = 13
# 1: a restart from a new best point first turns its periodic variables pressed against
# a bound the other way round (``restart.turn_values``); 0: never.
I_TURN_RESTARTS = 14
N_IOPT = 15

# Columns of the pass log the core fills.
L_START = 0
L_ITERS = 1
L_CODE = 2
L_F_START = 3
L_F_END = 4
L_GOAL = 5
L_ACTION = 6
L_NFEV = 7
N_LOG = 8
