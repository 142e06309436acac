"""Mimic joints: a follower moves at multiplier x its leader + offset, in FK, in the
exact gradient and Jacobian, in the limits, and through the URDF importer."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from solver import IKOptions, IKSolver
from solver.errors import InvalidModel
from solver.ik import pose_targets
from solver.model import Chain, Effector, Joint, JointKind, Mimic, NoteKind, build_chain
from solver.model.forward import link_poses
from solver.model.urdf import chain_from_urdf

from .helpers import mimic_gripper

PANDA = (Path(__file__).resolve().parent / "data" / "panda_kinematic.urdf").read_text()


def _unrolled(chain: Chain) -> Chain:
    """The same chain with every follower an ordinary joint (no limits to narrow)."""
    joints = [
        dataclasses.replace(
            j,
            mimic=None,
            lower=(-math.inf,) if j.kind is JointKind.CONTINUOUS else (-1e9,),
            upper=(math.inf,) if j.kind is JointKind.CONTINUOUS else (1e9,),
        )
        if j.mimic is not None
        else j
        for j in chain.joints
    ]
    return build_chain(joints, list(chain.effectors))


def _unrolled_q(chain: Chain, unrolled: Chain, q: np.ndarray) -> np.ndarray:
    values = dict(zip(chain.dof_names, q, strict=True))
    values.update(zip(chain.followers.names, chain.followers.values(q), strict=True))
    return np.array([values[n] for n in unrolled.dof_names])


def test_follower_is_not_a_variable_and_narrows_its_leader() -> None:
    chain = mimic_gripper()
    assert chain.dof_names == ("shoulder", "slide", "finger_a")
    assert chain.followers.names == ("finger_b", "pad")
    # pad = 0.02 finger_b + 0.01 = 0.02 (-1.5 a + 0.2) + 0.01: composed onto the leader.
    assert_allclose(chain.followers.multiplier, [-1.5, -0.03], rtol=1e-15)
    assert_allclose(chain.followers.offset, [0.2, 0.014], rtol=1e-15)
    # finger_b in [-1, 0.5] means a in [-0.2, 0.8] (a negative multiplier swaps the ends).
    assert_allclose(chain.lower, [-2.0, 0.0, -0.2], rtol=1e-15)
    assert_allclose(chain.upper, [2.0, 0.4, 0.8], rtol=1e-15)
    assert [n.kind for n in chain.notes] == [NoteKind.MIMIC_NARROWS_LEADER]
    assert chain.notes[0].joint == "finger_b"


def test_fk_equals_the_chain_with_the_followers_set_by_hand() -> None:
    chain = mimic_gripper()
    unrolled = _unrolled(chain)
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.uniform(chain.lower, chain.upper)
        a = link_poses(chain, q)
        b = link_poses(unrolled, _unrolled_q(chain, unrolled, q))
        for link in a:
            assert_allclose(a[link], b[link], rtol=0.0, atol=1e-15)


def test_a_solve_moves_the_followers_with_their_leader() -> None:
    chain = mimic_gripper()
    solver = IKSolver(chain, IKOptions(time_budget_us=None))
    rng = np.random.default_rng(5)
    for _ in range(10):
        goal = rng.uniform(chain.lower, chain.upper)
        result = solver.solve(pose_targets(chain, goal), seed=chain.mid_limits())
        assert result.success, result.status
        follower = chain.followers.values(result.q)
        assert np.all(follower[:1] >= -1.0 - 1e-12) and np.all(follower[:1] <= 0.5 + 1e-12)


_Z = np.array([0.0, 0.0, 1.0])


def _joint(name: str, parent: str, child: str, **kw: object) -> Joint:
    base: dict[str, object] = {
        "kind": JointKind.REVOLUTE,
        "axis": _Z,
        "lower": (-1.0,),
        "upper": (1.0,),
    }
    base.update(kw)
    return Joint(name=name, parent=parent, child=child, **base)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("joints", "field", "joint"),
    [
        pytest.param(
            [_joint("a", "w", "l1"), _joint("b", "l1", "l2", mimic=Mimic("zz"))],
            "mimic",
            "b",
            id="unknown_leader",
        ),
        pytest.param(
            [
                _joint("a", "w", "l1", mimic=Mimic("b")),
                _joint("b", "l1", "l2", mimic=Mimic("a")),
            ],
            "mimic",
            "a",
            id="cycle",
        ),
        pytest.param(
            [
                Joint(name="a", parent="w", child="l1", kind=JointKind.FIXED),
                _joint("b", "l1", "l2", mimic=Mimic("a")),
            ],
            "mimic",
            "b",
            id="fixed_leader",
        ),
        pytest.param(
            [
                _joint("a", "w", "l1"),
                Joint(
                    name="b",
                    parent="l1",
                    child="l2",
                    kind=JointKind.ROTATIONAL,
                    axes="xy",
                    lower=(-1.0, -1.0),
                    upper=(1.0, 1.0),
                    mimic=Mimic("a"),
                ),
            ],
            "mimic",
            "b",
            id="rotational_follower",
        ),
        pytest.param(
            [_joint("a", "w", "l1"), _joint("b", "l1", "l2", mimic=Mimic("a", math.nan))],
            "mimic.multiplier",
            "b",
            id="nan_multiplier",
        ),
        pytest.param(
            [_joint("a", "w", "l1"), _joint("b", "l1", "l2", mimic=Mimic("a", 1.0, 2e6))],
            "mimic.offset",
            "b",
            id="offset_beyond_1e6",
        ),
        # Each factor is finite and within bounds alone; composed they would be 1e12 (and
        # 1e200 x 1e200 gave inf: every frame then ended nonfinite).
        pytest.param(
            [
                _joint("a", "w", "l1"),
                _joint("b", "l1", "lb", mimic=Mimic("a", 1e6)),
                _joint("c", "lb", "l2", mimic=Mimic("b", 1e6)),
            ],
            "mimic.multiplier",
            "c",
            id="composed_multiplier_beyond_1e6",
        ),
    ],
)
def test_invalid_mimic(joints: list[Joint], field: str, joint: str) -> None:
    with pytest.raises(InvalidModel) as info:
        build_chain(joints, [Effector(name="t", link="l2")])
    assert (info.value.field, info.value.joint) == (field, joint)


@pytest.mark.parametrize(
    ("follower", "leader_range"),
    [
        # b = 2 a in [5, 6] needs a in [2.5, 3]: outside a's [-1, 1].
        (_joint("b", "l1", "l2", lower=(5.0,), upper=(6.0,), mimic=Mimic("a", 2.0)), (-1, 1)),
        # PR2's gripper: b = -a with both in [0, 0.548] leaves a only 0.
        (
            _joint("b", "l1", "l2", lower=(0.0,), upper=(0.548,), mimic=Mimic("a", -1.0)),
            (0.0, 0.548),
        ),
        # Held at 3 by multiplier 0, outside b's [-1, 1].
        (_joint("b", "l1", "l2", mimic=Mimic("a", 0.0, 3.0)), (-1, 1)),
    ],
)
def test_follower_limits_that_leave_the_leader_no_room_are_ignored_with_a_note(
    follower: Joint, leader_range: tuple[float, float]
) -> None:
    lo, hi = leader_range
    leader = _joint("a", "w", "l1", lower=(lo,), upper=(hi,))
    chain = build_chain([leader, follower], [Effector(name="t", link="l2")])
    assert (chain.lower[0], chain.upper[0]) == (lo, hi)
    assert [(n.kind, n.joint) for n in chain.notes] == [(NoteKind.MIMIC_LIMITS_IGNORED, "b")]


def test_multiplier_zero_holds_the_follower_at_its_offset() -> None:
    chain = build_chain(
        [_joint("a", "w", "l1"), _joint("b", "l1", "l2", mimic=Mimic("a", 0.0, 0.5))],
        [Effector(name="t", link="l2")],
    )
    assert chain.dof_names == ("a",)
    pose = link_poses(chain, np.array([0.25]))["l2"]
    assert_allclose(pose[:3, :3], _rz(0.75), rtol=0.0, atol=1e-15)


def _rz(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_urdf_mimic_finger_brings_its_leader_into_the_chain() -> None:
    # The right finger's tip alone: its joint follows finger_joint1, which is not on
    # the path, so the leader comes in as the variable.
    chain = chain_from_urdf(PANDA, base_link="panda_link0", tip_links="panda_rightfinger")
    assert chain.dof_names[-1] == "panda_finger_joint1"
    assert chain.followers.names == ("panda_finger_joint2",)
    both = chain_from_urdf(
        PANDA, base_link="panda_link0", tip_links=["panda_leftfinger", "panda_rightfinger"]
    )
    assert both.n_dof == 8
    q = np.array([0.1, -0.3, 0.2, -1.5, 0.1, 1.2, 0.4, 0.03])
    poses = link_poses(both, q)
    hand = poses["panda_hand"]
    # Both fingers open by 0.03 m along the hand's +y and -y.
    assert_allclose(
        np.linalg.inv(hand) @ poses["panda_leftfinger"][:, 3], [0, 0.03, 0.0584, 1], atol=1e-12
    )
    assert_allclose(
        np.linalg.inv(hand) @ poses["panda_rightfinger"][:, 3], [0, -0.03, 0.0584, 1], atol=1e-12
    )
