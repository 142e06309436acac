"""chain_from_skeleton: defaults and per-bone settings, bone quaternions reproduced by an
independent FK, and hands and feet of every shipped character reaching targets."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import pytransform3d.rotations as pr
from numpy.testing import assert_allclose

from solver.errors import InvalidModel
from solver.ik import STREAM_DEFAULTS, IKOptions, IKSolver, Target, pose_targets
from solver.model import Effector, EffectorMode, JointKind
from solver.model.bvh import read_bvh
from solver.model.forward import effector_poses
from solver.model.gltf import read_gltf
from solver.model.skeleton import (
    Bone,
    BoneSettings,
    FreeRoot,
    Skeleton,
    SkeletonChain,
    SkeletonSettings,
    chain_from_skeleton,
    default_limits,
)
from tests.solver.skeleton_refs import (
    WALK_UNIT_M,
    asset_bytes,
    rigid,
    split_glb,
    walk_text,
    world_matrices,
)

# RiggedFigure / CesiumMan joint nodes (shared/assets/README.md: upstream names).
RIGHT_ARM = ("node_13", "node_14", "node_15")  # arm_joint_R_1/2/3
RIGHT_LEG_FOOT = "node_6"  # leg_joint_R_5
LEFT_HAND = "node_18"  # arm_joint_L_3
TIGHT = IKOptions(position_tolerance_m=1e-4, rotation_tolerance_rad=1e-3, time_budget_us=None)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20261125)


def _figure(name: str = "RiggedFigure.glb") -> Skeleton:
    return read_gltf(asset_bytes(name))


def _walk() -> Skeleton:
    return read_bvh(walk_text(), unit_m=WALK_UNIT_M).skeleton


def _one(link: str, mode: EffectorMode = EffectorMode.POSITION) -> list[Effector]:
    return [Effector(name=link, link=link, mode=mode)]


# --- defaults --------------------------------------------------------------------------


def test_defaults_every_joint_moves_as_a_ball_joint() -> None:
    built = chain_from_skeleton(_figure(), SkeletonSettings(effectors=_one("node_15")))
    assert len(built.moving) == 19
    assert built.chain.n_dof == 57
    for joint in built.chain.joints:
        assert joint.kind is JointKind.ROTATIONAL
        assert joint.axes == "xyz"
        assert (joint.lower, joint.upper) == default_limits("xyz")
    # Every axis +-2 pi: no bound on the middle angle's gimbal lock, none half a turn
    # from rest (skeleton_settings).
    assert_allclose(default_limits("xyz")[1], [2 * math.pi] * 3)
    assert_allclose(default_limits("xyz")[0], [-2 * math.pi] * 3)
    assert_allclose(default_limits("yz")[1], [2 * math.pi] * 2)
    # Rest pose (q = 0) is the middle of the limits: where a solve starts.
    assert_allclose(built.chain.mid_limits(), 0.0)


def test_bvh_defaults_follow_the_channels_and_end_sites_stay_fixed() -> None:
    built = chain_from_skeleton(_walk(), SkeletonSettings(effectors=_one("LeftHand")))
    kinds = {j.name: j for j in built.chain.joints}
    assert kinds["LeftLeg"].axes == "zyx"
    assert kinds["LeftToeBase_end"].kind is JointKind.FIXED
    assert len(built.moving) == 31
    assert built.chain.n_dof == 93  # no free root unless asked
    assert "Hips.tx" not in built.chain.dof_names


def test_moving_axes_limits_terminator_and_free_root() -> None:
    settings = SkeletonSettings(
        effectors=_one("node_15", EffectorMode.POSE),
        moving=["node_15", "node_13", "node_14"],  # any order
        bones={
            "node_14": BoneSettings(axes="z", lower=(-0.1,), upper=(2.5,)),
            "node_13": BoneSettings(terminator=True),
        },
        free_root=FreeRoot(lower_m=(-1, -2, -3), upper_m=(1, 2, 3)),
    )
    built = chain_from_skeleton(_figure(), settings)
    assert built.moving == RIGHT_ARM
    names = built.chain.dof_names
    assert names[:3] == ("node_2.tx", "node_2.ty", "node_2.tz")
    assert "node_14.z" in names and "node_14.x" not in names
    i = names.index("node_14.z")
    assert (built.chain.lower[i], built.chain.upper[i]) == (-0.1, 2.5)
    assert_allclose(built.chain.lower[:3], [-1, -2, -3])
    # The terminator at the shoulder keeps the free root out of the hand's variables.
    hand_dofs = {names[k] for k in built.chain.compiled.eff_dofs[0]}
    assert hand_dofs == {
        "node_13.x",
        "node_13.y",
        "node_13.z",
        "node_14.z",
        *(f"node_15.{a}" for a in "xyz"),
    }


@pytest.mark.parametrize(
    ("settings", "field", "suggestion"),
    [
        (SkeletonSettings(effectors=_one("node_15x")), "effectors", "node_15"),
        (SkeletonSettings(effectors=_one("node_15"), moving=["Node_10"]), "moving", "node_10"),
        (
            SkeletonSettings(effectors=_one("node_15"), bones={"nod_3": BoneSettings()}),
            "bones",
            "node_3",
        ),
    ],
)
def test_unknown_bone_names_list_close_names(
    settings: SkeletonSettings, field: str, suggestion: str
) -> None:
    with pytest.raises(InvalidModel) as info:
        chain_from_skeleton(_figure(), settings)
    assert info.value.field == field
    assert repr(suggestion) in str(info.value)


def test_walk_unknown_bone_suggests_the_real_one() -> None:
    with pytest.raises(InvalidModel, match="'LeftHand'") as info:
        chain_from_skeleton(_walk(), SkeletonSettings(effectors=_one("LeftHnd")))
    assert info.value.joint == "LeftHnd"


def test_settings_errors_name_the_bone() -> None:
    figure = _figure()
    cases = [
        (
            SkeletonSettings(
                effectors=_one("node_15"),
                moving=["node_15"],
                bones={"node_14": BoneSettings(axes="x")},
            ),
            "node_14",
            "bones",
        ),
        (
            SkeletonSettings(effectors=_one("node_15"), bones={"node_14": BoneSettings(axes="xx")}),
            "node_14",
            "axes",
        ),
        (
            SkeletonSettings(
                effectors=_one("node_15"), bones={"node_14": BoneSettings(lower=(-1.0,))}
            ),
            "node_14",
            "upper",
        ),
        (
            SkeletonSettings(
                effectors=_one("node_15"),
                bones={"node_14": BoneSettings(lower=(-1.0,), upper=(1.0,))},
            ),
            "node_14",
            "lower",
        ),  # three axes, one limit: build_chain's check
        (
            SkeletonSettings(effectors=_one("node_15"), moving=["node_15", "node_15"]),
            "node_15",
            "moving",
        ),
        (SkeletonSettings(effectors=_one("node_15"), root_link="node_2"), "node_2", "root_link"),
        (
            SkeletonSettings(
                effectors=_one("node_15"), free_root=FreeRoot(lower_m=(1, 0, 0), upper_m=(0, 0, 0))
            ),
            "node_2",
            "free_root",
        ),
    ]
    for settings, joint, field in cases:
        with pytest.raises(InvalidModel) as info:
            chain_from_skeleton(figure, settings)
        assert (info.value.joint, info.value.field) == (joint, field)


def test_free_root_needs_a_single_root_and_skeletons_are_checked() -> None:
    two = Skeleton("two", (Bone(name="a", parent=None), Bone(name="b", parent=None)))
    with pytest.raises(InvalidModel) as info:
        chain_from_skeleton(two, SkeletonSettings(effectors=_one("a"), free_root=FreeRoot()))
    assert info.value.field == "free_root"
    with pytest.raises(InvalidModel, match="comes after"):
        Skeleton("bad", (Bone(name="a", parent="b"), Bone(name="b", parent=None)))
    with pytest.raises(InvalidModel, match="duplicate"):
        Skeleton("bad", (Bone(name="a", parent=None), Bone(name="a", parent=None)))


# --- bone quaternions through an independent FK -----------------------------------------


@pytest.mark.parametrize("name", ["RiggedFigure.glb", "CesiumMan.glb", "RiggedSimple.glb"])
def test_local_rotations_written_into_the_gltf_reproduce_the_pose(
    name: str, rng: np.random.Generator
) -> None:
    """What an engine does: put each bone's quaternion into its node and compose."""
    data = asset_bytes(name)
    doc, _ = split_glb(data)
    skeleton = read_gltf(data)
    built = chain_from_skeleton(skeleton, SkeletonSettings(effectors=_one(skeleton.names[-1])))
    for _ in range(3):
        q = rng.uniform(built.chain.lower, built.chain.upper)
        quats = built.local_rotations(q)
        assert_allclose(np.linalg.norm(quats, axis=1), 1.0, rtol=0, atol=1e-12)
        posed = json.loads(json.dumps(doc))
        for bone, (w, x, y, z) in zip(built.moving, quats, strict=True):
            posed["nodes"][int(bone.removeprefix("node_"))]["rotation"] = [x, y, z, w]
        reference = world_matrices(posed)
        world = built.world_transforms(q)
        for bone in built.moving:
            expected = rigid(reference[int(bone.removeprefix("node_"))])
            assert_allclose(world[bone], expected, rtol=0, atol=1e-6)


def test_local_rotations_of_a_bvh_frame_are_its_euler_angles() -> None:
    bvh = read_bvh(walk_text(), unit_m=WALK_UNIT_M)
    assert bvh.motion is not None
    built = chain_from_skeleton(bvh.skeleton, SkeletonSettings(effectors=_one("LeftHand")))
    q = built.clip(bvh.motion)[150]
    quats = built.local_rotations(q)
    column = {key: i for i, key in enumerate(bvh.motion.channels)}
    axis = {"x": 0, "y": 1, "z": 2}
    for bone_name, quat in zip(built.moving, quats, strict=True):
        bone = bvh.skeleton.bone(bone_name)
        rotations = [c for c in bone.channels if c.is_rotation]
        angles = [bvh.motion.values[150, column[(bone_name, c)]] for c in rotations]
        i, j, k = (axis[c.axis] for c in rotations)
        expected = pr.matrix_from_euler(angles, i, j, k, False)
        assert_allclose(pr.matrix_from_quaternion(quat), expected, rtol=0, atol=1e-12)


def test_quaternions_are_continuous_along_a_clip() -> None:
    bvh = read_bvh(walk_text(), unit_m=WALK_UNIT_M)
    assert bvh.motion is not None
    built = chain_from_skeleton(bvh.skeleton, SkeletonSettings(effectors=_one("LeftHand")))
    clip = built.clip(bvh.motion)[1:]  # frame 0 is a T-pose, the walk starts at frame 1
    quats = np.stack([built.local_rotations(q) for q in clip])
    # Consecutive frames at 120 fps: no sign flip, so every bone's dot product stays high.
    dots = np.sum(quats[1:] * quats[:-1], axis=2)
    assert dots.min() > 0.99


def test_quaternions_do_not_flip_sign_where_w_crosses_zero() -> None:
    # RiggedFigure's node_20 rests half a turn from identity (w = -7.5e-8): sweeping its
    # y angle takes w through zero, where a w >= 0 convention would flip the sign.
    built = chain_from_skeleton(_figure(), SkeletonSettings(effectors=_one("node_20")))
    row = built.moving.index("node_20")
    k = built.chain.dof_names.index("node_20.y")
    q = np.zeros(built.chain.n_dof)
    sweep = []
    for angle in np.linspace(-0.5, 0.5, 101):
        q[k] = angle
        sweep.append(built.local_rotations(q)[row])
    w = np.array(sweep)[:, 0]
    assert w.min() < -0.1 and w.max() > 0.1
    assert min(float(a @ b) for a, b in zip(sweep[1:], sweep[:-1], strict=True)) > 0.999


def test_world_transforms_of_chosen_bones_and_bad_q() -> None:
    built = chain_from_skeleton(_figure(), SkeletonSettings(effectors=_one("node_15")))
    q = np.zeros(built.chain.n_dof)
    assert set(built.world_transforms(q, ["node_15", "node_6"])) == {"node_15", "node_6"}
    with pytest.raises(InvalidModel, match="node_15"):
        built.world_transforms(q, ["node_155"])
    with pytest.raises(ValueError, match="57"):
        built.local_rotations(np.zeros(3))


# --- hands and feet reach targets --------------------------------------------------------


def _reach(built: SkeletonChain, rng: np.random.Generator, spread_rad: float, n: int) -> None:
    """Targets from random poses near rest (so within reach); every solve must succeed."""
    solver = IKSolver(built.chain, TIGHT, seed=1)
    lo, hi = built.chain.lower, built.chain.upper
    for _ in range(n):
        goal = np.clip(rng.uniform(-spread_rad, spread_rad, built.chain.n_dof), lo, hi)
        targets = pose_targets(built.chain, goal)
        result = solver.solve(targets)
        assert result.success, (result.status, result.max_position_error_m)
        reached = effector_poses(built.chain, result.q)
        wanted = effector_poses(built.chain, goal)
        for effector, got, want in zip(built.chain.effectors, reached, wanted, strict=True):
            assert np.linalg.norm(got[:3, 3] - want[:3, 3]) <= 1e-4
            if effector.mode is EffectorMode.POSE:
                cos = (np.trace(got[:3, :3].T @ want[:3, :3]) - 1.0) / 2.0
                assert math.acos(min(1.0, cos)) <= 1e-3
        # The goal really moved the effectors away from the rest pose.
        rest = effector_poses(built.chain, np.zeros(built.chain.n_dof))
        assert (
            max(np.linalg.norm(w[:3, 3] - r[:3, 3]) for w, r in zip(wanted, rest, strict=True))
            > 0.02
        )


@pytest.mark.parametrize("name", ["RiggedFigure.glb", "CesiumMan.glb"])
def test_figure_hand_and_foot_reach(name: str, rng: np.random.Generator) -> None:
    effectors = [
        Effector(name="left_hand", link=LEFT_HAND, mode=EffectorMode.POSE),
        Effector(name="right_foot", link=RIGHT_LEG_FOOT, mode=EffectorMode.POSITION),
    ]
    built = chain_from_skeleton(_figure(name), SkeletonSettings(effectors=effectors))
    _reach(built, rng, 0.5, 4)


def test_figure_arm_alone_moves_only_the_arm(rng: np.random.Generator) -> None:
    effectors = [
        Effector(
            name="hand",
            link="node_15",
            mode=EffectorMode.POSE,
            tip_offset=np.array([0.0, 0.1, 0.0]),
        )
    ]
    built = chain_from_skeleton(
        _figure(), SkeletonSettings(effectors=effectors, moving=list(RIGHT_ARM))
    )
    assert built.chain.n_dof == 9
    _reach(built, rng, 0.6, 4)


def test_simple_tip_reaches(rng: np.random.Generator) -> None:
    skeleton = read_gltf(asset_bytes("RiggedSimple.glb"))
    built = chain_from_skeleton(
        skeleton,
        SkeletonSettings(
            effectors=[Effector(name="tip", link="node_3", tip_offset=np.array([0.0, 4.0, 0.0]))]
        ),
    )
    _reach(built, rng, 0.5, 4)


def test_walk_hand_and_foot_reach_with_a_free_root(rng: np.random.Generator) -> None:
    effectors = [
        Effector(name="hand", link="LeftHand", mode=EffectorMode.POSE),
        Effector(name="foot", link="RightFoot", mode=EffectorMode.POSITION),
    ]
    built = chain_from_skeleton(
        _walk(),
        SkeletonSettings(
            effectors=effectors, free_root=FreeRoot(lower_m=(-0.3,) * 3, upper_m=(0.3,) * 3)
        ),
    )
    _reach(built, rng, 0.3, 4)


def test_walk_hand_follows_a_circle_near_the_shoulder_without_stalling() -> None:
    # A hand circle of 8 cm whose centre is 0.15 m from the shoulder (the elbow bent a
    # lot), tracked under the stream defaults (smooth, 0.1 rad per frame). With the
    # middle Euler angle bounded at +-pi/2 (the gimbal lock), the shoulder's middle angle
    # ran into that bound and 40-66 of the 300 frames missed, up to 8 cm off
    # (bench/history/2026-11-29-bvh-euler-wall.md); the default ball joint has no bound
    # there. A frame or two may miss by a hair on a loaded machine (the budget's deadline).
    arm = ("LeftArm", "LeftForeArm")
    built = chain_from_skeleton(
        _walk(),
        SkeletonSettings(effectors=[Effector(name="hand", link="LeftHand")], moving=arm),
    )
    shoulder = built.world_transforms(np.zeros(built.chain.n_dof), ["LeftArm"])["LeftArm"]
    normal = np.array([0.2, 0.9, -0.35]) / np.linalg.norm([0.2, 0.9, -0.35])
    u = np.cross(normal, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    centre = shoulder[:3, 3] + np.array([0.05, 0.10, -0.10])
    solver = IKSolver(built.chain, STREAM_DEFAULTS)
    missed, worst_m, largest_step = 0, 0.0, 0.0
    previous = solver.q.copy()
    for angle in 2.0 * math.pi * np.arange(300) / 300:
        point = centre + 0.08 * (math.cos(angle) * u + math.sin(angle) * v)
        result = solver.track([Target(effector="hand", position=point)])
        missed += not result.success
        worst_m = max(worst_m, result.max_position_error_m)
        if angle > 0.0:  # the first frame is solved from the rest pose as reach would
            largest_step = max(largest_step, float(np.abs(result.q - previous).max()))
        previous = result.q.copy()
    assert missed <= 2 and worst_m < 0.005, (missed, worst_m)
    assert largest_step <= STREAM_DEFAULTS.max_joint_step_rad + 1e-9
