"""Partial restarts: a restart keeps the limbs already on target and re-draws the others
(``optim.restart``, the IK's shares in ``ik.settled``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from solver import (
    Action,
    Chain,
    IKOptions,
    IKSolver,
    InvalidProblem,
    MinimizeOptions,
    PassStart,
    Target,
    Termination,
    Transform,
    build_chain,
)
from solver.ik import pose_targets
from solver.ik.options import SOLVE_FTOL, STREAM_FTOL
from solver.ik.settled import settled_variables
from solver.model import EffectorMode
from solver.model.examples import panda_arm
from solver.model.forward import effector_poses
from solver.optim.restart import keep_values


def panda_limbs(count: int) -> Chain:
    """``count`` Panda arms on one base, side by side, each with its own pose effector:
    independent parts, as a quadruped's legs or a robot's arms are."""
    arm = panda_arm()
    joints = []
    effectors = []
    for k in range(count):
        rename = {link: f"limb{k}_{link}" for j in arm.joints for link in (j.parent, j.child)}
        rename[arm.joints[0].parent] = "base"
        for j in arm.joints:
            origin = j.origin
            if j.parent == arm.joints[0].parent:  # the limb's mount: 0.5 m apart
                origin = Transform(origin.translation + [0.0, 0.5 * k, 0.0], origin.rotation)
            joints.append(
                dataclasses.replace(
                    j,
                    name=f"limb{k}_{j.name}",
                    parent=rename[j.parent],
                    child=rename[j.child],
                    origin=origin,
                )
            )
        for e in arm.effectors:
            effectors.append(dataclasses.replace(e, name=f"limb{k}_{e.name}", link=rename[e.link]))
    return build_chain(joints, effectors)


def test_shares_count_the_effectors_on_target_a_variable_moves() -> None:
    chain = panda_limbs(2)
    limb1 = np.array([name.startswith("limb1_") for name in chain.dof_names])
    solver = IKSolver(chain)
    rng = np.random.default_rng(3)
    q_goal = rng.uniform(chain.lower, chain.upper)
    targets = pose_targets(chain, q_goal)
    data = solver.load_frame(targets, chain.mid_limits())
    # Limb 0 at its goal, limb 1 elsewhere: limb 0's variables are settled, limb 1's not.
    q = np.where(limb1, chain.mid_limits(), q_goal)
    keep = np.full(chain.n_dof, np.nan)
    kept = settled_variables(q, data, keep)
    assert kept == 7
    np.testing.assert_array_equal(keep, np.where(limb1, 0.0, 1.0))
    # Both limbs off target: nothing is settled (the restart re-draws everything).
    assert settled_variables(chain.mid_limits(), data, keep) == 0
    np.testing.assert_array_equal(keep, np.zeros(14))


def test_a_shared_variable_gets_the_share_of_its_effectors_on_target() -> None:
    chain = panda_arm()
    # A second effector on link 4: joints 1-4 move both, joints 5-7 only the flange.
    elbow = dataclasses.replace(chain.effectors[0], name="elbow", link="link4")
    chain = build_chain(list(chain.joints), [*chain.effectors, elbow])
    solver = IKSolver(chain)
    q_goal = np.random.default_rng(5).uniform(chain.lower, chain.upper)
    data = solver.load_frame(pose_targets(chain, q_goal), chain.mid_limits())
    q = q_goal.copy()
    q[6] = chain.lower[6] if q_goal[6] > 0.0 else chain.upper[6]  # the flange turns off target
    keep = np.full(chain.n_dof, np.nan)
    assert settled_variables(q, data, keep) == 4
    np.testing.assert_array_equal(keep, [0.5] * 4 + [0.0] * 3)


def test_keep_values_keeps_settled_or_wholly_settled_variables() -> None:
    keep = np.array([1.0, 0.5, 0.0])
    source = np.array([1.0, 2.0, 3.0])
    lo, hi = np.full(3, -5.0), np.full(3, 5.0)
    out = np.zeros(3)
    assert keep_values(keep, source, out, False, lo, hi) == 2
    np.testing.assert_array_equal(out, [1.0, 2.0, 0.0])
    out = np.zeros(3)
    assert keep_values(keep, source, out, True, lo, hi) == 1
    np.testing.assert_array_equal(out, [1.0, 0.0, 0.0])


def test_keep_values_keeps_nothing_when_it_would_keep_every_free_variable() -> None:
    """Keeping every free variable would start the restart at the best point: a pass
    spent on nothing. A frozen variable (lo == hi) does not count as one to re-draw."""
    source = np.array([1.0, 2.0, 3.0])
    lo, hi = np.array([-5.0, -5.0, 3.0]), np.array([5.0, 5.0, 3.0])
    out = np.zeros(3)
    assert keep_values(np.array([0.5, 0.5, 0.0]), source, out, False, lo, hi) == 0
    np.testing.assert_array_equal(out, [0.0, 0.0, 0.0])
    assert keep_values(np.zeros(3), source, out, False, lo, hi) == 0
    np.testing.assert_array_equal(out, [0.0, 0.0, 0.0])


def test_no_partial_restart_starts_at_the_best_point() -> None:
    """Two effectors on one link, one on target and one unreachable with it: every
    variable moves both, so every variable has a share. A restart that kept them all
    would begin where the best pass ended and do nothing (the review of the merge
    found three such passes in six restarts); now it re-draws instead."""
    chain = panda_arm()
    probe = dataclasses.replace(
        chain.effectors[0],
        name="probe",
        mode=EffectorMode.POSITION,
        tip_offset=np.array([0.0, 0.0, 0.05]),
        position_weight=1e-6,
    )
    chain = build_chain(list(chain.joints), [*chain.effectors, probe])
    q = np.random.default_rng(1).uniform(chain.lower, chain.upper)
    tool, tip = effector_poses(chain, q)
    targets = [
        Target(effector="tool", position=tool[:3, 3], rotation=tool[:3, :3]),
        Target(effector="probe", position=tip[:3, 3] + [0.0, 0.03, 0.0]),  # 3 cm off
    ]
    solver = IKSolver(chain, IKOptions(time_budget_us=None, max_restarts=6), seed=3)
    result = solver.solve(targets, q)
    restarts = (PassStart.RESTART_RANDOM, PassStart.RESTART_PARTIAL)
    assert sum(p.start in restarts for p in result.pass_log) == 6
    best = np.inf
    for p in result.pass_log:
        if p.start in restarts:
            assert p.f_start != best, result.pass_log
        best = min(best, p.f_end)


def _solved(chain: Chain, options: IKOptions, goals: np.ndarray) -> tuple[int, set[PassStart]]:
    solver = IKSolver(chain, options, seed=7)
    starts: set[PassStart] = set()
    solved = 0
    for q in goals:
        result = solver.solve(pose_targets(chain, q))
        solved += result.success
        starts |= {p.start for p in result.pass_log}
    return solved, starts


def test_partial_restarts_solve_targets_whole_box_restarts_miss() -> None:
    """Four independent 7-DOF limbs, at most 4 restarts per target, no time budget:
    re-drawing every limb after each miss lands all four at once far less often
    than re-drawing only the limbs still off target (turn restarts off: they help
    both kinds, test_turn_restarts.py)."""
    chain = panda_limbs(4)
    rng = np.random.default_rng(11)
    goals = rng.uniform(chain.lower, chain.upper, size=(80, chain.n_dof))
    # The limbs in one solve (split, each limb would restart on its own: ik.split).
    base = IKOptions(time_budget_us=None, max_restarts=4, turn_restarts=False, split_limbs=False)
    whole, whole_starts = _solved(chain, dataclasses.replace(base, full_restart_every=1), goals)
    partial, partial_starts = _solved(chain, base, goals)
    assert PassStart.RESTART_PARTIAL not in whole_starts
    assert PassStart.RESTART_PARTIAL in partial_starts
    assert partial >= whole + 10, (whole, partial)  # measured: 59 against 73


def test_one_effector_restarts_as_before() -> None:
    """With one effector nothing is ever settled before it is solved: the default
    options give the same answers as restarts that always re-draw everything."""
    chain = panda_arm()
    rng = np.random.default_rng(2)
    goals = rng.uniform(chain.lower, chain.upper, size=(30, chain.n_dof))
    base = IKOptions(time_budget_us=None, max_restarts=20)
    answers = []
    for options in (base, dataclasses.replace(base, full_restart_every=1)):
        solver = IKSolver(chain, options, seed=3)
        answers.append([solver.solve(pose_targets(chain, q)).q for q in goals])
    np.testing.assert_array_equal(answers[0], answers[1])


def test_the_answer_meets_every_target() -> None:
    chain = panda_limbs(2)
    q_goal = np.random.default_rng(8).uniform(chain.lower, chain.upper)
    targets = pose_targets(chain, q_goal)
    result = IKSolver(chain, IKOptions(time_budget_us=None)).solve(targets)
    assert result.success
    for t, pose in zip(targets, effector_poses(chain, result.q), strict=True):
        assert isinstance(t, Target) and t.position is not None and t.rotation is not None
        assert np.linalg.norm(pose[:3, 3] - t.position) <= 1e-4
        assert np.linalg.norm(pose[:3, :3] - t.rotation) <= 2e-3


@pytest.mark.parametrize("make", [IKOptions, MinimizeOptions])
def test_full_restart_every_must_not_be_negative(make: type) -> None:
    with pytest.raises(InvalidProblem, match="full_restart_every"):
        make(full_restart_every=-1)


def test_a_stalled_gauss_newton_pass_restarts_instead_of_resetting() -> None:
    # A target out of reach: every pass misses. With the metric re-seeded at every
    # iteration (the panda's default) a reset would rebuild the pass's own H, so the
    # analyzer restarts; with BFGS updates (metric_every=0), or a metric phase a reset
    # would begin again (metric_until=8, the streams'), the article's reset comes first.
    chain = panda_arm()
    effector = chain.effectors[0].name
    far = Target(effector=effector, position=np.array([2.0, 0.0, 0.5]), rotation=np.eye(3))
    resettable = (Termination.STALLED, Termination.LINE_SEARCH_FAILED, Termination.STEP_SMALL)
    logs = []
    for changes in ({}, {"metric_every": 0}, {"metric_until": 8}):
        options = IKOptions(time_budget_us=None, max_restarts=6, **changes)  # type: ignore[arg-type]
        result = IKSolver(chain, options).solve([far])
        assert not result.success
        logs.append(result.pass_log)
    gauss_newton, bfgs, metric_phase = logs
    assert any(p.termination in resettable for p in gauss_newton)
    assert all(p.start is not PassStart.RESET_H for p in gauss_newton)
    assert all(
        p.action in (Action.RESTART_RANDOM, Action.STOP)
        for p in gauss_newton
        if p.termination in resettable
    )
    assert any(p.start is PassStart.RESET_H for p in bfgs)
    assert any(p.start is PassStart.RESET_H for p in metric_phase)


def test_a_solve_stalls_at_3_percent_and_a_stream_frame_at_0_1() -> None:
    opts = IKOptions()
    assert opts.ftol is None
    assert opts.minimize_options(7, 6).ftol == SOLVE_FTOL == 3e-2
    assert opts.minimize_options(7, 6, stream=True).ftol == STREAM_FTOL == 1e-3
    fixed = IKOptions(ftol=0.2)
    assert fixed.minimize_options(stream=True).ftol == fixed.minimize_options().ftol == 0.2
    with pytest.raises(InvalidProblem, match="ftol"):
        IKOptions(ftol=-1.0)
    # Through the solver: from the same pose, towards a target out of reach, a solve's
    # first pass gives up while a tracked frame's goes on crawling.
    chain = panda_arm()
    effector = chain.effectors[0].name
    far = Target(effector=effector, position=np.array([2.0, 0.0, 0.5]), rotation=np.eye(3))
    once = IKOptions(time_budget_us=None, max_restarts=0)
    solver = IKSolver(chain, once)
    start = chain.mid_limits()
    solved = solver.solve([far], seed=start)
    solver.set_pose(start)
    tracked = solver.track([far])
    assert solved.pass_log[0].termination is Termination.STALLED
    assert tracked.pass_log[0].start is PassStart.INITIAL
    assert solved.pass_log[0].iterations < tracked.pass_log[0].iterations
