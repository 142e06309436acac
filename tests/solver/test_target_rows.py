"""TargetRows: a frame's plain targets as packed rows, tracked without a Target each.

Whatever a solver does with the rows must be what it does with the Targets they stand
for: the same answers, bit for bit, frame after frame (the stream's usual frame copies
the row; any other frame reads the rows as Targets).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from solver import InvalidProblem
from solver.ik import (
    GIVEN_POSITION,
    GIVEN_ROTATION,
    STREAM_DEFAULTS,
    IKResult,
    IKSolver,
    Target,
    TargetRows,
    pose_targets,
)
from solver.model import Chain
from solver.model.examples import panda_arm, two_arm_torso


def rows_of(targets: list[Target]) -> TargetRows:
    """The TargetRows standing for plain ``targets``."""
    return TargetRows(
        tuple(t.effector for t in targets),
        np.array([t.packed for t in targets]),
        tuple(t.given for t in targets),
    )


def same_target(a: Target, b: Target) -> bool:
    """The same effector, parts, numbers (bit for bit), weights and pole."""
    return (
        a.effector == b.effector
        and a.given == b.given
        and a.packed.tobytes() == b.packed.tobytes()
        and (a.position_weight, a.rotation_weight, a.pole, a.plain)
        == (b.position_weight, b.rotation_weight, b.pole, b.plain)
    )


def same_answer(a: IKResult, b: IKResult) -> bool:
    return (
        a.q.tobytes() == b.q.tobytes()
        and (a.status, a.termination, a.iterations, a.function_evals, a.restarts)
        == (b.status, b.termination, b.iterations, b.function_evals, b.restarts)
        and a.raw_errors.tobytes() == b.raw_errors.tobytes()
    )


def test_rows_read_as_the_targets_they_stand_for() -> None:
    chain = two_arm_torso()
    targets = pose_targets(chain, chain.mid_limits() + 0.1)
    rows = rows_of(targets)
    assert len(rows) == len(targets) == 2
    for got, want in zip(rows, targets, strict=True):  # iteration builds each Target
        assert same_target(got, want)
        assert not np.shares_memory(got.packed, rows.rows)  # a copy
    assert same_target(rows[-1], targets[-1])
    (first,) = rows[0:1]
    assert same_target(first, targets[0])
    assert not rows.rows.flags.writeable  # kept, not copied, and frozen
    with pytest.raises(IndexError):
        rows[2]


def test_bad_rows_are_refused() -> None:
    with pytest.raises(InvalidProblem, match="15 float64"):
        TargetRows(("tool",), np.zeros((1, 14)), (GIVEN_POSITION,))
    with pytest.raises(InvalidProblem, match="15 float64"):
        TargetRows(("tool",), np.zeros((1, 15), dtype=np.float32), (GIVEN_POSITION,))
    with pytest.raises(InvalidProblem, match="15 float64"):
        TargetRows(("tool", "hand"), np.zeros((1, 15)), (GIVEN_POSITION,) * 2)
    with pytest.raises(InvalidProblem, match="15 float64"):
        TargetRows(("tool",), np.zeros((1, 15)), ())
    base = np.zeros((2, 15))
    with pytest.raises(InvalidProblem, match="of their own"):
        TargetRows(("tool",), base[:1], (GIVEN_POSITION,))  # a view: base could change it


def _stream(chain: Chain, n: int) -> list[list[Target]]:
    """n frames of pose targets along a small swing of every joint."""
    rng = np.random.default_rng(3)
    start = chain.mid_limits()
    swing = rng.uniform(-0.4, 0.4, chain.n_dof)
    return [pose_targets(chain, start + swing * np.sin(k / 5)) for k in range(n)]


@pytest.mark.parametrize("make", [panda_arm, two_arm_torso], ids=["panda", "two_arms"])
def test_a_stream_of_rows_is_answered_as_its_targets(make: Callable[[], Chain]) -> None:
    chain = make()
    frames = _stream(chain, 30)
    # The effector set changes now and then (the stream's usual frame and the others).
    frames[10] = frames[10][:1]
    frames[20] = [  # a pose target without its position: loaded the general way
        Target(effector=t.effector, rotation=t.rotation) if t.given & GIVEN_ROTATION else t
        for t in frames[20]
    ]
    by_targets = IKSolver(chain, STREAM_DEFAULTS, seed=1)
    by_rows = IKSolver(chain, STREAM_DEFAULTS, seed=1)
    for targets in frames:
        a = by_targets.track(targets)
        b = by_rows.track(rows_of(targets))
        assert same_answer(a, b)
        assert by_targets.last_step == by_rows.last_step
