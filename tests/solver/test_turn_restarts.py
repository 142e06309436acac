"""Turn restarts: a revolute joint that a limit stops, its best angle just past it, is
turned the other way round (``optim.restart.turn_values``; the IK's periods in
``ik.settled.variable_periods``)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from solver import IKOptions, IKSolver, MinimizeOptions, PassStart, Target, build_chain
from solver.ik import STREAM_DEFAULTS, pose_targets
from solver.ik.settled import variable_periods
from solver.model import Chain, EffectorMode
from solver.model.examples import panda_arm
from solver.model.forward import effector_poses
from solver.model.urdf import chain_from_urdf
from solver.optim.restart import turn_values

TWO_PI = 2.0 * math.pi
LIMIT = 3.05  # Baxter's wrists and forearms: 0.18 rad short of a full turn


def _turn(x, g, keep=None, lo=-LIMIT, hi=LIMIT, center=0.0, radius=math.inf):  # type: ignore[no-untyped-def]
    n = len(x)
    out = np.full(n, np.nan)
    turned = turn_values(
        np.array(x, dtype=float),
        np.array(g, dtype=float),
        np.full(n, TWO_PI),
        np.zeros(n) if keep is None else np.array(keep, dtype=float),
        np.full(n, lo),
        np.full(n, hi),
        np.full(n, center),
        radius,
        out,
    )
    return turned, out


def test_a_variable_a_bound_stops_turns_to_the_opposite_bound() -> None:
    # Pushed up against the upper bound (g < 0), pushed down against the lower one
    # (g > 0), and a free variable: the first two turn, the third keeps its value.
    turned, out = _turn([LIMIT, -LIMIT, 0.3], [-1.0, 2.0, 5.0])
    assert turned == 2
    np.testing.assert_array_equal(out, [-LIMIT, LIMIT, 0.3])


def test_a_full_turn_of_range_turns_to_the_same_angle() -> None:
    # A range of a whole turn (+-pi, the UR arms' joints): the same angle, other side.
    turned, out = _turn([math.pi], [-1.0], lo=-math.pi, hi=math.pi)
    assert turned == 1 and out[0] == -math.pi
    # Two turns of range (+-2 pi): the same angle inside the range.
    turned, out = _turn([TWO_PI], [-1.0], lo=-TWO_PI, hi=TWO_PI)
    assert turned == 1 and out[0] == 0.0


@pytest.mark.parametrize(
    ("x", "g", "keep", "lo", "hi", "radius"),
    [
        ([LIMIT], [1.0], [0.0], -LIMIT, LIMIT, math.inf),  # the gradient pulls it inside
        ([LIMIT], [0.0], [0.0], -LIMIT, LIMIT, math.inf),  # no pull at all
        ([LIMIT], [-1.0], [1.0], -LIMIT, LIMIT, math.inf),  # it moves only what is on target
        ([1.5], [-1.0], [0.0], -1.5, 1.5, math.inf),  # a range under half a turn (a knee)
        # A gap over a quarter turn (g1's shoulder roll, 3.84 rad of range): the
        # opposite bound is no nearer the best angle than a random draw.
        ([1.92], [-1.0], [0.0], -1.92, 1.92, math.inf),
        ([LIMIT], [-1.0], [0.0], -LIMIT, LIMIT, 0.3),  # a stream's local restarts
        ([0.5], [-1.0], [0.0], -LIMIT, LIMIT, math.inf),  # not on a bound
    ],
)
def test_what_does_not_turn(x, g, keep, lo, hi, radius) -> None:  # type: ignore[no-untyped-def]
    turned, out = _turn(x, g, keep, lo, hi, center=LIMIT, radius=radius)
    assert turned == 0
    assert np.isnan(out).all()  # untouched


_URDF = """<robot name="mixed">
  <link name="base"/><link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <joint name="turn" type="revolute"><parent link="base"/><child link="a"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="slide" type="prismatic"><parent link="a"/><child link="b"/>
    <origin xyz="0.1 0 0"/><axis xyz="1 0 0"/>
    <limit lower="0" upper="0.2" effort="1" velocity="1"/></joint>
  <joint name="spin" type="continuous"><parent link="b"/><child link="c"/>
    <origin xyz="0.1 0 0"/><axis xyz="0 1 0"/></joint>
  <joint name="half" type="revolute"><parent link="c"/><child link="d"/>
    <origin xyz="0.1 0 0"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/>
    <mimic joint="turn" multiplier="0.5"/></joint>
</robot>"""


def test_the_angles_of_revolute_joints_have_a_period_of_a_turn() -> None:
    """A revolute or continuous joint's angle: 2 pi. A slide: none. A leader with a
    follower at half its rate: none (two turns of the leader make one of the follower)."""
    chain = chain_from_urdf(_URDF, base_link="base", tip_links=["d"])
    assert chain.dof_names == ("turn", "slide", "spin")
    solver = IKSolver(chain)
    target = Target(effector=chain.effectors[0].name, position=np.zeros(3), rotation=np.eye(3))
    data = solver.load_frame([target], chain.mid_limits())
    period = np.full(3, np.nan)
    assert variable_periods(data, period) == 1
    np.testing.assert_array_equal(period, [0.0, 0.0, TWO_PI])


def _wrists(count: int) -> str:
    """``count`` one-joint arms on one base, each turning a 0.3 m link about z within
    +-3.05 rad, a position effector at its end."""
    parts = ['<robot name="wrists"><link name="base"/>']
    for k in range(count):
        parts.append(
            f'<link name="arm{k}"/><link name="tip{k}"/>'
            f'<joint name="j{k}" type="revolute"><parent link="base"/><child link="arm{k}"/>'
            f'<origin xyz="0 {0.5 * k} 0"/><axis xyz="0 0 1"/>'
            f'<limit lower="-{LIMIT}" upper="{LIMIT}" effort="1" velocity="1"/></joint>'
            f'<joint name="t{k}" type="fixed"><parent link="arm{k}"/><child link="tip{k}"/>'
            f'<origin xyz="0.3 0 0"/></joint>'
        )
    parts.append("</robot>")
    return "".join(parts)


def test_a_turn_restart_solves_what_random_restarts_miss() -> None:
    """Twelve arms, each started at 2.9 rad with its target at -3.0 rad: the short way
    there is up, through the 0.18 rad gap the limits forbid, so every arm's descent
    stops at its upper limit. A random restart lands all twelve in their target's
    basin (about half the range each) once in ~4000 draws; one turn restart moves
    each to its lower limit, 0.05 rad from the target, and the next pass solves all."""
    count = 12
    chain = chain_from_urdf(
        _wrists(count), base_link="base", tip_links=[f"tip{k}" for k in range(count)]
    )
    position = [dataclasses.replace(e, mode=EffectorMode.POSITION) for e in chain.effectors]
    chain = build_chain(list(chain.joints), position)
    goal = np.full(count, -3.0)
    tips = effector_poses(chain, goal)
    targets = [
        Target(effector=e.name, position=pose[:3, 3])
        for e, pose in zip(chain.effectors, tips, strict=True)
    ]
    seed = np.full(count, 2.9)
    # The wrists in one solve: each would be solved apart otherwise (ik.split).
    base = IKOptions(time_budget_us=None, max_restarts=1, split_limbs=False)
    before = IKSolver(chain, dataclasses.replace(base, turn_restarts=False), seed=5)
    after = IKSolver(chain, base, seed=5)
    missed = before.solve(targets, seed)
    solved = after.solve(targets, seed)
    assert not missed.success
    assert solved.success, solved.pass_log
    starts = [p.start for p in solved.pass_log]
    assert starts.count(PassStart.RESTART_TURN) == 1
    assert PassStart.RESTART_TURN not in [p.start for p in missed.pass_log]
    np.testing.assert_allclose(solved.q, goal, atol=1e-3)


def test_single_tip_solves_change_only_where_a_turn_restart_was_taken() -> None:
    """A single-tip arm (the Panda): with and without turn restarts, a solve that took
    no turn restart is the same, pass for pass, and one that did is the same up to
    its first turn restart (a restart still draws its random point, so the generator
    runs the same either way)."""
    chain = panda_arm()
    goals = np.random.default_rng(4).uniform(chain.lower, chain.upper, size=(40, chain.n_dof))
    # The wrists in one solve: each would be solved apart otherwise (ik.split).
    base = IKOptions(time_budget_us=None, max_restarts=20, split_limbs=False)
    turned = 0
    for q in goals:
        targets = pose_targets(chain, q)
        a = IKSolver(chain, base, seed=3).solve(targets)
        b = IKSolver(chain, dataclasses.replace(base, turn_restarts=False), seed=3).solve(targets)
        starts = [p.start for p in a.pass_log]
        if PassStart.RESTART_TURN in starts:
            turned += 1
            first = starts.index(PassStart.RESTART_TURN)
            assert a.pass_log[:first] == b.pass_log[:first]
        else:
            np.testing.assert_array_equal(a.q, b.q)
            assert a.pass_log == b.pass_log
    assert turned < len(goals)


@pytest.mark.parametrize("make", [IKOptions, MinimizeOptions])
def test_turn_restarts_are_on_by_default(make: type) -> None:
    assert make().turn_restarts is True


def _wrist_chain(count: int) -> Chain:
    """``count`` wrists of ``_wrists``, each tip a position effector."""
    urdf_chain = chain_from_urdf(
        _wrists(count), base_link="base", tip_links=[f"tip{k}" for k in range(count)]
    )
    return build_chain(
        list(urdf_chain.joints),
        [dataclasses.replace(e, mode=EffectorMode.POSITION) for e in urdf_chain.effectors],
    )


def test_one_turn_restart_per_best_point() -> None:
    """Targets in the gap the limits forbid: each wrist stops at a limit, and turning it
    lands on the other limit, no better. The turn is tried once from that best point;
    the later restarts are random draws, not the same turned pass again (review: with
    the once-per-best-point rule removed, every restart was ``restart_turn``)."""
    count = 3
    chain = _wrist_chain(count)
    targets = [
        Target(effector=e.name, position=np.array([-0.3, 0.5 * k, 0.0]))
        for k, e in enumerate(chain.effectors)
    ]
    # The wrists in one solve: each would be solved apart otherwise (ik.split).
    options = IKOptions(time_budget_us=None, max_restarts=6, split_limbs=False)
    r = IKSolver(chain, options, seed=5).solve(targets, np.full(count, 2.9))
    starts = [p.start for p in r.pass_log]
    assert starts.count(PassStart.RESTART_TURN) == 1, starts
    assert starts.count(PassStart.RESTART_RANDOM) >= 1, starts


def test_a_streams_local_restarts_take_no_turn_restart() -> None:
    """A tracked stream restarts within ``restart_radius_rad`` (0.3) of its start: the
    twelve wrists of the test above, tracked from 2.9 rad towards -3.0 rad, stop at
    their upper limit, where a turn restart would move each to -3.05 rad, 6.1 rad
    away. Every frame's restarts are local draws, never a turn (review: with the
    radius rule of ``turn_values`` removed, the first frame's first restart turned)."""
    count = 12
    chain = _wrist_chain(count)
    goal = np.full(count, -3.0)
    targets = [
        Target(effector=e.name, position=pose[:3, 3])
        for e, pose in zip(chain.effectors, effector_poses(chain, goal), strict=True)
    ]
    # No global fallback: it would retry the frame with the radius widened to the
    # whole box, where a turn is allowed.
    options = dataclasses.replace(
        STREAM_DEFAULTS, time_budget_us=None, max_restarts=6, global_fallback=False
    )
    solver = IKSolver(chain, options, seed=5)
    start = np.full(count, 2.9)
    solver.set_pose(start)
    starts = []
    for _ in range(3):
        r = solver.track(targets)
        starts += [p.start for p in r.pass_log]
        assert PassStart.RESTART_TURN not in starts, starts
        # SMOOTH: at most 0.1 rad a frame, so no wrist ever left its upper limit's side.
        assert np.all(r.q > 2.5), r.q
    assert starts.count(PassStart.RESTART_RANDOM) + starts.count(PassStart.RESTART_PARTIAL) >= 1
