"""Planning a clip as a whole (solver/path.py): smooth where tracking pops, never worse."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from solver import (
    Effector,
    EffectorMode,
    IKSolver,
    InvalidProblem,
    Target,
    build_chain,
)
from solver.ik import STREAM_DEFAULTS, Continuity, IKOptions, IKResult, pose_targets
from solver.model.examples import bolt, humanoid_arm, panda_arm, two_arm_torso
from solver.model.forward import effector_poses
from solver.path import PathOptions, PlannedPath, keyframes, plan_path
from solver.path.kernels import dp_step, frame_nodes
from solver.path.keyframes import repair_windows, target_jumps
from solver.path.programme import Planner

from .helpers import CHAINS, joint_stream

# The benchmark's tracking settings, without a time budget: a loaded CI machine must
# not change which answers a test sees. REACH: the tracker the plans are compared with
# is the one plan_path runs (a SMOOTH tracker does not jump; it lags instead).
STREAM = dataclasses.replace(
    STREAM_DEFAULTS,
    position_tolerance_m=1e-5,
    rotation_tolerance_rad=1e-4,
    time_budget_us=None,
    continuity=Continuity.REACH,
)


def largest_step(start: np.ndarray, qs: np.ndarray) -> float:
    return float(np.abs(np.diff(np.vstack([start, qs]), axis=0)).max())


def tracked_from(  # type: ignore[no-untyped-def]
    chain, start: np.ndarray, frames: list[list[Target]], options: IKOptions = STREAM
) -> list[IKResult]:
    """Frame by frame from ``start``, as a session streams them."""
    tracker = IKSolver(chain, options)
    tracker.set_pose(start)
    return [tracker.track(t, options=options) for t in frames]


def planned_from(  # type: ignore[no-untyped-def]
    chain,
    start: np.ndarray,
    frames: list[list[Target]],
    options: IKOptions = STREAM,
    path_options: PathOptions | None = None,
) -> PlannedPath:
    planner = IKSolver(chain, options)
    planner.set_pose(start)
    return plan_path(planner, frames, path_options=path_options)


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    c = (np.trace(a @ b.T) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, c)))


def assert_reaches(chain, q: np.ndarray, targets: list[Target]) -> None:  # type: ignore[no-untyped-def]
    """Independently of the solver's report: FK of q against the targets, and limits."""
    assert np.all(q >= chain.lower - 1e-12) and np.all(q <= chain.upper + 1e-12)
    poses = effector_poses(chain, q)
    for t in targets:
        pose = poses[chain.effector_names.index(t.effector)]
        if t.position is not None:
            assert np.linalg.norm(pose[:3, 3] - t.position) <= 1e-5 * (1 + 1e-9)
        if t.rotation is not None:
            assert rotation_angle(pose[:3, :3], t.rotation) <= 1e-4 * (1 + 1e-6)


@pytest.mark.parametrize("key_every", [1, 5], ids=["every-frame", "keyframes"])
def test_plan_crosses_smoothly_where_tracking_pops(key_every: int) -> None:
    # A Panda stream whose reference crosses the shoulder pole (joint 2 through 0):
    # the tracker, on another point of the self-motion, steps 0.11 rad (6.4x the
    # reference's) near frame 78. (Before a frame in the limit band was solved on the
    # exact task, solver/ik/frame.py, its global fallback jumped by radians there; no
    # 90-frame stream of seeds 0-39 pops by 10x any more.)
    chain = panda_arm()
    path = joint_stream(chain, 4, 90)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    frames = [pose_targets(chain, q) for q in path]
    tracked = np.array([r.q for r in tracked_from(chain, path[0], frames)])
    assert largest_step(path[0], tracked) > 5 * ref

    plan = planned_from(chain, path[0], frames, path_options=PathOptions(key_every=key_every))
    assert plan.success
    assert plan.largest_step <= 2 * ref
    assert plan.largest_step == pytest.approx(largest_step(path[0], plan.q), abs=0.0)
    assert plan.tracked_largest_step == pytest.approx(largest_step(path[0], tracked), rel=1e-12)
    for q, targets in zip(plan.q, frames, strict=True):
        assert_reaches(chain, q, targets)


def _locked_panda():  # type: ignore[no-untyped-def]
    """The Panda with its last joint locked: 6 free joints under a 6-D pose (no
    self-motion: the plan chooses between separate answers)."""
    chain = panda_arm()
    joints = list(chain.joints)
    last = max(i for i, j in enumerate(joints) if j.lower)
    joints[last] = dataclasses.replace(joints[last], lower=(0.3,), upper=(0.3,))
    return build_chain(joints, list(chain.effectors))


@pytest.mark.parametrize(
    "make, seeds",
    [
        (lambda: panda_arm(), (0, 1, 2)),
        (_locked_panda, (0, 1)),
        (lambda: panda_arm(EffectorMode.POSITION), (0, 1)),
        (lambda: humanoid_arm(), (0, 1)),
    ],
    ids=["panda-pose", "panda-locked-joint", "panda-position", "humanoid"],
)
def test_plan_is_never_worse_than_tracking(make, seeds) -> None:  # type: ignore[no-untyped-def]
    chain = make()
    for seed in seeds:
        path = joint_stream(chain, seed, 60)
        frames = [pose_targets(chain, q) for q in path]
        tracked = tracked_from(chain, path[0], frames)
        plan = planned_from(chain, path[0], frames)
        for r, t, targets in zip(plan.results, tracked, frames, strict=True):
            assert r.success or not t.success
            if r.success:
                assert_reaches(chain, r.q, targets)
        if all(t.success for t in tracked):
            assert plan.largest_step <= largest_step(path[0], np.array([t.q for t in tracked]))


def test_plan_results_are_judged_as_solve_judges_them() -> None:
    chain = panda_arm()
    path = joint_stream(chain, 4, 90)
    frames = [pose_targets(chain, q) for q in path]
    plan = planned_from(chain, path[0], frames)
    checker = IKSolver(chain, STREAM)
    for r, targets in zip(plan.results, frames, strict=True):
        assert r.effectors == checker.errors_at(r.q, targets)
        assert r.success == all(e.within_tolerance for e in r.effectors)


def test_a_frame_nothing_reaches_keeps_the_closest_pose() -> None:
    chain = panda_arm()
    path = joint_stream(chain, 1, 30)
    frames = [pose_targets(chain, q) for q in path]
    near = frames[10][0]
    far = Target(effector=near.effector, position=np.array([3.0, 0.0, 0.5]), rotation=near.rotation)
    frames[10] = [far]
    plan = planned_from(chain, path[0], frames)
    assert not plan.results[10].success
    assert not plan.success
    assert all(r.success for i, r in enumerate(plan.results) if i != 10)
    # The closest pose: the arm reaches towards the target (about 0.9 m from the base).
    tip = effector_poses(chain, plan.results[10].q)[0][:3, 3]
    assert np.linalg.norm(tip - far.position) < np.linalg.norm(far.position) - 0.5


def test_plan_starts_from_the_current_pose_and_ends_at_the_last_answer() -> None:
    chain = panda_arm()
    path = joint_stream(chain, 2, 20)
    frames = [pose_targets(chain, q) for q in path]
    solver = IKSolver(chain, STREAM)
    start = path[0] + 0.2  # off the first target: the first step is measured from here
    solver.set_pose(start)
    plan = plan_path(solver, frames)
    first = float(np.abs(plan.results[0].q - start).max())
    assert first >= 0.05
    assert plan.largest_step == largest_step(start, plan.q)
    assert np.array_equal(solver.q, plan.results[-1].q)
    after = solver.track(frames[-1], options=STREAM)
    assert after.success
    # Warm-started from the plan's last answer: only the rest pull moves it.
    assert np.abs(after.q - plan.results[-1].q).max() <= STREAM.null_space_step_rad + 1e-6


def test_plan_is_reproducible() -> None:
    chain = panda_arm()
    path = joint_stream(chain, 0, 40)
    frames = [pose_targets(chain, q) for q in path]
    plans = []
    for _ in range(2):
        solver = IKSolver(chain, STREAM)
        solver.set_pose(path[0])
        plans.append(plan_path(solver, frames).q)
    assert np.array_equal(plans[0], plans[1])


def test_plan_of_a_single_frame_is_the_nearest_answer() -> None:
    chain = panda_arm()
    q0 = chain.mid_limits() + 0.1
    solver = IKSolver(chain, STREAM)
    solver.set_pose(q0)
    target = pose_targets(chain, q0 + 0.05)
    plan = plan_path(solver, [target])
    assert plan.success and len(plan.results) == 1
    assert_reaches(chain, plan.q[0], target)
    # Never further than the tracker's answer, and q0 + 0.05 is an answer 0.05 away
    # in every joint: the plan's is within a walk's spacing of that distance.
    assert plan.largest_step <= plan.tracked_largest_step
    assert plan.largest_step <= 0.05 + PathOptions().spacing_rad


def test_plan_of_a_chain_without_variables() -> None:
    solver = IKSolver(bolt(), STREAM)
    frames = [
        [Target(effector="tip", position=np.array([0.0, 0.0, 1.0]))],
        [Target(effector="tip", position=np.array([0.0, 0.5, 1.0]))],
    ]
    plan = plan_path(solver, frames)
    assert [r.success for r in plan.results] == [True, False]
    assert plan.largest_step == 0.0 and plan.q.shape == (2, 0)


def test_plan_reaches_frames_the_tracker_misses() -> None:
    # A tracker allowed one iteration per frame and no restarts misses frames of a
    # fast clip; the planner's own projections reach them.
    chain = panda_arm()
    path = joint_stream(chain, 1, 300)[::10]
    frames = [pose_targets(chain, q) for q in path]
    weak = dataclasses.replace(STREAM, max_iter=1, max_restarts=0, global_fallback=False)
    solver = IKSolver(chain, weak)
    solver.set_pose(path[0])
    plan = plan_path(solver, frames)
    missed = sum(not r.success for r in tracked_from(chain, path[0], frames, weak))
    assert missed >= 5
    assert plan.success
    for q, targets in zip(plan.q, frames, strict=True):
        assert_reaches(chain, q, targets)


def test_a_rejected_plan_keeps_the_carried_state() -> None:
    chain = panda_arm()
    path = joint_stream(chain, 0, 10)
    frames = [pose_targets(chain, q) for q in path]
    carry = dataclasses.replace(STREAM, carry_hessian=True)
    solver = IKSolver(chain, carry)
    solver.set_pose(path[0])
    solver.track(frames[0])
    h, q = solver.stream_state().inverse_hessian, solver.q.copy()
    assert h is not None
    good = frames[5][0]
    bad = Target(effector=good.effector, position=good.position, rotation=2.0 * good.rotation)
    with pytest.raises(InvalidProblem, match="orthonormal"):
        plan_path(solver, frames[:5] + [[bad]] + frames[6:])
    assert solver.stream_state().inverse_hessian is h and np.array_equal(solver.q, q)


def test_a_plan_anchors_the_stream_only_if_a_frame_is_solved() -> None:
    # A smooth stream keeps to its step limit once it has an answer to stay near
    # (IKSolver.track); a clip none of whose frames reaches its target is none.
    chain = panda_arm()
    path = joint_stream(chain, 0, 4)
    frames = [pose_targets(chain, q) for q in path]
    near = frames[0][0]
    far = [[dataclasses.replace(near, position=np.array([3.0, 0.0, 0.5]))]] * 2
    behind = [[dataclasses.replace(near, position=np.array([0.0, 0.0, -0.4]))]] * 2
    for clip, anchored in ((frames, True), (behind, False), (far, True)):
        solver = IKSolver(chain, STREAM)
        solver.set_pose(path[0])
        plan = plan_path(solver, clip)
        assert solver.stream_state().anchored is anchored, (clip is frames, plan.success)
        # A rejected clip keeps the state it found (here: not anchored, no misses).
        if clip is behind:
            assert solver.stream_state().misses == 2
    fresh = IKSolver(chain, STREAM)
    fresh.set_pose(path[0])
    bad = Target(effector=near.effector, position=near.position, rotation=2.0 * near.rotation)
    with pytest.raises(InvalidProblem):
        plan_path(fresh, [[bad]])
    assert fresh.stream_state().anchored is False and fresh.stream_state().misses == 0


def test_plan_of_no_frames_changes_nothing() -> None:
    chain = panda_arm()
    solver = IKSolver(chain, STREAM)
    before = solver.q.copy()
    plan = plan_path(solver, [])
    assert isinstance(plan, PlannedPath)
    assert plan.results == () and plan.largest_step == 0.0 and plan.success
    assert np.array_equal(solver.q, before)


def test_plan_rejects_bad_targets_as_solve_does_and_stays_usable() -> None:
    chain = panda_arm()
    path = joint_stream(chain, 0, 10)
    frames = [pose_targets(chain, q) for q in path]
    good = frames[5][0]
    broken = Target(
        effector=good.effector, position=np.array([np.nan, 0.0, 0.5]), rotation=good.rotation
    )
    solver = IKSolver(chain, STREAM)
    solver.set_pose(path[0])
    with pytest.raises(InvalidProblem, match="finite"):
        plan_path(solver, frames[:5] + [[broken]] + frames[6:])
    assert np.array_equal(solver.q, path[0])  # a rejected clip changes nothing
    assert plan_path(solver, frames).success


def test_plan_with_two_effectors() -> None:
    chain = two_arm_torso()
    path = joint_stream(chain, 3, 40)
    frames = [pose_targets(chain, q) for q in path]
    tracked = tracked_from(chain, path[0], frames)
    plan = planned_from(chain, path[0], frames)
    assert plan.success
    for r, targets in zip(plan.results, frames, strict=True):
        assert_reaches(chain, r.q, targets)
    if all(t.success for t in tracked):
        assert plan.largest_step <= plan.tracked_largest_step


def test_a_stretch_the_keyframes_pass_badly_is_planned_again() -> None:
    # Keyframes 15 frames apart on the pole-crossing stream: the straight lines between
    # them cut across the self-motion near the pole, and the frames filled in step
    # several times the reference's; the repair plans those stretches frame by frame.
    # 93 frames: six keyframe intervals of 15 or 16 frames.
    chain = panda_arm()
    path = joint_stream(chain, 4, 93)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    frames = [pose_targets(chain, q) for q in path]
    coarse = PathOptions(key_every=15, smoothing_sweeps=0)
    unrepaired = planned_from(
        chain, path[0], frames, path_options=dataclasses.replace(coarse, repair_ratio=1e9)
    )
    repaired = planned_from(chain, path[0], frames, path_options=coarse)
    assert unrepaired.success and repaired.success
    assert unrepaired.largest_step > 2.5 * ref
    assert repaired.largest_step <= 1.5 * ref
    assert repaired.nodes > 10 * unrepaired.nodes  # the dense stretches' answers
    for q, targets in zip(repaired.q, frames, strict=True):
        assert_reaches(chain, q, targets)


@pytest.mark.parametrize(
    "make", [panda_arm, _locked_panda], ids=["self-motion-walked", "no-self-motion"]
)
def test_keyframes_cut_the_work_and_keep_the_guarantees(make) -> None:  # type: ignore[no-untyped-def]
    chain = make()
    path = joint_stream(chain, 0, 120)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    frames = [pose_targets(chain, q) for q in path]
    dense = planned_from(chain, path[0], frames, path_options=PathOptions(key_every=1))
    keyed = planned_from(chain, path[0], frames)
    assert keyed.success and dense.success
    assert keyed.nodes < dense.nodes / 2
    assert keyed.largest_step <= min(1.5 * ref, keyed.tracked_largest_step)
    for q, targets in zip(keyed.q, frames, strict=True):
        assert_reaches(chain, q, targets)


def test_a_repair_that_would_lengthen_a_step_is_not_kept() -> None:
    # The reference path itself is exact answers and the smoothest path there is;
    # re-planning frames 10-29 of it at 0.01 rad comes out rougher (0.0207 against
    # 0.0178 rad, the joins included), so the repair keeps the path as it was.
    chain = panda_arm()
    path = joint_stream(chain, 0, 40)
    frames = [pose_targets(chain, q) for q in path]
    solver = IKSolver(chain, STREAM)
    solver.set_pose(path[0])
    tracked, boxes = [], []
    for targets in frames:
        tracked.append(solver.track(targets, options=STREAM))
        boxes.append((chain.lower, chain.upper, solver.free_mask()))
    planner = Planner(solver, frames, STREAM, PathOptions(), tracked, boxes)
    rougher, _ = planner.dense(
        path[9],
        range(10, 30),
        spacing=0.01,
        cap=8192,
        walk=[True] * 20,
        along=path[10:30],
        end=path[29],
    )
    window = np.vstack([path[10:30], path[30:31]])
    assert largest_step(path[9], np.vstack([rougher, path[30:31]])) > largest_step(path[9], window)
    repaired = path.copy()
    keyframes.repair(planner, path[0], repaired, 9, 29, True)
    np.testing.assert_array_equal(repaired, path)


def test_repair_windows_widen_and_merge() -> None:
    assert repair_windows([3], 1, 10) == [(2, 4)]
    assert repair_windows([0, 9], 1, 10) == [(0, 1), (8, 9)]  # clipped to the clip
    assert repair_windows([2, 4], 1, 10) == [(1, 5)]  # overlapping
    assert repair_windows([2, 5], 1, 10) == [(1, 6)]  # touching: one window
    assert repair_windows([2, 6], 1, 10) == [(1, 3), (5, 7)]
    assert repair_windows([4], 3, 6) == [(1, 5)]


def test_the_work_budget_bounds_a_plan_and_keeps_its_guarantees() -> None:
    # Every frame planned densely: the budget's bound is simple to state.
    chain = panda_arm()
    path = joint_stream(chain, 4, 90)
    frames = [pose_targets(chain, q) for q in path]
    answers = 2000
    solver = IKSolver(chain, STREAM)
    solver.set_pose(path[0])
    dense = PathOptions(key_every=1)
    small = plan_path(
        solver, frames, path_options=dataclasses.replace(dense, max_work=answers * 7**3)
    )
    solver.set_pose(path[0])
    full = plan_path(solver, frames, path_options=dense)
    # Each frame may still keep its anchors (25) and the tracker's answer.
    assert small.nodes <= answers + 90 * 26 < full.nodes
    assert small.success
    tracked = largest_step(path[0], np.array([r.q for r in tracked_from(chain, path[0], frames)]))
    assert small.tracked_largest_step == pytest.approx(tracked, rel=1e-12)
    assert small.largest_step <= tracked


def test_the_work_budget_bounds_a_keyframe_plan_and_keeps_its_guarantees() -> None:
    chain = panda_arm()
    path = joint_stream(chain, 4, 90)
    frames = [pose_targets(chain, q) for q in path]
    coarse = PathOptions(key_every=15)  # with repairs, as above
    full = planned_from(chain, path[0], frames, path_options=coarse)
    small = planned_from(
        chain, path[0], frames, path_options=dataclasses.replace(coarse, max_work=500 * 7**3)
    )
    # Beyond the budget, each frame planned keeps its anchors (26): the keyframes
    # (6), the repaired stretches (at most twice the clip) and one answer per frame
    # filled in.
    assert small.nodes <= 500 + 26 * (6 + 2 * 90) + 90 < full.nodes
    assert small.success
    assert small.largest_step <= small.tracked_largest_step


@pytest.mark.parametrize("gone", [(29,), (29, 30)], ids=["one-frame", "two-frames"])
@pytest.mark.parametrize(
    "key_every", [1, 5, 15], ids=["every-frame", "keyframes", "keyframes-repaired"]
)
def test_frames_out_of_reach_do_not_spoil_the_rest_of_the_plan(
    key_every: int, gone: tuple[int, ...]
) -> None:
    # The pole-crossing stream with frames out of reach: they keep the tracker's
    # closest pose, and every step but those into and out of them stays within 2x the
    # reference's: the plan is ranked in segments between them (counted, the jumps
    # would be the largest steps whatever the rest did), and smoothing leaves their
    # neighbours alone. Also with keyframes 15 apart, whose straight lines cut
    # corners at the pole (frame ~78).
    chain = panda_arm()
    path = joint_stream(chain, 4, 90)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    frames = out_of_reach([pose_targets(chain, q) for q in path], gone)
    plan = planned_from(chain, path[0], frames, path_options=PathOptions(key_every=key_every))
    assert [k for k, r in enumerate(plan.results) if not r.success] == list(gone)
    steps = np.abs(np.diff(np.vstack([path[0], plan.q]), axis=0)).max(axis=1)
    jumps = {*gone, max(gone) + 1}
    assert max(steps[k] for k in range(90) if k not in jumps) <= 2 * ref
    for k, (q, targets) in enumerate(zip(plan.q, frames, strict=True)):
        if k not in gone:
            assert_reaches(chain, q, targets)


def out_of_reach(frames: list[list[Target]], gone: tuple[int, ...]) -> list[list[Target]]:
    """``frames`` with the first target of frames ``gone`` moved 5 m away."""
    frames = list(frames)
    for k in gone:
        first = frames[k][0]
        frames[k] = [dataclasses.replace(first, position=first.position + 5.0), *frames[k][1:]]
    return frames


def repairs_made(monkeypatch, chain, path, frames, key_every, start=None):  # type: ignore[no-untyped-def]
    """Plan ``frames`` from ``start`` (default path[0]) and return the stretches the
    keyframe plan re-planned, as (first, last) of ``keyframes.repair``, and the plan."""
    calls: list[tuple[int, int]] = []
    repair = keyframes.repair

    def spy(planner, start, path, first, last, walk):  # type: ignore[no-untyped-def]
        calls.append((first, last))
        repair(planner, start, path, first, last, walk)

    monkeypatch.setattr(keyframes, "repair", spy)
    start = path[0] if start is None else start
    plan = planned_from(chain, start, frames, path_options=PathOptions(key_every=key_every))
    return calls, plan


@pytest.mark.parametrize("gone", [(29,), (40,), (29, 30, 31, 32, 33)])
def test_a_frame_a_dense_plan_leaves_unreached_is_not_retried(  # type: ignore[no-untyped-def]
    monkeypatch, gone
) -> None:
    # Nothing reaches a target 5 m away. Its stretch (widened by one keyframe on each
    # side) is planned densely once; retrying it over 3 and 9 keyframes, and then as
    # a dense plan of the whole clip, would only spend work (about 6x this plan's).
    # Five frames in a row: the targets jump into and out of them (cuts, no longer
    # judged after the first round anyway), but not between them.
    chain = panda_arm()
    path = joint_stream(chain, 4, 90)
    frames = out_of_reach([pose_targets(chain, q) for q in path], gone)
    calls, plan = repairs_made(monkeypatch, chain, path, frames, 5)
    assert len(calls) == 1
    first, last = calls[0]
    assert first < min(gone) and max(gone) <= last and last - first <= 25
    assert [k for k, r in enumerate(plan.results) if not r.success] == list(gone)


def test_stretches_past_half_the_clip_are_planned_as_one(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # Keyframes 15 apart: the pole-crossing stretch (frames 15-59) and the interval
    # of the unreached keyframe 29, each widened by one keyframe, cover more than half
    # of the seven intervals (frame 0 is one): one dense plan of the whole clip
    # replaces them.
    chain = panda_arm()
    path = joint_stream(chain, 4, 90)
    frames = out_of_reach([pose_targets(chain, q) for q in path], (29,))
    calls, _ = repairs_made(monkeypatch, chain, path, frames, 15)
    assert calls == [(-1, 89)]


def test_an_unreached_keyframe_does_not_set_the_pace(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # 240 frames, keyframes 15 apart, keyframe 224 out of reach: the jump to it is
    # not the keyframes' pace (it would hide every other stretch's corner-cutting).
    # So the pole crossing near frame 78, which the straight lines between keyframes
    # pass at 1.6x the reference's step, is still planned again, to within 1.5x.
    chain = panda_arm()
    path = joint_stream(chain, 4, 240)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    frames = out_of_reach([pose_targets(chain, q) for q in path], (224,))
    calls, plan = repairs_made(monkeypatch, chain, path, frames, 15)
    assert calls == [(14, 59), (194, 239)]
    steps = np.abs(np.diff(np.vstack([path[0], plan.q]), axis=0)).max(axis=1)
    assert max(steps[k] for k in range(240) if k not in (224, 225)) <= 1.5 * ref


@pytest.mark.parametrize("seed, frames_in_clip", [(4, 90), (0, 120)])
def test_a_clip_that_starts_away_from_the_pose_is_planned_as_one_that_does_not(
    seed: int, frames_in_clip: int
) -> None:
    # A session's pose is often not the clip's first frame (a new session sits at
    # mid-limits). The step there is whatever it must be, so it neither sets the
    # keyframes' pace nor makes the first stretch "bad" (it was repaired over 1, 3 and
    # 9 keyframes: 20-30x the answers, and the frames before the first keyframe took
    # the jump in four steps of up to 1.9x the reference's).
    chain = panda_arm()
    path = joint_stream(chain, seed, frames_in_clip)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    frames = [pose_targets(chain, q) for q in path]
    on = planned_from(chain, path[0], frames)
    away = np.clip(path[0] + 0.5, chain.lower, chain.upper)
    off = planned_from(chain, away, frames)
    assert on.success and off.success
    assert off.nodes < 1.5 * on.nodes
    steps = np.abs(np.diff(np.vstack([away, off.q]), axis=0)).max(axis=1)
    assert steps[0] > 0.4  # the jump to the clip, in one step
    assert steps[1:].max() <= 1.5 * ref
    for q, targets in zip(off.q, frames, strict=True):
        assert_reaches(chain, q, targets)


def test_the_jump_to_a_clip_does_not_set_the_pace(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # From 0.5 rad away, keyframes 10 apart on the pole-crossing stream: counted in
    # the keyframes' pace, the jump to the first frame (about 0.5 rad over one
    # keyframe interval) would hide the corner the keyframes cut near the pole
    # (3.1x the reference's step, unrepaired); left out, that stretch is planned again.
    chain = panda_arm()
    path = joint_stream(chain, 4, 120)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    frames = [pose_targets(chain, q) for q in path]
    away = np.clip(path[0] + 0.5, chain.lower, chain.upper)
    calls, plan = repairs_made(monkeypatch, chain, path, frames, 10, start=away)
    assert calls
    assert plan.success
    assert largest_step(plan.q[0], plan.q[1:]) <= 1.5 * ref


def cut_clip(chain, frames_in_clip: int, cut: float):  # type: ignore[no-untyped-def]
    """The smooth stream of seed 0 with every joint turned by ``cut`` from the middle
    frame on (a cut in an animation: the targets jump there), and its frames."""
    path = joint_stream(chain, 0, frames_in_clip)
    path[frames_in_clip // 2 :] += cut
    path = np.clip(path, chain.lower, chain.upper)
    return path, [pose_targets(chain, q) for q in path]


def test_target_jumps_are_the_cuts_of_a_clip() -> None:
    chain = panda_arm()
    _, smooth = cut_clip(chain, 120, 0.0)
    assert target_jumps(smooth, 10) == set()
    _, cut = cut_clip(chain, 120, 0.15)
    assert target_jumps(cut, 10) == {60}
    # Moving between holds is not jumping: a clip that starts from rest, a gesture
    # between two holds, poses held for three frames each (the median over all the
    # frames around would be 0, every move a jump).
    still = [smooth[0]] * 30 + smooth[:30]
    assert target_jumps(still, 10) == set()
    gesture = [smooth[0]] * 40 + smooth[:8] + [smooth[7]] * 40
    assert target_jumps(gesture, 10) == set()
    held = [f for f in smooth[::3] for _ in range(3)]
    assert target_jumps(held, 30) == set()
    # A frame whose targeted effectors change is one.
    two = two_arm_torso()
    frames = [pose_targets(two, q) for q in joint_stream(two, 0, 40)]
    frames[20] = frames[20][:1]
    assert target_jumps(frames, 10) == {20, 21}


def test_a_cut_in_the_targets_does_not_widen_repairs_to_the_whole_clip(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # The jump at the cut is the targets': a first repair spreads what it can of it,
    # and the stretches around it are not widened to the whole clip (they were:
    # 188,000 answers, more than planning every frame densely, for the same largest
    # step).
    chain = panda_arm()
    path, frames = cut_clip(chain, 120, 0.15)
    calls, plan = repairs_made(monkeypatch, chain, path, frames, 5)
    assert calls and (-1, 119) not in calls
    dense = planned_from(chain, path[0], frames, path_options=PathOptions(key_every=1))
    assert plan.success and dense.success
    assert plan.nodes < dense.nodes
    assert plan.largest_step <= 1.05 * dense.largest_step


def test_a_cut_does_not_set_the_pace() -> None:
    # The pole-crossing stream, keyframes 10 apart, with a 0.3 rad cut at frame 100:
    # counted in the keyframes' pace, the cut's keyframe gap would hide the corner
    # the keyframes cut near the pole (2.1x the reference's step away from the cut).
    chain = panda_arm()
    path = joint_stream(chain, 4, 120)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    path[100:] += 0.3
    path = np.clip(path, chain.lower, chain.upper)
    frames = [pose_targets(chain, q) for q in path]
    plan = planned_from(chain, path[0], frames, path_options=PathOptions(key_every=10))
    assert plan.success
    steps = np.abs(np.diff(np.vstack([path[0], plan.q]), axis=0)).max(axis=1)
    assert max(steps[k] for k in range(120) if abs(k - 100) > 3) <= 1.5 * ref


@pytest.mark.parametrize("frames_in_clip", [9, 60], ids=["shorter-than-two-keyframes", "mixed"])
def test_clips_keyframes_cannot_serve_are_planned_densely(frames_in_clip: int) -> None:
    # Keyframes need at least 2 x key_every frames of one kind of task: a 9-frame
    # clip, or one whose first half targets the tool's pose only (one free direction:
    # walked) and second half the elbow's position as well (none: not walked), is
    # planned exactly as key_every=1 plans it.
    panda = panda_arm()
    elbow = Effector(name="elbow", link="link4", mode=EffectorMode.POSITION)
    chain = build_chain(list(panda.joints), [*panda.effectors, elbow])
    path = joint_stream(chain, 0, frames_in_clip)
    frames = [pose_targets(chain, q) for q in path]
    if frames_in_clip == 60:
        frames = [f[:1] for f in frames[:30]] + frames[30:]
    else:
        frames = [f[:1] for f in frames]
    plan = planned_from(chain, path[0], frames)
    dense = planned_from(chain, path[0], frames, path_options=PathOptions(key_every=1))
    assert plan.nodes == dense.nodes
    np.testing.assert_array_equal(plan.q, dense.q)
    assert plan.success


@pytest.mark.parametrize(
    "field, value",
    [
        ("spacing_rad", 0.0),
        ("spacing_rad", math.nan),
        ("window_rad", 0.0),
        ("max_nodes_per_frame", 0),
        ("carried", 0),
        ("perturbed", -1),
        ("perturbation_rad", -0.1),
        ("smoothing_sweeps", -1),
        ("max_work", 0.0),
        ("carried", 1.5),
        ("key_every", 0),
        ("key_spacing_rad", 0.0),
        ("key_spacing_rad", math.inf),
        ("repair_ratio", 0.5),
        ("repair_ratio", math.nan),
    ],
)
def test_path_options_are_validated(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        PathOptions(**{field: value})


def test_walk_samples_the_self_motion_on_the_target() -> None:
    # A 7-DOF arm under a 6-D pose: the nodes walked from one answer lie on the target,
    # inside the limits, each within a few spacings of the next, and they span more
    # than a radian of the joint that moves most.
    chain = panda_arm()
    q0 = chain.mid_limits() + 0.1
    targets = pose_targets(chain, q0)
    solver = IKSolver(chain, STREAM)
    data = solver.load_frame(targets, q0, options=STREAM)
    box = (chain.lower, chain.upper, solver.free_mask())
    nodes = frame_nodes(q0[None, :].copy(), data, box, True, 0.01, 4096)
    assert len(nodes) > 100
    steps = np.abs(np.diff(nodes, axis=0)).max(axis=1)
    assert steps.max() <= 3 * 0.01
    assert (nodes.max(axis=0) - nodes.min(axis=0)).max() > 1.0
    for q in nodes[:: max(1, len(nodes) // 25)]:
        assert_reaches(chain, q, targets)


def test_dp_step_picks_the_smallest_largest_step_then_the_smoothest() -> None:
    prev = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.3]])
    prev_worst = np.array([0.0, 0.0, 0.5])
    prev_sum = np.array([0.0, 0.0, 0.0])
    nodes = np.array([[0.1, 0.0], [0.95, 0.05], [0.0, 0.25], [5.0, 0.5]])
    worst, total, back = dp_step(prev, prev_worst, prev_sum, nodes, 0.25)
    # node 0 from prev 0 (step 0.1); node 1 from prev 1 (0.05); node 2: from prev 0 the
    # step is 0.25, from prev 2 it is 0.05 but that path already stepped 0.5.
    assert back.tolist()[:3] == [0, 1, 0]
    assert worst[:3] == pytest.approx([0.1, 0.05, 0.25])
    assert total[:3] == pytest.approx([0.01, 0.0025, 0.0625])
    # node 3 is beyond the window from everything: still reached, by the shortest jump.
    assert back[3] == 1 and worst[3] == pytest.approx(4.0)


def test_dp_step_looks_past_the_window_when_the_best_it_found_is_longer() -> None:
    # prev 0 is within the window along the ordering variable (axis 0 spreads most)
    # but 2.0 away in full; prev 1 is 0.3 away: the step to take.
    prev = np.array([[2.0, 0.0], [0.0, 0.3], [0.0, 5.0]])
    zeros = np.zeros(3)
    worst, _, back = dp_step(prev, zeros, zeros, np.array([[0.0, 0.0]]), 0.25)
    assert back[0] == 1 and worst[0] == pytest.approx(0.3)


@pytest.mark.parametrize("name", sorted(CHAINS))
def test_plans_on_every_test_chain_keep_the_guarantees(name: str) -> None:
    # Every kind of joint and effector mode (prismatic, multi-axis, aim, two arms on
    # one torso with one hand's target dropped in some frames, a 16-variable tail), a
    # slow and a fast clip, each as is and with a frame out of reach.
    chain = CHAINS[name]()
    for seed, speed, far in ((0, 1, False), (1, 4, False), (0, 1, True), (1, 4, True)):
        path = joint_stream(chain, seed, 80)[::speed][:30]
        frames = [pose_targets(chain, q) for q in path]
        if name == "two-arms":
            frames = [f[:1] if k % 7 < 3 else f for k, f in enumerate(frames)]
        if far:
            frames = out_of_reach(frames, (15,))
        tracked = tracked_from(chain, path[0], frames)
        plan = planned_from(chain, path[0], frames)
        if far:
            assert not plan.results[15].success
        for r, t, targets in zip(plan.results, tracked, frames, strict=True):
            assert r.success or not t.success
            if r.success:
                assert_reaches(chain, r.q, targets)
        assert plan.largest_step == largest_step(path[0], plan.q)
        if all(t.success for t in tracked):
            assert plan.largest_step <= largest_step(path[0], np.array([t.q for t in tracked]))
