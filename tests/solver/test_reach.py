"""A position target beyond an effector's reach (solver/ik/reach.py): the bound holds
on every test chain; such a frame is answered not_reached, never budget_exhausted, and
a REACH frame skips its global search, which cannot solve it."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from solver.ik import STREAM_DEFAULTS, IKOptions, IKSolver, IKStatus, Target
from solver.ik.continuity import Continuity
from solver.ik.reach import ReachBounds
from solver.model import Effector, EffectorMode, Joint, JointKind, Mimic, Transform, build_chain
from solver.model.examples import panda_arm
from solver.model.forward import effector_poses

from .helpers import CHAINS


@pytest.mark.parametrize("name", sorted(CHAINS))
def test_no_pose_puts_an_effector_beyond_its_bound(name: str, rng: np.random.Generator) -> None:
    chain = CHAINS[name]()
    bounds = ReachBounds(chain).bound
    pulled = {
        e.name for e in chain.effectors if e.mode in (EffectorMode.POSITION, EffectorMode.POSE)
    }
    assert set(bounds) == pulled, name  # aim effectors: no point to place
    lower = np.maximum(chain.lower, -np.pi)
    upper = np.minimum(chain.upper, np.pi)
    farthest = dict.fromkeys(bounds, 0.0)
    for _ in range(300):
        poses = effector_poses(chain, rng.uniform(lower, upper))
        for e, pose in zip(chain.effectors, poses, strict=True):
            if e.name in bounds:
                distance = float(np.linalg.norm(pose[:3, 3]))
                assert distance <= bounds[e.name] + 1e-9, (name, e.name)
                farthest[e.name] = max(farthest[e.name], distance)
    # Not a bound so loose that it proves nothing: the sampled poses come within half.
    assert all(farthest[n] >= 0.5 * bounds[n] for n in bounds), (farthest, bounds)


def _two_links(**slide: Any) -> Any:
    """Two revolute links of 0.3 and 0.2 m, then a prismatic slide (``slide``'s limits)."""
    z, x = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    joints = [
        Joint(
            name="j1", parent="base", child="l1", kind=JointKind.REVOLUTE, axis=z,
            lower=(-3.0,), upper=(3.0,),
        ),
        Joint(
            name="j2", parent="l1", child="l2", kind=JointKind.REVOLUTE,
            origin=Transform(0.3 * x), axis=z, lower=(-3.0,), upper=(3.0,),
        ),
        Joint(
            name="s", parent="l2", child="l3", kind=JointKind.PRISMATIC,
            origin=Transform(0.2 * x), axis=x, **slide,
        ),
    ]  # fmt: skip
    tip = Effector(
        name="tip", link="l3", tip_offset=np.array([0.0, 0.0, 0.05]), mode=EffectorMode.POSITION
    )
    return build_chain(joints, [tip])


def test_the_bound_is_the_links_the_slide_and_the_tip() -> None:
    assert ReachBounds(_two_links(lower=(-0.1,), upper=(0.4,))).bound["tip"] == pytest.approx(
        0.3 + 0.2 + 0.4 + 0.05
    )
    # A slide without limits reaches anywhere: nothing is ever beyond it.
    unlimited = ReachBounds(_two_links(lower=(-np.inf,), upper=(np.inf,)))
    assert unlimited.bound["tip"] == np.inf
    far = [Target(effector="tip", position=np.array([1e6, 0.0, 0.0]))]
    assert not unlimited.beyond(far, IKOptions())


def test_a_slide_following_a_follower_reaches_its_leader_s_range() -> None:
    """F2 slides as -F1 = L, L in [0, 1]; F1's own limits contradict its map and are
    ignored (a model note): the bound takes the range F2 really has (a review found
    0.6 m taken from F1's declared limits, so a reachable 0.9 m target read beyond)."""
    z, x = np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])
    joints = [
        Joint(
            name="L", parent="base", child="a", kind=JointKind.REVOLUTE, axis=z,
            lower=(0.0,), upper=(1.0,),
        ),
        Joint(
            name="F1", parent="a", child="b", kind=JointKind.REVOLUTE, axis=z,
            lower=(0.5,), upper=(0.6,), mimic=Mimic("L", -1.0, 0.0),
        ),
        Joint(
            name="F2", parent="b", child="c", kind=JointKind.PRISMATIC, axis=x,
            lower=(-2.0,), upper=(2.0,), mimic=Mimic("F1", -1.0, 0.0),
        ),
    ]  # fmt: skip
    chain = build_chain(joints, [Effector(name="tip", link="c")])
    assert chain.notes  # F1's limits were set aside
    reach = ReachBounds(chain)
    assert reach.bound["tip"] >= 1.0
    target = [Target(effector="tip", position=np.array([0.9, 0.0, 0.0]))]
    assert not reach.beyond(target, IKOptions())
    assert IKSolver(chain).solve(target).success


def test_a_target_beyond_reach_is_not_reached_whatever_the_budget() -> None:
    chain = panda_arm(EffectorMode.POSITION)
    (effector,) = chain.effector_names
    bound = ReachBounds(chain).bound[effector]
    far = [Target(effector=effector, position=np.array([bound + 0.05, 0.0, 0.3]))]
    # 100 us: the restarts are cut by the time, which used to read budget_exhausted.
    tight = IKOptions(time_budget_us=100.0)
    r = IKSolver(chain, tight).solve(far)
    assert r.status is IKStatus.NOT_REACHED and r.termination.value == "deadline"
    # The restarts still run, and the arm is stretched towards the target.
    r = IKSolver(chain, IKOptions(time_budget_us=None, max_restarts=20)).solve(far)
    assert r.status is IKStatus.NOT_REACHED and r.restarts == 20
    start = effector_poses(chain, chain.mid_limits())[0][:3, 3]
    assert r.effectors[0].position_error_m < float(np.linalg.norm(start - far[0].position)) - 0.3
    # A target within the bound is judged as before; so is a weighted one, which aims
    # short of where it points.
    near = [Target(effector=effector, position=np.array([0.3, 0.1, 0.5]))]
    weighted = [Target(effector=effector, position=far[0].position, position_weight=0.5)]
    assert not ReachBounds(chain).beyond(near, tight)
    assert not ReachBounds(chain).beyond(weighted, tight)


def test_a_reach_frame_beyond_reach_skips_the_global_fallback() -> None:
    chain = panda_arm(EffectorMode.POSITION)
    # The stream defaults: restarts within a radius, then the global search.
    options = replace(STREAM_DEFAULTS, continuity=Continuity.REACH, time_budget_us=None)
    solver = IKSolver(chain, options)
    calls = []
    frame = solver._frame

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append(kwargs.get("stream"))
        return frame(*args, **kwargs)

    solver._frame = counted  # type: ignore[method-assign]
    (effector,) = chain.effector_names
    bound = ReachBounds(chain).bound[effector]
    r = solver.track([Target(effector=effector, position=np.array([0.0, bound + 0.1, 0.2]))])
    assert not r.success and len(calls) == 1  # no second, global search
    # An unreachable target within the bound still gets the global search: the bound
    # cannot tell it from a reachable one (below the base, out of the arm's reach from
    # its shoulder, nearer the root than the sum of the links).
    low = [Target(effector=effector, position=np.array([0.2, 0.0, -0.9]))]
    assert not ReachBounds(chain).beyond(low, options)
    assert not solver.track(low).success and len(calls) == 3
