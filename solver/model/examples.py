"""Example chains shipped with the solver: tests, benchmarks, load tests and docs use them.

- ``panda_arm``: the Franka Panda's 7 revolute joints from Franka's published
  (modified Denavit-Hartenberg) parameters and limits, pose effector at the flange.
- ``humanoid_arm``: clavicle, a three-axis shoulder (the article's rotational joint
  with a pivot), elbow, forearm twist and a two-axis wrist: 7 DOF.
- ``tail``: n_links segments with two-axis rotational joints (2 n_links DOF).
- ``two_arm_torso``: a tree: a spine joint and two arms whose shoulders are
  terminators, two effectors.

Also (not in ``EXAMPLES``): ``bolt``, a chain with no variables, and ``with_tip``, the
serial chain the first three end as: a fixed tip link and one effector on it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .chain import Chain, build_chain
from .joints import Effector, EffectorMode, Joint, JointKind, Transform

_PANDA_MDH = (  # (a_{i-1}, d_i, alpha_{i-1}) per joint, Franka's documentation
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -math.pi / 2),
    (0.0, 0.316, math.pi / 2),
    (0.0825, 0.0, math.pi / 2),
    (-0.0825, 0.384, -math.pi / 2),
    (0.0, 0.0, math.pi / 2),
    (0.088, 0.0, math.pi / 2),
)
_PANDA_LIMITS = (
    (-2.8973, 2.8973),
    (-1.7628, 1.7628),
    (-2.8973, 2.8973),
    (-3.0718, -0.0698),
    (-2.8973, 2.8973),
    (-0.0175, 3.7525),
    (-2.8973, 2.8973),
)


def _rot_x(alpha: float) -> np.ndarray:
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def panda_arm(mode: EffectorMode = EffectorMode.POSE) -> Chain:
    """The Panda's arm (7 DOF), effector at the flange (d = 0.107 m past joint 7)."""
    joints = []
    parent = "base"
    for i, ((a, d, alpha), (lo, hi)) in enumerate(zip(_PANDA_MDH, _PANDA_LIMITS, strict=True)):
        rot = _rot_x(alpha)
        origin = Transform(np.array([a, 0.0, 0.0]) + rot @ np.array([0.0, 0.0, d]), rot)
        child = f"link{i + 1}"
        joints.append(
            Joint(
                name=f"joint{i + 1}",
                parent=parent,
                child=child,
                kind=JointKind.REVOLUTE,
                origin=origin,
                axis=np.array([0.0, 0.0, 1.0]),
                lower=(lo,),
                upper=(hi,),
            )
        )
        parent = child
    return with_tip(joints, "flange", (0.0, 0.0, 0.107), effector="tool", mode=mode)


def humanoid_arm(mode: EffectorMode = EffectorMode.POSE) -> Chain:
    """A humanoid arm: 3-axis shoulder with a pivot, elbow, twist, 2-axis wrist (7 DOF)."""
    deg = math.pi / 180.0
    joints = [
        Joint(
            name="clavicle",
            parent="torso",
            child="shoulder_base",
            kind=JointKind.FIXED,
            origin=Transform(np.array([0.0, 0.18, 0.45])),
        ),
        Joint(
            name="shoulder",
            parent="shoulder_base",
            child="upper_arm",
            kind=JointKind.ROTATIONAL,
            axes="zxy",
            pivot=np.array([0.0, 0.02, 0.0]),
            lower=(-90 * deg, -30 * deg, -90 * deg),
            upper=(120 * deg, 170 * deg, 90 * deg),
        ),
        Joint(
            name="elbow",
            parent="upper_arm",
            child="forearm",
            kind=JointKind.ROTATIONAL,
            axes="x",
            origin=Transform(np.array([0.0, 0.30, 0.0])),
            lower=(0.0,),
            upper=(150 * deg,),
        ),
        Joint(
            name="forearm_twist",
            parent="forearm",
            child="forearm_distal",
            kind=JointKind.REVOLUTE,
            origin=Transform(np.array([0.0, 0.12, 0.0])),
            axis=np.array([0.0, 1.0, 0.0]),
            lower=(-80 * deg,),
            upper=(80 * deg,),
        ),
        Joint(
            name="wrist",
            parent="forearm_distal",
            child="hand",
            kind=JointKind.ROTATIONAL,
            axes="zx",
            origin=Transform(np.array([0.0, 0.13, 0.0])),
            lower=(-30 * deg, -70 * deg),
            upper=(30 * deg, 70 * deg),
        ),
    ]
    return build_chain(
        joints,
        [Effector(name="hand", link="hand", tip_offset=np.array([0.0, 0.08, 0.0]), mode=mode)],
    )


def tail(n_links: int = 20, mode: EffectorMode = EffectorMode.POSITION) -> Chain:
    """A tail of n_links segments of 0.1 m, each joint rotating about x and z (+-40 deg)."""
    lim = 40.0 * math.pi / 180.0
    joints = []
    parent = "root"
    for i in range(n_links):
        child = f"seg{i + 1}"
        joints.append(
            Joint(
                name=f"j{i + 1}",
                parent=parent,
                child=child,
                kind=JointKind.ROTATIONAL,
                axes="xz",
                origin=Transform(np.array([0.0, 0.0, 0.1 if i else 0.0])),
                lower=(-lim, -lim),
                upper=(lim, lim),
            )
        )
        parent = child
    return with_tip(joints, "tip", (0.0, 0.0, 0.1), mode=mode)


def two_arm_torso() -> Chain:
    """A spine and two 3-DOF arms; each shoulder is a terminator (the spine does not move
    for one arm alone), two position effectors."""
    lim = (-2.0,), (2.0,)
    joints = [
        Joint(
            name="spine",
            parent="pelvis",
            child="chest",
            kind=JointKind.REVOLUTE,
            axis=np.array([0.0, 0.0, 1.0]),
            lower=lim[0],
            upper=lim[1],
            origin=Transform(np.array([0.0, 0.0, 0.5])),
        ),
    ]
    for side, y in (("left", 0.2), ("right", -0.2)):
        joints += [
            Joint(
                name=f"{side}_shoulder",
                parent="chest",
                child=f"{side}_upper",
                kind=JointKind.ROTATIONAL,
                axes="xy",
                origin=Transform(np.array([0.0, y, 0.3])),
                lower=(-2.0, -2.0),
                upper=(2.0, 2.0),
                terminator=True,
            ),
            Joint(
                name=f"{side}_elbow",
                parent=f"{side}_upper",
                child=f"{side}_fore",
                kind=JointKind.REVOLUTE,
                axis=np.array([1.0, 0.0, 0.0]),
                origin=Transform(np.array([0.0, 0.0, -0.3])),
                lower=(0.0,),
                upper=(2.5,),
            ),
            Joint(
                name=f"{side}_wrist",
                parent=f"{side}_fore",
                child=f"{side}_hand",
                kind=JointKind.FIXED,
                origin=Transform(np.array([0.0, 0.0, -0.25])),
            ),
        ]
    effectors = [
        Effector(name="left_hand", link="left_hand"),
        Effector(name="right_hand", link="right_hand"),
    ]
    return build_chain(joints, effectors)


def with_tip(
    joints: Sequence[Joint],
    link: str,
    translation: Sequence[float],
    *,
    parent: str | None = None,
    joint: str | None = None,
    effector: str | None = None,
    mode: EffectorMode = EffectorMode.POSITION,
) -> Chain:
    """A serial chain: ``joints``, then a fixed joint (``joint``, default
    ``f"{link}_joint"``) carrying ``link`` at ``translation`` [m] in ``parent``'s frame
    (default: the last joint's child link), and one effector on ``link`` (named
    ``effector``, default the link's name)."""
    tip = Joint(
        name=joint if joint is not None else f"{link}_joint",
        parent=parent if parent is not None else joints[-1].child,
        child=link,
        kind=JointKind.FIXED,
        origin=Transform(np.array(translation, dtype=np.float64)),
    )
    name = effector if effector is not None else link
    return build_chain([*joints, tip], [Effector(name=name, link=link, mode=mode)])


def bolt() -> Chain:
    """A chain with no variables: link ``tip`` fixed 1 m above ``base``, effector ``tip``
    (such a chain takes its own compiled path: errors only, no solve)."""
    return with_tip([], "tip", (0.0, 0.0, 1.0), parent="base", joint="bolt")


EXAMPLES = {
    "panda_arm": panda_arm,
    "humanoid_arm": humanoid_arm,
    "tail": tail,
    "two_arm_torso": two_arm_torso,
}
