"""Pole targets and blend weights (issue 21 item 4), on CesiumMan's legs.

Geometry is measured from each answer's FK: the knee's side is the sign of its offset
from the hip-foot line along the direction from that line to the pole.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from solver.errors import InvalidProblem
from solver.ik import (
    STREAM_DEFAULTS,
    IKOptions,
    IKSolver,
    Pole,
    Target,
    default_pole_link,
    pole_node,
)
from solver.ik.poles import PoleShaper
from solver.model import (
    Chain,
    Effector,
    EffectorMode,
    Joint,
    JointKind,
    Mimic,
    Transform,
    build_chain,
    examples,
)
from solver.model.forward import effector_poses, link_poses
from solver.model.gltf import read_gltf
from solver.model.skeleton import SkeletonSettings, chain_from_skeleton
from tests.solver.skeleton_refs import asset_bytes

# CesiumMan: right leg nodes 3 (hip) 4 (knee) 5 (ankle) 6 (toe), left leg 7-10.
LEGS = tuple(f"node_{i}" for i in range(3, 11))
HIP, KNEE = "node_3", "node_4"


@pytest.fixture(scope="module")
def legs() -> Chain:
    skeleton = read_gltf(asset_bytes("CesiumMan.glb"))
    effectors = [
        Effector(name="right_foot", link="node_6"),
        Effector(name="left_foot", link="node_10"),
        Effector(name="left_knee", link="node_8", mode=EffectorMode.POSE),
    ]
    settings = SkeletonSettings(effectors=effectors, moving=LEGS)
    return chain_from_skeleton(skeleton, settings).chain


def foot(chain: Chain, q: np.ndarray, effector: int = 0) -> np.ndarray:
    return effector_poses(chain, q)[effector][:3, 3]


def bent_leg(chain: Chain) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A right-foot target that bends the knee (the foot raised by 30% of the hip-foot
    distance), and the unit direction across the leg that the poles lie along."""
    rest = np.zeros(chain.n_dof)
    hip = link_poses(chain, rest)[HIP][:3, 3]
    toe = foot(chain, rest)
    target = toe + 0.3 * (hip - toe)
    axis = (hip - toe) / np.linalg.norm(hip - toe)
    across = np.cross(axis, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    return target, 0.5 * (hip + target), across


def knee_side(chain: Chain, q: np.ndarray, across: np.ndarray) -> float:
    """The knee's offset from the hip-foot line along ``across`` [m]."""
    links = link_poses(chain, q)
    hip = links[HIP][:3, 3]
    knee = links[KNEE][:3, 3] - hip
    axis = foot(chain, q) - hip
    axis /= np.linalg.norm(axis)
    return float((knee - (knee @ axis) * axis) @ across)


def test_default_pole_bone_is_the_knee(legs: Chain) -> None:
    assert default_pole_link(legs, 0) == KNEE
    assert pole_node(legs, 0, None) == legs.compiled.link_node[KNEE]


# CesiumMan's left arm: chest 12, shoulder 16, elbow 17, hand 18; spine 11, hips 2; the
# left leg's hip 7, knee 8, ankle 9.
ARM = ("node_16", "node_17", "node_18")


@pytest.mark.parametrize(
    ("effector_bones", "moving"),
    [
        (("node_18",), None),  # a lone hand: its limb stops at the chest's branch
        (("node_18", "node_9"), None),  # a hand and a foot share only the hips
        (("node_18", "node_14"), None),  # both hands: the chest is shared
        (("node_18",), ARM),  # an arm-only session: nothing above the shoulder moves
    ],
)
def test_a_hand_s_default_pole_bone_is_its_elbow(
    effector_bones: tuple[str, ...], moving: tuple[str, ...] | None
) -> None:
    """Whatever the other effectors and ``moving``: it was the lower spine for a lone
    hand, the shoulder for a hand beside a foot, the spine in an arm-only session."""
    skeleton = read_gltf(asset_bytes("CesiumMan.glb"))
    effectors = [Effector(name=f"e{i}", link=b) for i, b in enumerate(effector_bones)]
    settings = SkeletonSettings(effectors=effectors, moving=moving)
    chain = chain_from_skeleton(skeleton, settings).chain
    assert default_pole_link(chain, 0) == "node_17"
    if "node_9" in effector_bones:
        assert default_pole_link(chain, 1) == "node_8"  # and the foot's is its knee


def test_a_pole_on_a_bone_nothing_moves_is_refused_with_the_bones_that_move() -> None:
    skeleton = read_gltf(asset_bytes("CesiumMan.glb"))
    settings = SkeletonSettings(effectors=[Effector(name="hand", link="node_18")], moving=ARM)
    chain = chain_from_skeleton(skeleton, settings).chain
    for still in ("node_11", "node_12", "node_16"):  # spine, chest; shoulder turned in place
        with pytest.raises(InvalidProblem, match="no moving joint moves the origin") as info:
            pole_node(chain, 0, still)
        assert "(links whose origin moves: 'node_18', 'node_17')" in str(info.value)
    assert pole_node(chain, 0, "node_17") == chain.compiled.link_node["node_17"]


def _arm_with_gripper(side: str) -> Chain:
    """A 3-joint arm (shoulder, elbow, wrist) with a two-finger gripper whose right
    finger mimics the left (a URDF's usual parallel gripper), one effector on the
    ``side`` finger."""
    up = Transform(translation=np.array([0.0, 0.0, 0.3]))
    y_axis = np.array([0.0, 1.0, 0.0])

    def hinge(name: str, parent: str, child: str) -> Joint:
        kind = JointKind.REVOLUTE
        return Joint(
            name=name, parent=parent, child=child, kind=kind, origin=up, axis=y_axis,
            lower=(-2.0,), upper=(2.0,),
        )  # fmt: skip

    def finger(side: str, mimic: Mimic | None) -> Joint:
        name, child, kind = f"{side}_finger_joint", f"{side}_finger", JointKind.PRISMATIC
        return Joint(
            name=name, parent="hand", child=child, kind=kind, axis=y_axis, mimic=mimic,
            lower=(0.0,), upper=(0.04,),
        )  # fmt: skip

    joints = [
        hinge("shoulder", "base", "upper"),
        hinge("elbow", "upper", "fore"),
        hinge("wrist", "fore", "hand"),
        finger("left", None),
        finger("right", Mimic(joint="left_finger_joint")),
    ]
    return build_chain(joints, [Effector(name="tip", link=f"{side}_finger")])


def test_a_finger_that_mimics_the_other_is_no_branch_of_its_arm() -> None:
    """The other finger moves on the leader's variable, which the follower reads too:
    the hand is no branch for either (a review: Panda's right finger, PR2's and Talos's
    grippers lost their default, the hand counted as a branch)."""
    left, right = _arm_with_gripper("left"), _arm_with_gripper("right")
    assert default_pole_link(left, 0) == default_pole_link(right, 0) == "fore"


def test_a_rigid_finger_beside_its_gripper_s_motor_is_no_limb() -> None:
    """Talos's reduced models: the finger hangs by fixed joints from the gripper base,
    and the gripper's one variable turns a motor link beside it. The base branches on
    a variable the fingertip does not read, but nothing of the fingertip's own bends
    below it: the limb goes on to the arm (a review: the default was a rigid finger
    link, or none)."""
    arm = _arm_with_gripper("left")
    fixed, hinge = JointKind.FIXED, JointKind.REVOLUTE
    step = Transform(translation=np.array([0.0, 0.0, 0.05]))
    extra = [
        Joint(name="base_mount", parent="hand", child="gripper_base", kind=fixed, origin=step),
        Joint(name="finger_mount", parent="gripper_base", child="finger", kind=fixed, origin=step),
        Joint(name="tip_mount", parent="finger", child="fingertip", kind=fixed, origin=step),
        Joint(
            name="gripper_motor", parent="gripper_base", child="motor", kind=hinge,
            origin=step, lower=(0.0,), upper=(1.0,),
        ),
    ]  # fmt: skip
    chain = build_chain([*arm.joints, *extra], [Effector(name="tip", link="fingertip")])
    assert default_pole_link(chain, 0) == "fore"


def test_a_bone_on_its_parent_joint_s_axis_is_no_pole_bone() -> None:
    """A turn about the vertical carries a link whose origin is on that very axis (as
    Panda's link2 on joint 1's, or a BVH bone with no offset at its parent's joint): no
    variable moves that origin, so it is neither the default nor accepted by name (a
    review: a pole there did nothing, silently)."""
    z_axis, y_axis = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])
    up = Transform(translation=np.array([0.0, 0.0, 0.3]))
    hinge = JointKind.REVOLUTE

    def joint(name: str, parent: str, child: str, axis: np.ndarray) -> Joint:
        return Joint(
            name=name, parent=parent, child=child, kind=hinge, origin=up, axis=axis,
            lower=(-2.0,), upper=(2.0,),
        )  # fmt: skip

    chain = build_chain(
        [
            joint("yaw", "base", "turret", z_axis),  # turns about the vertical
            joint("lift", "turret", "boom", y_axis),  # its origin on the yaw axis
            joint("bend", "boom", "arm", y_axis),
            joint("wrist", "arm", "hand", y_axis),
        ],
        [Effector(name="tip", link="hand", tip_offset=np.array([0.0, 0.0, 0.1]))],
    )
    with pytest.raises(InvalidProblem, match="no moving joint moves the origin of link 'boom'"):
        pole_node(chain, 0, "boom")
    assert default_pole_link(chain, 0) == "arm"  # the middle joint that moves: the bend


def test_a_terminator_ends_the_limb_as_moving_does() -> None:
    """two_arm_torso's shoulders are terminators: the spine does not move for a hand,
    so the shoulder's origin stays put, the default is the elbow and a pole on the
    shoulder or the chest is refused (a review: the rule looked at fixed joints only)."""
    chain = examples.EXAMPLES["two_arm_torso"]()
    assert default_pole_link(chain, 0) == "left_fore"
    for still in ("left_upper", "chest"):
        with pytest.raises(InvalidProblem, match="no moving joint moves the origin"):
            pole_node(chain, 0, still)


def test_a_joint_locked_by_its_limits_moves_no_limb() -> None:
    """A URDF freezes a joint with lower = upper: it moves nothing, so it neither
    stretches the limb above the arm (the default stays the elbow, not the shoulder)
    nor makes a pole on a link only it carries look useful (a review: locked joints
    counted as moving). A locked finger beside the hand is no branch either."""
    y_axis = np.array([0.0, 1.0, 0.0])
    hinge, fixed = JointKind.REVOLUTE, JointKind.FIXED

    def up(z: float) -> Transform:
        return Transform(translation=np.array([0.0, 0.0, z]))

    def joint(name: str, parent: str, child: str, z: float, lo: float, hi: float) -> Joint:
        return Joint(
            name=name, parent=parent, child=child, kind=hinge, origin=up(z), axis=y_axis,
            lower=(lo,), upper=(hi,),
        )  # fmt: skip

    chain = build_chain(
        [
            Joint(name="post", parent="base", child="mast", kind=fixed, origin=up(0.5)),
            joint("lift", "mast", "boom", 0.5, 0.4, 0.4),  # locked
            joint("shoulder", "boom", "upper", 0.3, -2.0, 2.0),
            joint("elbow", "upper", "fore", 0.3, -2.0, 2.0),
            joint("wrist", "fore", "hand", 0.3, -2.0, 2.0),
            joint("finger", "hand", "finger_tip", 0.1, -1.0, 1.0),
            joint("thumb", "hand", "thumb_tip", 0.05, 0.0, 0.0),  # locked
        ],
        [Effector(name="tip", link="finger_tip", tip_offset=np.array([0.0, 0.0, 0.1]))],
    )
    # From the boom (the top: nothing free moves it) the arm is 1.1 m to the tip: the
    # elbow is at 0.6 m, nearest half; counted from the mast, the shoulder was; had the
    # locked thumb been a branch, the hand would have been the top and no link the middle.
    assert default_pole_link(chain, 0) == "fore"
    with pytest.raises(InvalidProblem, match="no moving joint moves the origin of link 'upper'"):
        pole_node(chain, 0, "upper")
    assert pole_node(chain, 0, "fore") >= 0


def test_a_thousand_fixed_joints_deep_is_no_recursion() -> None:
    """Session creation computes every effector's default (service ChainView): a
    recursive walk raised RecursionError, a 500, past ~400 fixed joints."""
    step = Transform(translation=np.array([0.01, 0.0, 0.0]))
    fixed = JointKind.FIXED
    joints = [
        Joint(name=f"j{i}", parent=f"l{i}", child=f"l{i + 1}", kind=fixed, origin=step)
        for i in range(1000)
    ]
    hinge = JointKind.REVOLUTE
    limits = {"lower": (-1.0,), "upper": (1.0,)}
    joints.append(Joint(name="r", parent="l1000", child="tip", kind=hinge, **limits))
    chain = build_chain(joints, [Effector(name="e", link="tip")])
    assert default_pole_link(chain, 0) is None  # nothing on it can bend


def test_a_fixed_frame_on_the_forearm_is_not_a_branch_of_the_arm() -> None:
    """A sensor or attachment frame hung by a fixed joint (a URDF's camera link) does not
    end the limb: the default stays the arm's middle, not a bone below the attachment."""
    arm = examples.EXAMPLES["humanoid_arm"]()
    forearm = next(j for j in arm.joints if j.child == "forearm")
    camera = Joint(
        name="camera_mount",
        parent="forearm",
        child="camera",
        kind=JointKind.FIXED,
        origin=forearm.origin,
    )
    with_camera = build_chain([*arm.joints, camera], list(arm.effectors))
    assert default_pole_link(arm, 0) == default_pole_link(with_camera, 0) == "forearm"


def test_a_pole_flips_the_knee_to_its_side(legs: Chain) -> None:
    target, middle, across = bent_leg(legs)
    solver = IKSolver(legs)
    sides = {}
    for sign in (1.0, -1.0):
        pole = Pole(middle + sign * 0.5 * across)
        result = solver.solve([Target(effector="right_foot", position=target, pole=pole)])
        assert result.success, result.status
        assert np.linalg.norm(foot(legs, result.q) - target) <= 1e-4 + 1e-9
        sides[sign] = knee_side(legs, result.q, across)
        # Flip on demand: from the answer on this side, the other pole brings it across.
        flipped = solver.solve(
            [Target(effector="right_foot", position=target, pole=Pole(middle - sign * across))],
            result.q,
        )
        assert flipped.success
        assert -sign * knee_side(legs, flipped.q, across) > 0.02
    assert sides[1.0] > 0.02 and sides[-1.0] < -0.02


def test_a_named_pole_bone_and_bad_poles(legs: Chain) -> None:
    target, middle, across = bent_leg(legs)
    solver = IKSolver(legs)
    named = Pole(middle - 0.5 * across, link=KNEE)
    result = solver.solve([Target(effector="right_foot", position=target, pole=named)])
    assert result.success and knee_side(legs, result.q, across) < -0.02
    with pytest.raises(InvalidProblem, match="not on the effector's path"):
        solver.solve([Target(effector="right_foot", position=target, pole=Pole(target, "node_8"))])
    # A name that is no link of the chain is a typo, said as such with the closest name.
    typo = KNEE + "_"
    with pytest.raises(InvalidProblem, match=f"no link '{typo}'.*did you mean '{KNEE}'"):
        solver.solve([Target(effector="right_foot", position=target, pole=Pole(target, typo))])
    with pytest.raises(InvalidProblem, match="finite"):
        Pole([0.0, math.nan, 0.0])


def test_a_stream_s_first_frame_swings_an_arm_to_a_pole_behind_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """CesiumMan's left arm (shoulder node 16, elbow 17, hand 18) from its middle pose:
    a pole on the far side of the shoulder-hand line. A stream's first frame has no
    next frame to finish the swing, so its shaping pass may run longer: the elbow ends
    on the pole's side (with a later frame's 15 iterations it stopped a quarter turn
    short: a new user's report)."""
    settings = SkeletonSettings(
        effectors=[Effector(name="hand_l", link="node_18")], moving=("node_16", "node_17")
    )
    arm = chain_from_skeleton(read_gltf(asset_bytes("CesiumMan.glb")), settings).chain
    start = arm.mid_limits()
    shoulder = link_poses(arm, start)["node_16"][:3, 3]
    hand = effector_poses(arm, start)[0][:3, 3]
    target = shoulder + 0.7 * (hand - shoulder) + np.array([0.0, 0.05, 0.0])
    line = (target - shoulder) / np.linalg.norm(target - shoulder)
    across = np.cross(line, [0.0, 1.0, 0.0])
    across /= np.linalg.norm(across)
    middle = 0.5 * (shoulder + target)
    pole = Pole(middle + 0.5 * across, link="node_17")

    def elbow_towards_pole(result_q: np.ndarray) -> float:
        offset = link_poses(arm, result_q)["node_17"][:3, 3] - middle
        offset -= (offset @ line) * line
        return float(offset @ across / np.linalg.norm(offset))

    # No time budget: the shaping pass's half of it must not be what stops it here.
    options = replace(STREAM_DEFAULTS, time_budget_us=None)
    frame = [Target(effector="hand_l", position=target, pole=pole)]

    def first_frame() -> np.ndarray:
        solver = IKSolver(arm, options)
        solver.set_pose(start)
        result = solver.track(frame)
        assert result.success, result.status
        return result.q

    assert elbow_towards_pole(first_frame()) > 0.9
    # The cap each shaping pass got: a stream's first frame, a later one, a one-shot solve.
    caps: list[int] = []
    shape = PoleShaper.solve

    def recording(self: PoleShaper, *args: Any) -> Any:
        caps.append(args[3])
        return shape(self, *args)

    monkeypatch.setattr(PoleShaper, "solve", recording)
    solver = IKSolver(arm, options)
    solver.set_pose(start)
    solver.track(frame)
    solver.track(frame)
    solver.solve(frame)
    assert caps == [60, 15, 60]
    monkeypatch.setattr("solver.ik.solver.SHAPING_FIRST_MAX_ITER", 15)
    assert elbow_towards_pole(first_frame()) < 0.5  # the case the longer pass is for


def test_a_pole_never_fails_a_reachable_frame(legs: Chain) -> None:
    # A pole far away on the wrong side of everything: the frame still solves.
    target, middle, across = bent_leg(legs)
    pole = Pole(middle + 100.0 * across + 50.0)
    result = IKSolver(legs).solve([Target(effector="right_foot", position=target, pole=pole)])
    assert result.success


def test_the_bend_side_follows_a_moving_pole_without_popping(legs: Chain) -> None:
    # The pole swings 1 rad about the hip-foot line (with a +-90 deg bound on the hip's
    # middle Euler angle, the default until 2026-11-29, the hip stopped at that bound
    # after 1.6 rad: bench/history/2026-11-29-bvh-euler-wall.md).
    target, middle, across = bent_leg(legs)
    hip = link_poses(legs, np.zeros(legs.n_dof))[HIP][:3, 3]
    line = (hip - target) / np.linalg.norm(hip - target)
    round_ = np.cross(line, across)
    solver = IKSolver(legs, STREAM_DEFAULTS)
    solver.track([Target(effector="right_foot", position=target, pole=Pole(middle + across))])
    steps = []
    for angle in np.linspace(0.0, 1.0, 31)[1:]:
        towards = math.cos(angle) * across + math.sin(angle) * round_
        before = solver.q.copy()
        result = solver.track(
            [Target(effector="right_foot", position=target, pole=Pole(middle + 0.5 * towards))]
        )
        assert result.success
        steps.append(float(np.abs(result.q - before).max()))
        # The knee's direction round the line follows the pole's.
        knee = link_poses(legs, result.q)[KNEE][:3, 3] - hip
        offset = knee - (knee @ line) * line
        knee_angle = math.atan2(offset @ round_, offset @ across)
        assert abs(knee_angle - angle) <= 0.25, (angle, knee_angle)
    # No pop: no frame's largest joint step is more than 3x the median one.
    assert max(steps) <= 3.0 * float(np.median(steps))


def test_a_still_pole_leaves_the_legs_still(legs: Chain) -> None:
    """The same frame, poles and all, again and again (a character standing still):
    the answers come to rest with the knees on their poles' side. With the shaped
    answer taken every frame, these ball-joint knees moved 1-2 cm and their joints up
    to the step limit every frame, for ever (a game developer's trial)."""
    target, middle, across = bent_leg(legs)
    left = foot(legs, np.zeros(legs.n_dof), 1) + [0.0, 0.1, 0.05]
    knee_pole = Pole(middle + 0.5 * across)
    left_pole = Pole(left + np.array([0.0, 0.5, 0.6]))
    frame = [
        Target(effector="right_foot", position=target, pole=knee_pole),
        Target(effector="left_foot", position=left, pole=left_pole),
    ]
    solver = IKSolver(legs, replace(STREAM_DEFAULTS, time_budget_us=None))
    answers = []
    for _ in range(60):
        result = solver.track(frame)
        assert result.success, result.status
        answers.append(result.q.copy())
    assert np.abs(np.diff(answers[-20:], axis=0)).max() == 0.0
    assert knee_side(legs, answers[-1], across) > 0.02


def test_a_held_frame_skips_the_shaping_and_answers_the_same(
    legs: Chain, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A frame the same as the last one that kept its plain answer keeps it without the
    shaping pass (a standing character paid for it every frame): the answers are the
    same, bit for bit, as with the shaping pass run every time."""
    target, middle, across = bent_leg(legs)
    frame = [Target(effector="right_foot", position=target, pole=Pole(middle + 0.5 * across))]

    def stream() -> tuple[list[np.ndarray], int]:
        solver = IKSolver(legs, replace(STREAM_DEFAULTS, time_budget_us=None))
        shaped = 0
        nearer = PoleShaper._nearer

        def counting(self: PoleShaper, *args: Any) -> bool:
            nonlocal shaped
            shaped += 1
            return nearer(self, *args)

        with monkeypatch.context() as m:
            m.setattr(PoleShaper, "_nearer", counting)
            answers = [solver.track(frame).q.copy() for _ in range(40)]
        return answers, shaped

    held, shaped_held = stream()
    monkeypatch.setattr(PoleShaper, "_inputs", lambda self, *args: object())  # never equal
    every, shaped_every = stream()
    assert all(np.array_equal(a, b) for a, b in zip(held, every, strict=True))
    assert shaped_every >= 35 and shaped_held <= 5


def test_a_still_pole_leaves_a_leg_reaching_out_of_range_still(legs: Chain) -> None:
    """A foot target beyond the leg's length (a game stretching a limb past its reach):
    no answer solves the frame, and the one shaped by the pole was taken whenever the
    plain one missed too, so the joints kept stepping ~0.09 rad a frame (a review)."""
    _, middle, across = bent_leg(legs)
    rest = np.zeros(legs.n_dof)
    hip = link_poses(legs, rest)[HIP][:3, 3]
    far = hip + 1.6 * (foot(legs, rest) - hip) + 0.3 * across
    frame = [Target(effector="right_foot", position=far, pole=Pole(middle + 0.5 * across))]
    solver = IKSolver(legs, replace(STREAM_DEFAULTS, time_budget_us=None))
    answers = []
    for _ in range(40):
        result = solver.track(frame)
        assert not result.success  # out of reach
        answers.append(result.q.copy())
    assert np.abs(np.diff(answers[-10:], axis=0)).max() == 0.0


def test_weight_zero_frees_an_effector(legs: Chain) -> None:
    target, _, _ = bent_leg(legs)
    left = foot(legs, np.zeros(legs.n_dof), 1) + [0.0, 0.1, 0.0]
    far = np.array([10.0, 10.0, 10.0])  # unreachable
    solver = IKSolver(legs)
    alone = solver.solve([Target(effector="left_foot", position=left)])
    result = solver.solve(
        [
            Target(effector="left_foot", position=left),
            Target(effector="right_foot", position=far, position_weight=0.0),
        ]
    )
    assert result.success and alone.success
    assert np.linalg.norm(foot(legs, result.q, 1) - left) <= 1e-4 + 1e-9
    # Not pulled at all: the answer is the one without that target.
    assert np.allclose(result.q, alone.q, atol=1e-6)
    errors = {e.name: e for e in result.effectors}
    assert errors["right_foot"].position_error_m is None
    # The same target at full weight fails the frame.
    full = solver.solve(
        [Target(effector="left_foot", position=left), Target(effector="right_foot", position=far)]
    )
    assert not full.success


def test_a_limb_at_weight_zero_holds_still_in_a_stream(legs: Chain) -> None:
    # IK faded out (every part of the only target at weight 0) for a second of frames:
    # the answer is the one without the target, the pose of the frame before. It used
    # to creep towards the rest pose under the stream's null-space step (CesiumMan's
    # leg: 0.3 rad of joint motion in 60 frames); now the limb is held.
    target, middle, across = bent_leg(legs)
    solver = IKSolver(legs, STREAM_DEFAULTS)
    solver.set_pose(np.zeros(legs.n_dof))
    assert solver.track([Target(effector="right_foot", position=target)]).success
    held = solver.q.copy()
    # A pole on the faded target changes nothing either: the held limb has no bend to pick.
    pole = Pole(middle + 0.5 * across)
    faded = [
        Target(
            effector="right_foot",
            position=target + [0.0, 0.2, 0.0],
            position_weight=0.0,
            pole=pole,
        )
    ]
    for _ in range(60):
        result = solver.track(faded)
        assert result.success
    assert np.array_equal(solver.q, held)
    assert {e.name: e.position_error_m for e in result.effectors} == {"right_foot": None}
    # Another limb's target still moves that limb, and the faded one stays put (1 cm:
    # within the stream's default step limit of 0.1 rad per frame).
    left = foot(legs, held, 1) + [0.0, 0.01, 0.0]
    both = solver.track([*faded, Target(effector="left_foot", position=left)])
    assert both.success
    assert np.linalg.norm(foot(legs, both.q, 1) - left) <= 1e-4 + 1e-9
    assert np.allclose(foot(legs, both.q, 0), foot(legs, held, 0), atol=1e-9)


def test_a_weight_zero_target_is_as_if_left_out_of_a_one_shot_solve(legs: Chain) -> None:
    # The left knee's pose target at weight 0 in both parts beside the left foot's:
    # the answer is the foot's alone. The limb split used to take the knee's target,
    # which has the rows to place the leg, as the one that fixes the trunk: 1.2-3.9
    # rad apart and about 5x the time (review of 297ff97).
    rng = np.random.default_rng(1)
    solver = IKSolver(legs)
    for k in range(20):
        goal = np.clip(rng.normal(0.0, 0.4, legs.n_dof), legs.lower, legs.upper)
        seed = np.clip(rng.normal(0.0, 0.4, legs.n_dof), legs.lower, legs.upper)
        poses = effector_poses(legs, goal)
        left = Target(effector="left_foot", position=poses[1][:3, 3])
        knee = Target(
            effector="left_knee",
            position=poses[2][:3, 3] + 0.3,
            rotation=poses[2][:3, :3].T,
            position_weight=0.0,
            rotation_weight=0.0,
        )
        alone = solver.solve([left], seed=seed, rng=np.random.default_rng(k))
        both = solver.solve([left, knee], seed=seed, rng=np.random.default_rng(k))
        assert both.success == alone.success
        assert np.allclose(both.q, alone.q, atol=1e-9), k


def test_rotation_weight_zero_frees_the_orientation(legs: Chain) -> None:
    rest = np.zeros(legs.n_dof)
    pose = effector_poses(legs, rest)[2]
    turned = pose[:3, :3] @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    solver = IKSolver(legs)
    result = solver.solve(
        [Target(effector="left_knee", position=pose[:3, 3], rotation=turned, rotation_weight=0.0)]
    )
    assert result.success
    assert np.allclose(result.q, rest, atol=1e-6)  # the position holds, nothing turns
    assert result.effectors[0].rotation_error_rad is None


def test_a_weight_in_between_lands_between(legs: Chain) -> None:
    target, _, _ = bent_leg(legs)
    rest = np.zeros(legs.n_dof)
    start = foot(legs, rest)
    solver = IKSolver(legs)
    reached = []
    for w in (0.25, 0.5, 0.75):
        result = solver.solve([Target(effector="right_foot", position=target, position_weight=w)])
        assert result.success
        reached.append(foot(legs, result.q))
        expected = start + w * (target - start)
        assert np.linalg.norm(reached[-1] - expected) <= 1e-3
    distances = [float(np.linalg.norm(p - target)) for p in reached]
    assert distances[0] > distances[1] > distances[2] > 1e-3


def test_a_soft_weight_never_fails_the_frame(legs: Chain) -> None:
    far = np.array([10.0, 10.0, 10.0])
    result = IKSolver(legs).solve(
        [Target(effector="right_foot", position=far, position_weight=0.5)]
    )
    assert result.success


def test_a_soft_rotation_lands_between(legs: Chain) -> None:
    rest = np.zeros(legs.n_dof)
    pose = effector_poses(legs, rest)[2]
    c, s = math.cos(0.6), math.sin(0.6)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    target = Target(
        effector="left_knee", position=pose[:3, 3], rotation=pose[:3, :3] @ turn,
        rotation_weight=0.5,
    )  # fmt: skip
    result = IKSolver(legs).solve([target])
    assert result.success
    got = effector_poses(legs, result.q)[2][:3, :3]
    angle = math.acos(min(1.0, (np.trace(pose[:3, :3].T @ got) - 1.0) / 2.0))
    assert abs(angle - 0.3) <= 1e-2


@pytest.mark.parametrize("bad", [-0.1, 1.5, math.nan, math.inf, "1", True, None])
def test_bad_weights_are_refused(bad: object) -> None:
    with pytest.raises(InvalidProblem, match="position_weight"):
        Target(effector="right_foot", position=[0.0, 0.0, 0.0], position_weight=bad)  # type: ignore[arg-type]
    with pytest.raises(InvalidProblem, match="rotation_weight"):
        Target.from_row("right_foot", np.zeros(15), 1, rotation_weight=bad)  # type: ignore[arg-type]


def test_weights_reset_between_frames(legs: Chain) -> None:
    # A weighted frame then a plain one: the plain one is judged at full weight again.
    solver = IKSolver(legs, IKOptions())
    far = np.array([10.0, 10.0, 10.0])
    assert solver.solve([Target(effector="right_foot", position=far, position_weight=0.0)]).success
    assert not solver.solve([Target(effector="right_foot", position=far)]).success


def test_a_weight_on_a_part_the_effector_lacks_changes_nothing(legs: Chain) -> None:
    # right_foot is a position effector: a rotation weight has nothing to act on.
    target, _, _ = bent_leg(legs)
    plain = IKSolver(legs).solve([Target(effector="right_foot", position=target)])
    weighted = IKSolver(legs).solve(
        [Target(effector="right_foot", position=target, rotation_weight=0.5)]
    )
    assert plain.success and weighted.success
    assert np.array_equal(plain.q, weighted.q)
