"""The Levenberg-Marquardt polish after the optimizer (solver/ik/polish.py): a frame
that ends a few tolerances short of its goal is finished; one far from it, or held by
SMOOTH's step box, is not moved beyond what the frame allows (issue 22)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from solver.ik import STREAM_DEFAULTS, Continuity, IKOptions, IKSolver, IKStatus, Target
from solver.ik.kinematics import MISC_LIMIT, MISC_POSTURE
from solver.ik.polish import POLISH_WITHIN
from solver.model import Chain
from solver.model.examples import humanoid_arm, two_arm_torso
from solver.model.forward import effector_poses
from solver.model.layout import ED_WP, ED_WR
from solver.optim import Termination

from .helpers import folding_arm

TOL_P = 1e-5
TOL_R = 1e-4


def pose_target(chain: Chain, q: np.ndarray) -> list[Target]:
    p = effector_poses(chain, q)[0]
    return [Target(effector=chain.effectors[0].name, position=p[:3, 3], rotation=p[:3, :3])]


def short_solve(polish_steps: int) -> IKOptions:
    """One heavily damped iteration: the optimizer stops a few tolerances short."""
    return IKOptions(
        position_tolerance_m=TOL_P,
        rotation_tolerance_rad=TOL_R,
        max_iter=1,
        max_restarts=0,
        damping=10.0,
        polish_steps=polish_steps,
    )


def near_miss() -> tuple[Chain, list[Target], np.ndarray]:
    """The humanoid arm, a pose target and a seed a few tolerances from it."""
    chain = humanoid_arm()
    rng = np.random.default_rng(7)
    lo, hi = chain.lower, chain.upper
    goal = lo + (hi - lo) * rng.uniform(0.3, 0.7, chain.n_dof)
    seed = goal + rng.normal(0.0, 4e-5, chain.n_dof)
    return chain, pose_target(chain, goal), seed


def test_a_solve_stopped_a_few_tolerances_short_is_polished_to_its_goal() -> None:
    chain, targets, seed = near_miss()
    short = IKSolver(chain, short_solve(0)).solve(targets, seed)
    # The case is what it claims to be: the optimizer alone ends short, within reach.
    assert short.status is IKStatus.BUDGET_EXHAUSTED
    measure = max(short.max_position_error_m / TOL_P, short.max_rotation_error_rad / TOL_R)
    assert 1.0 < measure <= POLISH_WITHIN

    done = IKSolver(chain, short_solve(20)).solve(targets, seed)
    assert done.status is IKStatus.SOLVED
    assert done.termination is Termination.GOAL_REACHED
    assert done.max_position_error_m <= TOL_P
    assert done.max_rotation_error_rad <= TOL_R
    # Its steps are counted: one iteration of the optimizer, then the polish's.
    assert done.iterations > short.iterations == 1
    # The optimizer's own record is the same run's: the article's pass log untouched.
    assert [p.start for p in done.pass_log] == [p.start for p in short.pass_log]
    assert np.abs(done.q - short.q).max() < 1e-2


def test_a_target_out_of_reach_costs_no_polish() -> None:
    chain, targets, seed = near_miss()
    far = [replace(targets[0], position=targets[0].position + np.array([5.0, 0.0, 0.0]))]
    plain = IKSolver(chain, short_solve(0)).solve(far, seed)
    polished = IKSolver(chain, short_solve(20)).solve(far, seed)
    assert plain.max_position_error_m / TOL_P > POLISH_WITHIN
    assert polished.iterations == plain.iterations
    np.testing.assert_array_equal(polished.q, plain.q)


def test_polish_steps_zero_turns_it_off_and_negative_is_refused() -> None:
    chain, targets, seed = near_miss()
    off = IKSolver(chain, short_solve(0)).solve(targets, seed)
    assert off.termination is Termination.MAX_ITER
    with pytest.raises(ValueError, match="polish_steps"):
        IKOptions(polish_steps=-1)


def test_the_polish_stays_inside_smooths_step_box() -> None:
    # The target needs the shoulder 0.1 rad + 2e-5 rad away: 4e-5 m (4 tolerances)
    # beyond what SMOOTH's 0.1 rad per frame allows. The polish must not cross the box.
    chain = folding_arm()
    options = replace(
        STREAM_DEFAULTS,
        position_tolerance_m=TOL_P,
        rotation_tolerance_rad=TOL_R,
        time_budget_us=None,
        continuity=Continuity.SMOOTH,
        max_joint_step_rad=0.1,
    )
    q0 = np.array([0.2, 1.0])
    solver = IKSolver(chain, options)
    solver.set_pose(q0)
    solver.restore(solver.stream_state()._replace(anchored=True))  # not a stream's first
    goal = effector_poses(chain, q0 + np.array([0.1 + 2e-5, 0.0]))[0][:3, 3]
    r = solver.track([Target(effector="hand", position=goal)])
    assert np.abs(r.q - q0).max() <= 0.1 + 1e-9
    assert not solver.last_step.jumped
    assert r.status is not IKStatus.SOLVED
    assert TOL_P < r.max_position_error_m < 2 * 2e-5 * 2.0  # the closest continuous pose


def test_a_frame_the_polish_cannot_finish_keeps_the_optimizers_answer() -> None:
    # Just out of reach (5 tolerances past the arm stretched straight, its elbow at the
    # stop), from that pose: the polish's steps cannot meet the goal, so the answer is
    # the optimizer's, bit for bit; and among near misses on the humanoid arm, each
    # answer is either solved or the optimizer's.
    chain = folding_arm()
    beyond = [Target(effector="hand", position=np.array([2.0 + 5 * TOL_P, 0.0, 0.0]))]
    seed = np.array([0.0, 0.0])
    a = IKSolver(chain, short_solve(0)).solve(beyond, seed)
    b = IKSolver(chain, short_solve(20)).solve(beyond, seed)
    assert 1.0 < a.max_position_error_m / TOL_P <= POLISH_WITHIN  # the polish ran
    assert b.iterations > a.iterations
    np.testing.assert_array_equal(b.q, a.q)
    assert b.termination is a.termination

    arm = humanoid_arm()
    rng = np.random.default_rng(3)
    lo, hi = arm.lower, arm.upper
    solved = 0
    for _ in range(40):
        goal = lo + (hi - lo) * rng.uniform(0.02, 0.98, arm.n_dof)
        near = np.clip(goal + rng.normal(0.0, 1e-4, arm.n_dof), lo, hi)
        targets = pose_target(arm, goal)
        plain = IKSolver(arm, short_solve(0)).solve(targets, near)
        polished = IKSolver(arm, short_solve(20)).solve(targets, near)
        if polished.success and not plain.success:
            solved += 1
        else:
            np.testing.assert_array_equal(polished.q, plain.q)
    assert solved > 0


def test_no_time_left_no_polish() -> None:
    # A zero budget: the optimizer stops on its deadline, and the polish, which runs
    # within the time the solve left, does not start.
    chain, targets, seed = near_miss()
    options = replace(short_solve(20), time_budget_us=0.0, max_iter=100)
    r = IKSolver(chain, options).solve(targets, seed)
    assert r.termination is Termination.DEADLINE
    assert not r.success


@pytest.mark.parametrize("posture_weight", [0.0, 1e-3])
def test_the_polish_leaves_the_weights_and_preferences_as_they_were(
    posture_weight: float,
) -> None:
    # It swaps in the tolerance weights and turns the posture and limit preferences off
    # while it runs: the solver's arrays must hold the client's again afterwards. Two
    # effectors sharing a torso, one a pose and one a position target (solved whole,
    # not limb by limb, so that these are the arrays the solve used).
    chain = two_arm_torso()
    rng = np.random.default_rng(5)
    options = replace(
        short_solve(20), posture_weight=posture_weight, limit_weight=1e-3, split_limbs=False
    )
    solver = IKSolver(chain, options)
    ni, nd, ei, ed, dd, misc = solver._data
    polished = 0
    for _ in range(20):
        goal = chain.lower + (chain.upper - chain.lower) * rng.uniform(0.2, 0.8, chain.n_dof)
        seed = goal + rng.normal(0.0, 4e-5, chain.n_dof)
        poses = effector_poses(chain, goal)
        left, right = chain.effectors[0].name, chain.effectors[1].name
        targets = [
            Target(effector=left, position=poses[0][:3, 3], rotation=poses[0][:3, :3]),
            Target(effector=right, position=poses[1][:3, 3]),
        ]
        solver.solve(targets, seed)  # loads the targets: the weights as the client set them
        weights = ed[:, [ED_WP, ED_WR]].copy()
        preferences = misc[[MISC_POSTURE, MISC_LIMIT]].copy()
        r = solver.solve(targets, seed)
        polished += r.termination is Termination.GOAL_REACHED and r.iterations > 1
        np.testing.assert_array_equal(ed[:, [ED_WP, ED_WR]], weights)
        np.testing.assert_array_equal(misc[[MISC_POSTURE, MISC_LIMIT]], preferences)
    assert polished > 0
