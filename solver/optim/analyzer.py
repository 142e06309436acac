"""The analyzer: after every pass, an explicit policy table decides what happens next.

The article splits its optimizer into two parts, the algorithm and an analyzer of
its runs: each pass ends with a termination code, and empirical rules map the code
to the next move. Here the rules are data, a table from (termination, goal status)
to an ``Action``, so a caller can change them per kind of problem and every
decision is visible in the result's pass log.

Guards sit on top of the table, because the table alone could loop:
- RESET_H after a pass that began from H = I and did not lower f cannot help;
- with a goal that is still missed, a second RESET_H in a row (the reset pass
  itself stalled) is not helping either: a local minimum is crawled along, not left;
- RESET_H after a pass whose every H was the objective's metric, re-seeded at each
  iteration (``metric_every=1``, no ``metric_until``, no BFGS update in between: the
  IK's damped Gauss-Newton steps) would rebuild the very H the next iteration
  would have used, so the reset pass is the stalled pass again with its stall count
  cleared (on Tiago's three fingertips, 1000 targets, such reset passes met the goal
  5 times in 193 and took 17% of the iterations of the passes that missed it).
  All three escalate: to RESTART_RANDOM when the goal was missed and restarts remain,
  otherwise to STOP (ACCEPT when no goal was set);
- RESTART_RANDOM with no restarts left becomes STOP;
- a continuing action (reset, restart) when a budget is spent becomes STOP.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

from .._jit import jit_leaf
from . import codes as C
from .termination import Action, GoalStatus, Termination

PolicyTable = Mapping[tuple[Termination, GoalStatus], Action]

_A = Action
_G = GoalStatus
_T = Termination


def _rows(code: Termination, met: Action, missed: Action, no_goal: Action) -> PolicyTable:
    return {(code, _G.MET): met, (code, _G.MISSED): missed, (code, _G.NO_GOAL): no_goal}


# The default rules, one row per termination code (see the module docstring).
DEFAULT_TABLE: PolicyTable = MappingProxyType(
    {
        **_rows(_T.GOAL_REACHED, _A.ACCEPT, _A.ACCEPT, _A.ACCEPT),
        # A stationary point that misses the goal is a local minimum: reseed (TRAC-IK).
        **_rows(_T.GTOL, _A.ACCEPT, _A.RESTART_RANDOM, _A.ACCEPT),
        # A tiny step with a stale H can be H's fault: the article's reset first.
        **_rows(_T.STEP_SMALL, _A.ACCEPT, _A.RESET_H, _A.ACCEPT),
        # The multi-pass trigger itself.
        **_rows(_T.STALLED, _A.ACCEPT, _A.RESET_H, _A.RESET_H),
        # A bad direction from an inaccurate H: reset; the guard escalates if H was already I.
        **_rows(_T.LINE_SEARCH_FAILED, _A.ACCEPT, _A.RESET_H, _A.RESET_H),
        **_rows(_T.MAX_ITER, _A.ACCEPT, _A.STOP, _A.STOP),
        **_rows(_T.MAX_FEV, _A.ACCEPT, _A.STOP, _A.STOP),
        **_rows(_T.DEADLINE, _A.ACCEPT, _A.STOP, _A.STOP),
        **_rows(_T.NONFINITE, _A.STOP, _A.STOP, _A.STOP),
    }
)


def _single_pass_table() -> PolicyTable:
    """Every pass is final: the plain single-pass BFGS of the article's reference [1]."""
    table = {
        key: (_A.ACCEPT if key[1] is not _G.MISSED and key[0] is not _T.NONFINITE else _A.STOP)
        for key in DEFAULT_TABLE
    }
    return MappingProxyType(table)


def _multi_pass_table() -> PolicyTable:
    """Single pass plus the article's multi-pass H reset on stalls, no other rules."""
    table = dict(_single_pass_table())
    for goal in GoalStatus:
        if goal is not _G.MET:
            table[(_T.STALLED, goal)] = _A.RESET_H
    return MappingProxyType(table)


@dataclass(frozen=True, slots=True)
class AnalyzerPolicy:
    """A complete table from (termination, goal status) to the next action.

    Args:
        table: One action for every (termination, goal status) pair; missing pairs
            are an error so that no code falls through silently.
    """

    table: PolicyTable = field(default_factory=lambda: DEFAULT_TABLE)

    def __post_init__(self) -> None:
        missing = [(t, g) for t in Termination for g in GoalStatus if (t, g) not in self.table]
        if missing:
            raise ValueError(f"policy table lacks rows for {missing}")
        if any(self.table[(_T.NONFINITE, g)] is not _A.STOP for g in GoalStatus):
            raise ValueError("a non-finite objective must STOP: nothing can be trusted after it")

    @classmethod
    def default(cls) -> AnalyzerPolicy:
        return cls(DEFAULT_TABLE)

    @classmethod
    def single_pass(cls) -> AnalyzerPolicy:
        return cls(_single_pass_table())

    @classmethod
    def multi_pass(cls) -> AnalyzerPolicy:
        return cls(_multi_pass_table())

    def with_rule(self, code: Termination, goal: GoalStatus, action: Action) -> AnalyzerPolicy:
        table = dict(self.table)
        table[(code, goal)] = action
        return AnalyzerPolicy(MappingProxyType(table))

    def action(self, code: Termination, goal: GoalStatus) -> Action:
        return self.table[(code, goal)]

    def as_array(self) -> npt.NDArray[np.int64]:
        """The table as int64[n_codes, 3] for the compiled core (row = code, col = goal)."""
        out = np.empty((C.N_CODES, len(C.GOAL_STATUSES)), dtype=np.int64)
        for i, code in enumerate(C.TERMINATIONS):
            for j, goal in enumerate(C.GOAL_STATUSES):
                out[i, j] = C.ACTIONS.index(self.table[(code, goal)])
        return out


@jit_leaf
def decide(
    policy: npt.NDArray[np.int64],
    code: int,
    goal: int,
    restarts_left: int,
    budget_left: bool,
    pass_began_with_identity: bool,
    pass_improved: bool,
    pass_was_reset: bool,
    pass_kept_fresh_h: bool,
) -> int:
    """Next action (a ``codes`` action int) for a pass that ended with ``code``.

    Args:
        policy: int64[n_codes, 3] from ``AnalyzerPolicy.as_array``.
        code: The pass's termination (``codes`` int).
        goal: NO_GOAL, MET or MISSED (``codes`` int).
        restarts_left: Random restarts still allowed.
        budget_left: False once iterations, evaluations or time are spent.
        pass_began_with_identity: The pass started with a fresh H (I or the
            objective's metric: no curvature learnt yet; the name is the article's
            case, H = I).
        pass_improved: f at the end of the pass is below f at its start.
        pass_was_reset: The pass itself began with a RESET_H.
        pass_kept_fresh_h: Every H of the pass was the objective's metric,
            re-seeded at each iteration, and the next pass would do the same
            (``metric_every=1``, no ``metric_until`` phase a reset would begin
            again): a reset would rebuild the same H.
    """
    action = policy[code, goal]
    futile = pass_kept_fresh_h or (
        pass_began_with_identity and (not pass_improved or (goal == C.MISSED and pass_was_reset))
    )
    if action == C.RESET_H and futile:
        # A reset cannot change anything: H already was fresh and the pass went
        # nowhere, or the reset would hand the next pass the H this one used.
        if goal == C.MISSED and restarts_left > 0:
            action = C.RESTART_RANDOM
        elif goal == C.NO_GOAL:
            action = C.ACCEPT
        else:
            action = C.STOP
    if action == C.RESTART_RANDOM and restarts_left <= 0:
        action = C.STOP
    if (action == C.RESET_H or action == C.RESTART_RANDOM) and not budget_left:
        action = C.STOP
    return int(action)
