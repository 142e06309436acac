"""The analyzer: one test per policy-table row, the guards, and the table's validation."""

from __future__ import annotations

import numpy as np
import pytest

from solver import Action, AnalyzerPolicy, GoalStatus, MinimizeOptions, Termination, minimize
from solver.optim import codes as C
from solver.optim.analyzer import DEFAULT_TABLE, decide

from .objectives import NONCONVEX, make_data, toy_objective

ROWS = sorted(DEFAULT_TABLE.items(), key=lambda kv: (kv[0][0].value, kv[0][1].value))


def run_decide(
    code: Termination,
    goal: GoalStatus,
    *,
    restarts_left: int = 3,
    budget_left: bool = True,
    fresh: bool = False,
    improved: bool = True,
    was_reset: bool = False,
    kept_fresh: bool = False,
    policy: AnalyzerPolicy | None = None,
) -> Action:
    table = (policy or AnalyzerPolicy.default()).as_array()
    out = decide(
        table,
        C.TERMINATIONS.index(code),
        C.GOAL_STATUSES.index(goal),
        restarts_left,
        budget_left,
        fresh,
        improved,
        was_reset,
        kept_fresh,
    )
    return C.ACTIONS[int(out)]


@pytest.mark.parametrize(
    ("key", "action"), ROWS, ids=[f"{k[0].value}-{k[1].value}" for k, _ in ROWS]
)
def test_each_default_row_is_applied_as_written(
    key: tuple[Termination, GoalStatus], action: Action
) -> None:
    code, goal = key
    assert run_decide(code, goal) is action


def test_default_rows_have_the_documented_meaning() -> None:
    t = DEFAULT_TABLE
    assert t[(Termination.GTOL, GoalStatus.MISSED)] is Action.RESTART_RANDOM  # local minimum
    assert t[(Termination.STALLED, GoalStatus.NO_GOAL)] is Action.RESET_H  # multi-pass
    assert t[(Termination.LINE_SEARCH_FAILED, GoalStatus.MISSED)] is Action.RESET_H
    assert all(t[(c, GoalStatus.MET)] in (Action.ACCEPT, Action.STOP) for c in Termination)
    assert all(t[(Termination.NONFINITE, g)] is Action.STOP for g in GoalStatus)


def test_reset_after_a_fresh_pass_without_progress_escalates() -> None:
    missed = run_decide(
        Termination.LINE_SEARCH_FAILED, GoalStatus.MISSED, fresh=True, improved=False
    )
    assert missed is Action.RESTART_RANDOM
    no_goal = run_decide(
        Termination.LINE_SEARCH_FAILED, GoalStatus.NO_GOAL, fresh=True, improved=False
    )
    assert no_goal is Action.ACCEPT
    none_left = run_decide(
        Termination.STALLED, GoalStatus.MISSED, fresh=True, improved=False, restarts_left=0
    )
    assert none_left is Action.STOP


def test_second_reset_in_a_row_with_goal_missed_escalates_to_restart() -> None:
    assert (
        run_decide(Termination.STALLED, GoalStatus.MISSED, fresh=True, was_reset=True)
        is Action.RESTART_RANDOM
    )
    # Without a goal the article's multi-pass keeps resetting while f improves.
    assert (
        run_decide(Termination.STALLED, GoalStatus.NO_GOAL, fresh=True, was_reset=True)
        is Action.RESET_H
    )


def test_reset_after_a_pass_that_kept_its_fresh_h_escalates() -> None:
    # Every H of the pass was the objective's metric (or I): a reset rebuilds it, so
    # the reset pass would be the same descent with its stall count cleared.
    for code in (Termination.STALLED, Termination.LINE_SEARCH_FAILED, Termination.STEP_SMALL):
        assert run_decide(code, GoalStatus.MISSED, fresh=True, kept_fresh=True) is (
            Action.RESTART_RANDOM
        )
        assert run_decide(code, GoalStatus.NO_GOAL, fresh=True, kept_fresh=True) is (Action.ACCEPT)
        assert (
            run_decide(code, GoalStatus.MISSED, fresh=True, kept_fresh=True, restarts_left=0)
            is Action.STOP
        )
        # The same pass after BFGS updates: the article's reset first.
        assert run_decide(code, GoalStatus.MISSED, fresh=True) is Action.RESET_H


def test_restart_without_restarts_left_stops() -> None:
    assert run_decide(Termination.GTOL, GoalStatus.MISSED, restarts_left=0) is Action.STOP


def test_no_continuing_action_once_the_budget_is_spent() -> None:
    assert run_decide(Termination.STALLED, GoalStatus.NO_GOAL, budget_left=False) is Action.STOP
    assert run_decide(Termination.GTOL, GoalStatus.MISSED, budget_left=False) is Action.STOP


def test_tables_must_be_complete_and_stop_on_nonfinite() -> None:
    table = dict(DEFAULT_TABLE)
    del table[(Termination.GTOL, GoalStatus.MET)]
    with pytest.raises(ValueError, match="lacks rows"):
        AnalyzerPolicy(table)
    with pytest.raises(ValueError, match="non-finite"):
        AnalyzerPolicy.default().with_rule(Termination.NONFINITE, GoalStatus.MISSED, Action.RESET_H)


def test_single_and_multi_pass_tables() -> None:
    single = AnalyzerPolicy.single_pass()
    multi = AnalyzerPolicy.multi_pass()
    assert all(a in (Action.ACCEPT, Action.STOP) for a in single.table.values())
    assert multi.action(Termination.STALLED, GoalStatus.NO_GOAL) is Action.RESET_H
    assert multi.action(Termination.GTOL, GoalStatus.MISSED) is Action.STOP


def test_custom_rule_changes_behaviour_end_to_end() -> None:
    # A non-convex function whose local minima miss the goal: the default table
    # restarts; a table that stops on GTOL does not.
    data = make_data(NONCONVEX, np.zeros(3), 0.1 * np.eye(3))
    opts = MinimizeOptions(f_goal=-100.0, max_restarts=4)
    box = (np.full(3, -2.0), np.full(3, 2.0))
    restarting = minimize(toy_objective, np.zeros(3), bounds=box, data=data, options=opts)
    stopping_policy = AnalyzerPolicy.default().with_rule(
        Termination.GTOL, GoalStatus.MISSED, Action.STOP
    )
    stopping = minimize(
        toy_objective, np.zeros(3), bounds=box, data=data, options=opts, policy=stopping_policy
    )
    assert restarting.restarts == 4
    assert stopping.restarts == 0
    assert stopping.pass_log[-1].action is Action.STOP
    assert [p.action for p in restarting.pass_log[:-1]] == [Action.RESTART_RANDOM] * 4
