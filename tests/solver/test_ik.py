"""IK: exact gradients, solving, streams, terminators, modes and model validation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from solver import (
    DimensionMismatch,
    Effector,
    EffectorMode,
    IKOptions,
    IKSolver,
    IKStatus,
    InvalidModel,
    InvalidProblem,
    Joint,
    JointKind,
    Target,
    Termination,
    Transform,
    build_chain,
)
from solver.ik import STREAM_DEFAULTS, IKResult, pose_targets
from solver.ik.frame import solve_frame
from solver.ik.kinematics import DD_HI, DD_LO, MISC_SIZE, ik_objective
from solver.ik.metric import metric_inverse
from solver.ik.pole_term import POLE_NODE, POLE_POINT, POLE_WEIGHT
from solver.model.examples import bolt, humanoid_arm, panda_arm, tail, two_arm_torso
from solver.model.forward import effector_poses

from .helpers import CHAINS, slider_arm

TIGHT = IKOptions(position_tolerance_m=1e-5, rotation_tolerance_rad=1e-4, time_budget_us=None)


@pytest.mark.parametrize("name", sorted(CHAINS))
@pytest.mark.parametrize(("posture", "limit"), [(0.0, 0.0), (0.3, 2.0)])
def test_gradient_matches_central_differences(name: str, posture: float, limit: float) -> None:
    chain = CHAINS[name]()
    rng = np.random.default_rng(11)
    solver = IKSolver(
        chain, IKOptions(posture_weight=posture, limit_weight=limit, limit_margin=0.3)
    )
    targets = pose_targets(chain, rng.uniform(chain.lower, chain.upper))
    data = solver.load_frame(targets, chain.mid_limits())
    data[5][0:3] = (posture, limit, 0.3)
    data[4][0] = rng.uniform(chain.lower, chain.upper)
    for _ in range(4):
        q = rng.uniform(chain.lower, chain.upper)
        g = np.zeros(chain.n_dof)
        ik_objective(q, g, True, data)
        fd = np.zeros_like(g)
        for i in range(chain.n_dof):
            h = 1e-6
            qp, qm = q.copy(), q.copy()
            qp[i] += h
            qm[i] -= h
            fd[i] = (
                ik_objective(qp, np.zeros_like(g), False, data)
                - ik_objective(qm, np.zeros_like(g), False, data)
            ) / (2 * h)
        assert_allclose(g, fd, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("name", sorted(CHAINS))
def test_gradient_with_a_pole_matches_central_differences(name: str) -> None:
    """The pole term's gradient (solver.ik.pole_term), mimic joints included: a
    follower above the pulled link moves it at its multiplier times the leader."""
    chain = CHAINS[name]()
    rng = np.random.default_rng(12)
    solver = IKSolver(chain)
    targets = pose_targets(chain, rng.uniform(chain.lower, chain.upper))
    data = solver.load_frame(targets, chain.mid_limits())
    misc = data[5]
    pulled = chain.compiled.link_node[chain.effectors[-1].link]
    row = MISC_SIZE + 1
    misc[MISC_SIZE] = 1.0  # one pole, on the last effector's link
    misc[row + POLE_NODE] = pulled
    misc[row + POLE_WEIGHT] = 0.7
    misc[row + POLE_POINT : row + POLE_POINT + 3] = rng.normal(size=3)
    without = np.zeros(chain.n_dof)
    for _ in range(3):
        q = rng.uniform(chain.lower, chain.upper)
        g = np.zeros(chain.n_dof)
        ik_objective(q, g, True, data)
        misc[MISC_SIZE] = 0.0
        ik_objective(q, without, True, data)
        misc[MISC_SIZE] = 1.0
        assert np.any(np.abs(g - without) > 1e-6)  # the pole term is on
        fd = np.zeros_like(g)
        for i in range(chain.n_dof):
            h = 1e-6
            qp, qm = q.copy(), q.copy()
            qp[i] += h
            qm[i] -= h
            fd[i] = (
                ik_objective(qp, np.zeros_like(g), False, data)
                - ik_objective(qm, np.zeros_like(g), False, data)
            ) / (2 * h)
        assert_allclose(g, fd, rtol=1e-5, atol=1e-7)


def check_solution(chain, result, targets, opts: IKOptions) -> None:  # type: ignore[no-untyped-def]
    """Success re-checked with our FK and the limits, not the solver's flag."""
    assert np.all(result.q >= chain.lower) and np.all(result.q <= chain.upper)
    poses = effector_poses(chain, result.q)
    for t in targets:
        pose = poses[chain.effector_index(t.effector)]
        assert np.linalg.norm(pose[:3, 3] - t.position) <= opts.position_tolerance_m
        if t.rotation is not None:
            cos = (np.trace(pose[:3, :3] @ t.rotation.T) - 1.0) / 2.0
            assert math.acos(min(1.0, max(-1.0, cos))) <= opts.rotation_tolerance_rad * (1 + 1e-9)


@pytest.mark.parametrize(("factory", "floor"), [(panda_arm, 0.99), (humanoid_arm, 0.98)])
def test_random_reachable_poses_are_solved_from_mid_limits(factory, floor: float) -> None:  # type: ignore[no-untyped-def]
    chain = factory()
    solver = IKSolver(chain, TIGHT)
    rng = np.random.default_rng(5)
    solved = 0
    for _ in range(150):
        targets = pose_targets(chain, rng.uniform(chain.lower, chain.upper))
        r = solver.solve(targets, rng=rng)
        if r.success:
            solved += 1
            check_solution(chain, r, targets, TIGHT)
            assert r.status is IKStatus.SOLVED and r.termination is Termination.GOAL_REACHED
            assert all(e.within_tolerance for e in r.effectors)
    assert solved / 150 >= floor


def test_unreachable_target_returns_closest_pose_and_says_so() -> None:
    chain = panda_arm(EffectorMode.POSITION)
    far = np.array([3.0, 0.0, 0.5])
    r = IKSolver(chain, TIGHT).solve([Target(effector="tool", position=far)])
    assert not r.success
    assert r.status in (IKStatus.NOT_REACHED, IKStatus.BUDGET_EXHAUSTED)
    reach = np.linalg.norm(effector_poses(chain, r.q)[0][:3, 3])
    # The arm stretches towards the target: its tip is about as far out as it gets.
    assert r.effectors[0].position_error_m == pytest.approx(
        np.linalg.norm(far - effector_poses(chain, r.q)[0][:3, 3])
    )
    assert reach > 0.8


def test_zero_time_budget_reports_deadline_and_best_pose() -> None:
    chain = panda_arm()
    r = IKSolver(chain, IKOptions(time_budget_us=0.0)).solve(pose_targets(chain, chain.lower * 0.5))
    assert r.termination is Termination.DEADLINE
    assert r.status is IKStatus.BUDGET_EXHAUSTED
    assert_allclose(r.q, chain.mid_limits(), rtol=0, atol=0)


@given(
    st.lists(st.floats(-5.0, 5.0, allow_nan=False), min_size=3, max_size=3),
    st.integers(0, 2**31 - 1),
)
def test_any_finite_target_gives_finite_joints_inside_limits(pos: list[float], seed: int) -> None:
    chain = humanoid_arm(EffectorMode.POSITION)
    r = IKSolver(chain, IKOptions(time_budget_us=None, max_iter=60, max_restarts=2)).solve(
        [Target(effector="hand", position=np.array(pos))], rng=np.random.default_rng(seed)
    )
    assert np.isfinite(r.q).all()
    assert np.all(r.q >= chain.lower) and np.all(r.q <= chain.upper)


def test_terminators_freeze_joints_above_the_chain() -> None:
    chain = two_arm_torso()
    solver = IKSolver(chain, TIGHT)
    q_true = chain.mid_limits() + np.array([0.0, 0.3, -0.2, 0.8, 0.1, 0.1, 0.5])
    q_true[0] = 0.0  # the spine stays where the seed has it
    targets = [t for t in pose_targets(chain, q_true) if t.effector == "left_hand"]
    seed = chain.mid_limits()
    r = solver.solve(targets, seed)
    assert r.success
    spine = chain.dof_names.index("spine")
    right = [i for i, n in enumerate(chain.dof_names) if n.startswith("right")]
    assert r.q[spine] == seed[spine]
    assert_allclose(r.q[right], seed[right], rtol=0, atol=0)
    assert [e.name for e in r.effectors] == ["left_hand"]


def test_two_effectors_solved_together() -> None:
    chain = two_arm_torso()
    q_true = np.array([0.0, 0.4, -0.3, 1.0, -0.2, 0.5, 0.7])
    r = IKSolver(chain, TIGHT).solve(pose_targets(chain, q_true))
    assert r.success
    check_solution(chain, r, pose_targets(chain, q_true), TIGHT)


def test_aim_effector_points_its_axis() -> None:
    chain = slider_arm()
    rng = np.random.default_rng(2)
    q = rng.uniform(chain.lower, chain.upper) * 0.5
    targets = pose_targets(chain, q)
    r = IKSolver(chain, TIGHT).solve(targets)
    assert r.success
    pose = effector_poses(chain, r.q)[0]
    assert_allclose(pose[:3, 0], targets[0].direction, rtol=0, atol=2e-4)


def test_stream_tracks_a_smooth_path_without_popping() -> None:
    chain = panda_arm()
    solver = IKSolver(
        chain,
        IKOptions(
            position_tolerance_m=1e-5,
            rotation_tolerance_rad=1e-4,
            time_budget_us=None,
            restart_radius_rad=0.3,
            limit_weight=1e-3,
            limit_margin=0.02,
        ),
    )
    mid = chain.mid_limits()
    amp = 0.25 * (chain.upper - chain.lower) / 2
    ts = np.arange(240) / 60.0
    path = mid + amp * np.sin(2 * np.pi * 0.25 * ts[:, None] + np.arange(7))
    solver.set_pose(path[0])
    ref_step = np.abs(np.diff(path, axis=0)).max()
    prev = solver.q.copy()
    worst_step = 0.0
    for q in path[1:]:
        r = solver.track(pose_targets(chain, q))
        assert r.success, (r.status, r.effectors)
        worst_step = max(worst_step, float(np.abs(r.q - prev).max()))
        prev = r.q
    assert worst_step <= 2.0 * ref_step


def test_partial_targets_and_input_errors() -> None:
    chain = two_arm_torso()
    solver = IKSolver(chain)
    with pytest.raises(InvalidProblem, match="unknown effector"):
        solver.solve([Target(effector="nose", position=np.zeros(3))])
    with pytest.raises(InvalidProblem, match="two targets"):
        solver.solve([Target(effector="left_hand", position=np.zeros(3))] * 2)
    with pytest.raises(DimensionMismatch):
        solver.solve([Target(effector="left_hand", position=np.zeros(3))], np.zeros(3))
    with pytest.raises(InvalidProblem, match="finite"):
        solver.solve([Target(effector="left_hand", position=np.array([np.nan, 0, 0]))])
    pose_chain = panda_arm()
    with pytest.raises(InvalidProblem, match="rotation"):
        IKSolver(pose_chain).solve([Target(effector="tool", position=np.zeros(3))])
    with pytest.raises(InvalidProblem, match="orthonormal"):
        IKSolver(pose_chain).solve(
            [Target(effector="tool", position=np.zeros(3), rotation=2 * np.eye(3))]
        )


def test_all_fixed_chain_reports_errors_without_solving() -> None:
    solver = IKSolver(bolt())
    assert solver.solve([Target(effector="tip", position=np.array([0.0, 0.0, 1.0]))]).success
    miss = solver.solve([Target(effector="tip", position=np.array([0.0, 0.0, 2.0]))])
    assert miss.status is IKStatus.NOT_REACHED
    assert miss.effectors[0].position_error_m == pytest.approx(1.0)


def j(name: str, parent: str, child: str, **kw: object) -> Joint:
    base = {"kind": JointKind.REVOLUTE, "lower": (-1.0,), "upper": (1.0,)}
    base.update(kw)
    return Joint(name=name, parent=parent, child=child, **base)  # type: ignore[arg-type]


EFF = [Effector(name="e", link="b")]


@pytest.mark.parametrize(
    ("joints", "effectors", "joint", "field"),
    [
        ([j("a", "w", "b"), j("a", "b", "c")], EFF, "a", "name"),
        ([j("a", "w", "b"), j("x", "c", "d"), j("y", "d", "c")], EFF, None, "parent"),
        ([j("a", "w", "b", lower=(1.0,), upper=(0.0,))], EFF, "a", "lower"),
        ([j("a", "w", "b", axis=np.zeros(3))], EFF, "a", "axis"),
        ([j("a", "w", "b", lower=(math.nan,))], EFF, "a", "lower"),
        (
            [j("a", "w", "b", kind=JointKind.ROTATIONAL, axes="xx", lower=(0, 0), upper=(1, 1))],
            EFF,
            "a",
            "axes",
        ),
        ([j("a", "w", "b", pivot=np.array([math.inf, 0.0, 0.0]))], EFF, "a", "pivot"),
        ([j("a", "w", "b")], [Effector(name="e", link="nowhere")], "e", "link"),
        ([], EFF, None, "joints"),
    ],
)
def test_model_validation_names_joint_and_field(joints, effectors, joint, field) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(InvalidModel) as err:
        build_chain(joints, effectors)
    assert err.value.field == field
    if joint is not None:
        assert err.value.joint == joint


def test_cycle_and_too_many_joints_and_bad_quaternion() -> None:
    with pytest.raises(InvalidModel) as err:
        build_chain([j("a", "b", "c"), j("b", "c", "b")], EFF)
    assert err.value.field == "parent"
    many = [j(f"j{i}", f"l{i}", f"l{i + 1}") for i in range(10)]
    with pytest.raises(InvalidModel) as err:
        build_chain(many, [Effector(name="e", link="l10")], max_dof=5)
    assert err.value.field == "joints"
    with pytest.raises(InvalidModel) as err:
        Transform.from_quaternion([0, 0, 0], 1.0, 0.1, 0.0, 0.0, owner="a")
    assert (err.value.joint, err.value.field) == ("a", "rotation")


def test_metric_until_switches_from_gauss_newton_to_bfgs_updates() -> None:
    """metric_until=k re-seeds H from the Gauss-Newton metric only in a pass's first k
    iterations: k=1 is the article's BFGS (metric at the pass start only), and a k
    beyond the iterations taken is the unlimited metric_every=1."""
    chain = panda_arm()
    rng = np.random.default_rng(7)
    q = rng.uniform(chain.lower, chain.upper)
    targets = pose_targets(chain, q)
    base = IKOptions(max_restarts=0, time_budget_us=None)

    def run(**changes: object) -> IKResult:
        return IKSolver(chain, dataclasses.replace(base, **changes)).solve(targets)

    bfgs, until_1 = run(metric_every=0), run(metric_until=1)
    assert until_1.iterations == bfgs.iterations
    assert_allclose(until_1.q, bfgs.q, rtol=0, atol=0)
    gauss_newton, until_big = run(metric_until=0), run(metric_until=10_000)
    assert until_big.iterations == gauss_newton.iterations
    assert_allclose(until_big.q, gauss_newton.q, rtol=0, atol=0)
    assert gauss_newton.iterations != bfgs.iterations  # the switch is observable
    with pytest.raises(InvalidProblem, match="metric_until"):
        IKOptions(metric_until=-1)


def test_metric_every_by_default_depends_on_what_the_metric_costs() -> None:
    """None (the default) re-seeds every iteration, except every second one on chains
    of 13+ variables with at least as many task rows as variables."""
    auto = IKOptions()
    assert auto.metric_every is None
    assert auto.metric_interval(7, 6) == 1  # a 7-DOF arm's pose
    assert auto.metric_interval(12, 24) == 1
    assert auto.metric_interval(29, 39) == 2  # a humanoid's 9 effectors
    assert auto.metric_interval(27, 18) == 1  # three fingertips: a redundant task
    assert auto.metric_interval(40, 3) == 1  # the low-rank form: cheap at any size
    assert IKOptions(metric_every=1).metric_interval(29, 39) == 1
    assert IKOptions(metric_every=0).metric_interval(29, 39) == 0
    # The solver counts the chain's rows: three pose effectors on 14 variables.
    base = tail(7)
    chain = build_chain(
        list(base.joints),
        [Effector(name=f"e{k}", link=f"seg{k}", mode=EffectorMode.POSE) for k in (3, 5, 7)],
    )
    assert chain.n_dof == 14
    rng = np.random.default_rng(3)
    targets = pose_targets(chain, rng.uniform(chain.lower, chain.upper))
    plain = IKOptions(max_restarts=0, time_budget_us=None)

    def run(every: int | None) -> IKResult:
        return IKSolver(chain, dataclasses.replace(plain, metric_every=every)).solve(targets)

    default, every_2, every_1 = run(None), run(2), run(1)
    assert default.iterations == every_2.iterations
    assert_allclose(default.q, every_2.q, rtol=0, atol=0)
    assert (every_1.iterations, every_1.function_evals) != (
        every_2.iterations,
        every_2.function_evals,
    )


def test_target_parts_of_the_wrong_shape_are_rejected_when_built() -> None:
    with pytest.raises(InvalidProblem, match="'tool'.*3 numbers"):
        Target(effector="tool", position=np.zeros(2))
    with pytest.raises(InvalidProblem, match="3x3 matrix"):
        Target(effector="tool", position=np.zeros(3), rotation=np.eye(3).reshape(9))
    with pytest.raises(InvalidProblem, match="3 numbers"):
        Target(effector="tool", direction=["a", "b", "c"])  # type: ignore[arg-type]


def test_a_result_keeps_its_own_numbers_after_later_solves() -> None:
    """Results read errors, H and the pass log lazily from their own output block: a
    later solve on the same solver must not change an earlier result."""
    chain = panda_arm()
    solver = IKSolver(chain)
    rng = np.random.default_rng(3)
    first = solver.solve(pose_targets(chain, rng.uniform(chain.lower, chain.upper)))
    kept = (
        first.q.copy(),
        first.raw_errors.copy(),
        first.inverse_hessian.copy(),
        first.pass_log,
        first.effectors,
    )
    for _ in range(3):
        solver.track(pose_targets(chain, rng.uniform(chain.lower, chain.upper)))
    assert_allclose(first.q, kept[0], rtol=0, atol=0)
    assert_allclose(first.raw_errors, kept[1], rtol=0, atol=0)
    assert_allclose(first.inverse_hessian, kept[2], rtol=0, atol=0)
    assert first.pass_log == kept[3]
    assert first.effectors == kept[4]
    assert first.joint_values == dict(zip(chain.dof_names, kept[0].tolist(), strict=True))


def test_targets_from_sequences_and_from_arrays_pack_the_same_row() -> None:
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    from_arrays = Target(effector="tool", position=np.array([0.1, 0.2, 0.3]), rotation=rotation)
    from_tuples = Target(
        effector="tool", position=(0.1, 0.2, 0.3), rotation=tuple(map(tuple, rotation.tolist()))
    )
    from_lists = Target(effector="tool", position=[0.1, 0.2, 0.3], rotation=rotation.tolist())
    for t in (from_tuples, from_lists):
        assert_allclose(t.packed, from_arrays.packed, rtol=0, atol=0)
        assert t.given == from_arrays.given
    aim = Target(effector="tool", direction=(0.0, 1.0, 0.0))
    assert_allclose(aim.packed[12:], [0.0, 1.0, 0.0])
    with pytest.raises(InvalidProblem, match="3x3 matrix"):
        Target(effector="tool", rotation=((1.0, 0.0), (0.0, 1.0), (0.0, 0.0)))
    with pytest.raises(InvalidProblem, match="3 numbers"):
        Target(effector="tool", position=(0.1, (0.2,), 0.3))


def test_a_target_from_a_packed_row_is_the_one_its_parts_build() -> None:
    """Target.from_row (the service's per-frame constructor) against __init__, for each
    combination of given parts, down to the bits of the row and the views shown."""
    from solver.ik import GIVEN_DIRECTION, GIVEN_POSITION, GIVEN_ROTATION

    position = (0.1, -0.2, 0.3)
    rotation = ((0.0, -1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    direction = (0.0, 0.6, 0.8)
    for bits in range(8):
        parts = {
            "position": position if bits & GIVEN_POSITION else None,
            "rotation": rotation if bits & GIVEN_ROTATION else None,
            "direction": direction if bits & GIVEN_DIRECTION else None,
        }
        built = Target(effector="tool", **parts)  # type: ignore[arg-type]
        row = built.packed.copy()
        fast = Target.from_row("tool", row, built.given)
        assert fast.given == built.given == bits
        assert fast.packed.tobytes() == built.packed.tobytes()
        assert not row.flags.writeable  # kept, not copied, and frozen
        for name in ("position", "rotation", "direction"):
            a, b = getattr(fast, name), getattr(built, name)
            assert (a is None) == (b is None) == (parts[name] is None)
            if a is not None:
                assert_allclose(a, b, rtol=0, atol=0)
                assert np.shares_memory(a, fast.packed)
    with pytest.raises(InvalidProblem, match="15 float64"):
        Target.from_row("tool", np.zeros(14), GIVEN_POSITION)
    with pytest.raises(InvalidProblem, match="15 float64"):
        Target.from_row("tool", np.zeros(15, dtype=np.float32), GIVEN_POSITION)
    with pytest.raises(InvalidProblem, match="15 float64"):
        Target.from_row("tool", np.zeros(15), 8)
    with pytest.raises(InvalidProblem, match="15 float64"):
        Target.from_row("tool", np.zeros(15), 1.0)  # type: ignore[arg-type]
    with pytest.raises(InvalidProblem, match="15 float64"):
        Target.from_row("tool", np.zeros(15, dtype=">f8"), GIVEN_POSITION)
    base = np.zeros((2, 15))
    with pytest.raises(InvalidProblem, match="of its own"):
        Target.from_row("tool", base[0], GIVEN_POSITION)  # a view: base could change it


def test_a_target_is_a_snapshot_of_its_numbers() -> None:
    position = np.array([0.3, 0.1, 0.5])
    t = Target(effector="tool", position=position)
    position[:] = 9.0
    assert_allclose(t.position, [0.3, 0.1, 0.5])  # type: ignore[arg-type]
    assert not t.packed.flags.writeable
    assert np.shares_memory(t.position, t.packed)  # type: ignore[arg-type]
    with pytest.raises(InvalidProblem, match="3 numbers"):
        Target(effector="tool", position=[[0.1, 0.2, 0.3]] * 3)


def test_track_checks_the_stream_pose_it_starts_from() -> None:
    chain = panda_arm()
    solver = IKSolver(chain)
    solver.q = np.zeros(3)
    with pytest.raises(DimensionMismatch):
        solver.track(pose_targets(chain, chain.mid_limits()))


def test_odd_layouts_and_number_types_reuse_the_compiled_frame() -> None:
    """A Fortran-ordered H, an int null-space step or a float32 stream pose must not
    make numba compile another specialisation of the frame (seconds, at run time)."""
    chain = panda_arm()
    targets = pose_targets(chain, chain.mid_limits() + 0.05)
    IKSolver(chain, STREAM_DEFAULTS).track(targets)  # the usual signature
    before = len(solve_frame.signatures)
    solver = IKSolver(chain, dataclasses.replace(STREAM_DEFAULTS, null_space_step_rad=0))
    solver.q = chain.mid_limits().astype(np.float32)
    assert solver.track(targets).success
    h = np.asfortranarray(np.eye(chain.n_dof) * 0.5)
    assert solver.solve(targets, initial_inverse_hessian=h).success
    assert len(solve_frame.signatures) == before


def test_later_solves_skip_type_dispatch_and_still_convert_odd_seeds() -> None:
    """After its first solve an IKSolver calls the compiled frame's entry point directly
    (no per-call type dispatch), so every argument must reach it with the compiled
    types: strided, float32, read-only and list seeds are converted first, and give
    the same answer as a solver that has not cached the entry point."""
    chain = panda_arm()
    targets = pose_targets(chain, chain.mid_limits() + 0.05)
    solver = IKSolver(chain)
    assert solver.solve(targets).success
    assert solver._solve_call is not solve_frame
    seed = chain.mid_limits() + 0.01
    readonly = seed.copy()
    readonly.flags.writeable = False
    for odd in (np.repeat(seed, 2)[::2], seed.astype(np.float32), readonly, list(seed)):
        cached = solver.solve(targets, odd)
        reference = IKSolver(chain).solve(targets, np.array(odd, dtype=np.float64))
        assert cached.success
        assert_allclose(cached.q, reference.q, rtol=0, atol=0)
        assert cached.iterations == reference.iterations


@pytest.mark.parametrize("carry", [True, False])
def test_carried_h_is_the_metric_at_the_answer(carry: bool) -> None:
    """A solve that meets the goal skips the Gauss-Newton metric for the step it will
    not take, unless the caller carries H to its next solve (carry_hessian): then
    the H handed back is the metric at the answer, as before that saving."""
    chain = panda_arm()
    targets = pose_targets(chain, chain.mid_limits() + 0.1)
    solver = IKSolver(chain, IKOptions(carry_hessian=carry))
    result = solver.solve(targets)
    assert result.success and result.iterations >= 1
    data = solver.load_frame(targets, result.q)
    h = np.empty((chain.n_dof, chain.n_dof))
    g = np.zeros(chain.n_dof)  # the answer is inside the limits: nothing is held
    ik_objective(result.q, np.empty(chain.n_dof), True, data)
    assert metric_inverse(result.q, g, data[4][DD_LO], data[4][DD_HI], data, h)
    same = np.allclose(result.inverse_hessian, h, rtol=1e-9, atol=1e-12)
    assert same is carry


def _solve_with_floor(chain, targets, seed, **changes):  # type: ignore[no-untyped-def]
    opts = dataclasses.replace(TIGHT, **{"damping": 0.01, "damping_scale": 1.0, **changes})
    return IKSolver(chain, seed=0).solve(targets, seed, options=opts)


@pytest.mark.parametrize(
    ("chain", "redundant"),
    [
        (tail(3, EffectorMode.POSE), False),  # 6 joints, 6 target rows
        (tail(3, EffectorMode.POSITION), True),  # 6 joints, 3 rows
        (two_arm_torso(), False),  # one hand: its arm's 3 joints (the shoulder terminates), 3 rows
    ],
    ids=["pose-6dof", "position-6dof", "one-hand-of-two"],
)
def test_damping_floor_follows_the_task_redundancy(chain, redundant) -> None:  # type: ignore[no-untyped-def]
    """damping_redundant_only: a task with as many rows as free joints solves exactly
    as with no floor, a redundant one exactly as with the floor."""
    lo, hi = chain.lower, chain.upper
    seed = lo + 0.45 * (hi - lo)
    goal = lo + 0.7 * (hi - lo)
    goal[0] = seed[0]  # the torso's spine does not move for one hand
    targets = pose_targets(chain, goal)[:1]
    on = _solve_with_floor(chain, targets, seed)
    off = _solve_with_floor(chain, targets, seed, damping=0.0)
    auto = _solve_with_floor(chain, targets, seed, damping_redundant_only=True)
    assert on.success and off.success and auto.success
    assert on.iterations != off.iterations  # the floor changes this solve's path
    expected = on if redundant else off
    np.testing.assert_array_equal(auto.q, expected.q)
    assert auto.iterations == expected.iterations


def test_damping_floor_follows_the_target_set_under_the_same_options() -> None:
    """The redundancy is the frame's target set's: a 4-joint aim effector with its
    position targeted has 5 rows (no floor), with the direction alone 2 (floor), and
    one solver with one options object switches between them frame by frame."""
    chain = tail(2, EffectorMode.AIM)
    lo, hi = chain.lower, chain.upper
    seed = lo + 0.45 * (hi - lo)
    full = pose_targets(chain, lo + 0.7 * (hi - lo))[0]
    aim_only = Target(effector=full.effector, direction=full.direction)
    opts = dataclasses.replace(TIGHT, damping=0.01, damping_scale=1.0, damping_redundant_only=True)
    solver = IKSolver(chain, opts, seed=0)
    for targets, floor in (([full], False), ([aim_only], True), ([full], False)):
        got = solver.solve(targets, seed)
        want = _solve_with_floor(chain, targets, seed, damping=0.01 if floor else 0.0)
        assert got.success and want.success
        np.testing.assert_array_equal(got.q, want.q)
        assert got.iterations == want.iterations
    assert (
        _solve_with_floor(chain, [aim_only], seed).iterations
        != _solve_with_floor(chain, [aim_only], seed, damping=0.0).iterations
    )


def _tail_with(*effectors: Effector, locked: tuple[str, ...] = ()):  # type: ignore[no-untyped-def]
    """tail(3)'s six joints (j1..j3, axes x and z, +-40 deg) with other effectors;
    ``locked`` pins joints ("j1": both axes) or single axes ("j2.x") at 0.1 rad
    (lower == upper)."""
    joints = []
    for j in tail(3).joints:
        pins = [f"{j.name}.{a}" in locked or j.name in locked for a in j.axes]
        if any(pins):
            j = dataclasses.replace(
                j,
                lower=tuple(0.1 if p else lo for p, lo in zip(pins, j.lower, strict=True)),
                upper=tuple(0.1 if p else hi for p, hi in zip(pins, j.upper, strict=True)),
            )
        joints.append(j)
    return build_chain(joints, list(effectors))


@pytest.mark.parametrize(
    ("chain", "targets", "redundant"),
    [
        # A pose without a weighted position: 3 rows on 6 joints.
        (
            _tail_with(
                Effector(name="tip", link="tip", mode=EffectorMode.POSE, position_weight=0.0)
            ),
            None,
            True,
        ),
        # A pose without a weighted rotation: 3 rows on 6 joints.
        (
            _tail_with(
                Effector(name="tip", link="tip", mode=EffectorMode.POSE, rotation_weight=0.0)
            ),
            None,
            True,
        ),
        # A position on 6 joints of which 4 are locked: 3 rows on 2 joints.
        (_tail_with(Effector(name="tip", link="tip"), locked=("j1", "j2")), None, False),
        # An aim alone (2 rows) on seg2's 4 joints with j1 locked: 2 free joints.
        (
            _tail_with(Effector(name="tip", link="seg2", mode=EffectorMode.AIM), locked=("j1",)),
            "aim only",
            False,
        ),
        # The same aim on all 6 joints but j1 and j2.x: 3 free joints, 2 rows.
        (
            _tail_with(
                Effector(name="tip", link="tip", mode=EffectorMode.AIM), locked=("j1", "j2.x")
            ),
            "aim only",
            True,
        ),
    ],
    ids=["pose-no-position", "pose-no-rotation", "locked-joints", "aim-2-of-2", "aim-2-of-3"],
)
def test_redundancy_counts_weighted_rows_and_unlocked_joints(chain, targets, redundant) -> None:  # type: ignore[no-untyped-def]
    lo, hi = chain.lower, chain.upper
    seed = lo + 0.45 * (hi - lo)
    full = pose_targets(chain, lo + 0.7 * (hi - lo))
    if targets == "aim only":
        full = [Target(effector=full[0].effector, direction=full[0].direction)]
    auto = _solve_with_floor(chain, full, seed, damping_redundant_only=True)
    want = _solve_with_floor(chain, full, seed, **({} if redundant else {"damping": 0.0}))
    other = _solve_with_floor(chain, full, seed, **({"damping": 0.0} if redundant else {}))
    assert auto.success and want.success
    assert other.iterations != want.iterations or not np.array_equal(other.q, want.q)
    np.testing.assert_array_equal(auto.q, want.q)
    assert auto.iterations == want.iterations


def test_redundancy_is_recounted_when_a_target_set_is_rejected() -> None:
    """A frame whose second target is rejected leaves its first loaded; the next frame
    (the fast path) must see that effector's redundancy, not the frame before's."""
    chain = _tail_with(
        Effector(name="tip", link="tip", mode=EffectorMode.POSE),  # 6 rows on 6 joints
        Effector(name="mid", link="seg2"),  # 3 rows on 4 joints: redundant
    )
    lo, hi = chain.lower, chain.upper
    seed = lo + 0.45 * (hi - lo)
    tip, mid = pose_targets(chain, lo + 0.7 * (hi - lo))
    opts = dataclasses.replace(TIGHT, damping=0.01, damping_scale=1.0, damping_redundant_only=True)
    solver = IKSolver(chain, opts, seed=0)
    assert solver.solve([tip], seed).success
    with pytest.raises(InvalidProblem, match="unknown effector"):
        solver.solve([mid, Target(effector="nose", position=np.zeros(3))], seed)
    got = solver.solve([mid], seed)
    want = _solve_with_floor(chain, [mid], seed)
    assert got.success and want.success
    np.testing.assert_array_equal(got.q, want.q)
    assert got.iterations == want.iterations
