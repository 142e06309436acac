"""Chains and streams shared by the solver's test modules."""

from __future__ import annotations

import math

import numpy as np

from solver.model import Effector, EffectorMode, Joint, JointKind, Mimic, Transform, build_chain
from solver.model.examples import humanoid_arm, panda_arm, tail, two_arm_torso


def slider_arm():  # type: ignore[no-untyped-def]
    """A prismatic base, a revolute with an off-axis pivot, and an aim effector."""
    joints = [
        Joint(
            name="slide",
            parent="world",
            child="carriage",
            kind=JointKind.PRISMATIC,
            axis=np.array([1.0, 1.0, 0.0]),
            lower=(-0.5,),
            upper=(0.5,),
        ),
        Joint(
            name="turn",
            parent="carriage",
            child="arm",
            kind=JointKind.REVOLUTE,
            axis=np.array([0.0, 0.0, 1.0]),
            pivot=np.array([0.1, 0.0, 0.0]),
            origin=Transform.from_rpy([0.0, 0.0, 0.2], 0.1, 0.2, 0.3),
            lower=(-2.0,),
            upper=(2.0,),
        ),
        Joint(
            name="tilt",
            parent="arm",
            child="head",
            kind=JointKind.ROTATIONAL,
            axes="yx",
            origin=Transform(np.array([0.4, 0.0, 0.0])),
            lower=(-1.0, -1.0),
            upper=(1.0, 1.0),
        ),
    ]
    return build_chain(
        joints,
        [
            Effector(
                name="eye",
                link="head",
                tip_offset=np.array([0.05, 0.0, 0.0]),
                mode=EffectorMode.AIM,
                aim_axis=np.array([1.0, 0.0, 0.0]),
                position_weight=0.5,
                rotation_weight=0.2,
            ),
        ],
    )


def mimic_gripper():  # type: ignore[no-untyped-def]
    """A shoulder, a slide and a finger (the leader) with two mimic joints: a revolute
    finger at -1.5 x the leader + 0.2, and a prismatic pad following that follower (a
    chain of mimics); a pose effector on the finger, a position effector on the pad."""
    z = np.array([0.0, 0.0, 1.0])
    joints = [
        Joint(
            name="shoulder",
            parent="base",
            child="upper",
            kind=JointKind.REVOLUTE,
            axis=z,
            lower=(-2.0,),
            upper=(2.0,),
        ),
        Joint(
            name="slide",
            parent="upper",
            child="hand",
            kind=JointKind.PRISMATIC,
            axis=np.array([1.0, 0.0, 0.0]),
            origin=Transform(np.array([0.3, 0.0, 0.1])),
            lower=(0.0,),
            upper=(0.4,),
        ),
        Joint(
            name="finger_a",
            parent="hand",
            child="a",
            kind=JointKind.REVOLUTE,
            axis=np.array([0.0, 1.0, 0.0]),
            origin=Transform(np.array([0.1, 0.02, 0.0])),
            lower=(-0.3,),
            upper=(0.8,),
        ),
        Joint(
            name="finger_b",
            parent="hand",
            child="b",
            kind=JointKind.REVOLUTE,
            axis=np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0),
            origin=Transform.from_rpy([0.1, -0.02, 0.0], 0.3, 0.0, 0.1),
            lower=(-1.0,),
            upper=(0.5,),
            mimic=Mimic("finger_a", -1.5, 0.2),
        ),
        Joint(
            name="pad",
            parent="b",
            child="pad_link",
            kind=JointKind.PRISMATIC,
            axis=np.array([1.0, 0.0, 0.0]),
            origin=Transform(np.array([0.05, 0.0, 0.0])),
            lower=(-1.0,),
            upper=(1.0,),
            mimic=Mimic("finger_b", 0.02, 0.01),
        ),
    ]
    effectors = [
        Effector(
            name="b_tip", link="b", tip_offset=np.array([0.04, 0.0, 0.0]), mode=EffectorMode.POSE
        ),
        Effector(name="pad_tip", link="pad_link", mode=EffectorMode.POSITION),
    ]
    return build_chain(joints, effectors)


CHAINS = {
    "panda-pose": lambda: panda_arm(),
    "panda-position": lambda: panda_arm(EffectorMode.POSITION),
    "humanoid-pose": lambda: humanoid_arm(),
    "humanoid-aim": lambda: humanoid_arm(EffectorMode.AIM),
    "two-arms": two_arm_torso,
    "slider-aim": slider_arm,
    "tail": lambda: tail(8),
    "mimic-gripper": mimic_gripper,
}


def joint_stream(chain, seed: int, frames: int) -> np.ndarray:  # type: ignore[no-untyped-def]
    """bench/ik/'s reference paths: q(t) = c + A sin(2 pi f t + phi) at 60 Hz."""
    rng = np.random.default_rng(seed)
    lo, hi = chain.lower, chain.upper
    n = chain.n_dof
    c = lo + (hi - lo) * rng.uniform(0.25, 0.75, n)
    amp = np.minimum(0.6, 0.8 * np.minimum(c - lo, hi - c))
    f = rng.uniform(0.05, 0.3, n)
    phi = rng.uniform(0.0, 2 * math.pi, n)
    t = np.arange(frames)[:, None] / 60.0
    q: np.ndarray = c + amp * np.sin(2 * math.pi * f * t + phi)
    return q


def folding_arm():  # type: ignore[no-untyped-def]
    """Two 1 m links in a plane, the elbow in [0, 2.5] rad: 0 is the straight arm."""
    z = np.array([0.0, 0.0, 1.0])
    joints = [
        Joint(name="shoulder", parent="world", child="upper", kind=JointKind.REVOLUTE, axis=z,
              lower=(-3.0,), upper=(3.0,)),
        Joint(name="elbow", parent="upper", child="fore", kind=JointKind.REVOLUTE, axis=z,
              origin=Transform(np.array([1.0, 0.0, 0.0])), lower=(0.0,), upper=(2.5,)),
        Joint(name="wrist", parent="fore", child="hand", kind=JointKind.FIXED,
              origin=Transform(np.array([1.0, 0.0, 0.0]))),
    ]  # fmt: skip
    return build_chain(joints, [Effector(name="hand", link="hand", mode=EffectorMode.POSITION)])
