"""Forward kinematics against references that do not share solver's compiled kernel.

(a) Hand-computed poses and a plain-numpy walk of the documented frame formula
    ``link = parent * origin * Tr(pivot) * motion(q) * Tr(-pivot)`` over every example
    chain (the humanoid arm has multi-axis rotational joints with a pivot, which URDF
    cannot express, so it is checked here and not against the URDF reference).
(b) pytransform3d's URDF parser and ``UrdfTransformManager`` (lxml parsing, its own
    Euler and axis-angle code; test extra ``pytransform3d==3.17.0``) on the committed
    Panda URDF, random URDFs with general rpy/axes, and the installed robots.
(c) The Panda from URDF against ``solver.examples.panda_arm()`` (Franka's modified DH
    table): every link frame and the flange agree to rounding, with no base or flange
    offset (franka_ros writes each MDH step as origin xyz = (a, 0, 0) + Rx(alpha) (0, 0, d),
    rpy = (alpha, 0, 0)).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pytransform3d.urdf import UrdfTransformManager

from solver.model import Chain, Joint, JointKind, Transform, build_chain
from solver.model.examples import EXAMPLES, panda_arm, two_arm_torso, with_tip
from solver.model.forward import effector_poses, link_poses
from solver.model.urdf import chain_from_urdf

DATA = Path(__file__).resolve().parent / "data"
REPO = Path(__file__).resolve().parents[2]
PANDA = (DATA / "panda_kinematic.urdf").read_text(encoding="utf-8")
ATOL = 1e-12  # [m] and [-] (rotation entries): a few hundred ulps at 1 m
Z = np.array([0.0, 0.0, 1.0])


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(8675309)


def rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def pose(rotation: np.ndarray, translation: Any) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rotation
    m[:3, 3] = translation
    return m


def sample(chain: Chain, rng: np.random.Generator) -> np.ndarray:
    """Uniform inside the limits; unbounded (continuous) joints in [-2 pi, 2 pi]."""
    lo = np.where(np.isfinite(chain.lower), chain.lower, -2.0 * math.pi)
    hi = np.where(np.isfinite(chain.upper), chain.upper, 2.0 * math.pi)
    return rng.uniform(lo, hi)


# --- (a) hand-computed ------------------------------------------------------------------


def _planar(l1: float = 0.5, l2: float = 0.3) -> Chain:
    joints = [
        Joint(
            name="q1",
            parent="base",
            child="upper",
            kind=JointKind.REVOLUTE,
            axis=Z,
            lower=(-3.0,),
            upper=(3.0,),
        ),
        Joint(
            name="q2",
            parent="upper",
            child="fore",
            kind=JointKind.REVOLUTE,
            axis=Z,
            origin=Transform(np.array([l1, 0.0, 0.0])),
            lower=(-3.0,),
            upper=(3.0,),
        ),
    ]
    return with_tip(joints, "hand", (l2, 0.0, 0.0), joint="wrist")


def test_planar_two_link_by_hand(rng: np.random.Generator) -> None:
    chain = _planar()
    cases = [
        ((0.0, 0.0), (0.8, 0.0)),
        ((math.pi / 2, 0.0), (0.0, 0.8)),
        ((math.pi / 2, -math.pi / 2), (0.3, 0.5)),
        ((math.pi, 0.0), (-0.8, 0.0)),
    ]
    for q, xy in cases:
        expected = pose(rot_z(sum(q)), [xy[0], xy[1], 0.0])
        assert_allclose(effector_poses(chain, np.array(q))[0], expected, rtol=0.0, atol=1e-15)
    for _ in range(20):
        q1, q2 = rng.uniform(-3.0, 3.0, size=2)
        tip = [
            0.5 * math.cos(q1) + 0.3 * math.cos(q1 + q2),
            0.5 * math.sin(q1) + 0.3 * math.sin(q1 + q2),
            0.0,
        ]
        poses = link_poses(chain, np.array([q1, q2]))
        assert_allclose(poses["hand"], pose(rot_z(q1 + q2), tip), rtol=0.0, atol=ATOL)
        assert_allclose(
            poses["fore"],
            pose(rot_z(q1 + q2), [0.5 * math.cos(q1), 0.5 * math.sin(q1), 0.0]),
            rtol=0.0,
            atol=ATOL,
        )


def test_prismatic_slides_along_its_axis_in_the_joint_frame() -> None:
    # origin rotates the joint frame by Rx(90 deg): the joint's +z is the parent's -y.
    joints = [
        Joint(
            name="slide",
            parent="base",
            child="carriage",
            kind=JointKind.PRISMATIC,
            origin=Transform(np.array([0.1, 0.2, 0.0]), rot_x(math.pi / 2)),
            axis=np.array([0.0, 0.0, 2.0]),
            lower=(-0.5,),
            upper=(0.5,),
        ),
    ]
    chain = with_tip(joints, "tip", (0.0, 0.0, 0.05), joint="tool")
    poses = link_poses(chain, np.array([0.25]))
    assert_allclose(
        poses["carriage"], pose(rot_x(math.pi / 2), [0.1, -0.05, 0.0]), rtol=0.0, atol=1e-15
    )
    assert_allclose(poses["tip"], pose(rot_x(math.pi / 2), [0.1, -0.1, 0.0]), rtol=0.0, atol=1e-15)


def _shoulder_zx() -> Chain:
    joints = [
        Joint(
            name="shoulder",
            parent="torso",
            child="upper",
            kind=JointKind.ROTATIONAL,
            axes="zx",
            origin=Transform(np.array([0.0, 0.0, 1.0])),
            pivot=np.array([0.0, 0.1, 0.0]),
            lower=(-3.0, -3.0),
            upper=(3.0, 3.0),
        ),
    ]
    return with_tip(joints, "elbow", (0.0, 0.3, 0.0), joint="elbow_mount")


@pytest.mark.parametrize(
    ("q", "rotation", "upper_t", "elbow_t"),
    [
        # Rz(90): the pivot (0, .1, 0) swings to (-.1, 0, 0); link origin = o + p - R p
        ((math.pi / 2, 0.0), [[0, -1, 0], [1, 0, 0], [0, 0, 1]], [0.1, 0.1, 1.0], [-0.2, 0.1, 1.0]),
        ((0.0, math.pi / 2), [[1, 0, 0], [0, 0, -1], [0, 1, 0]], [0.0, 0.1, 0.9], [0.0, 0.1, 1.2]),
        # intrinsic order "zx": Rz(90) Rx(90), not Rx(90) Rz(90) = [[0,-1,0],[0,0,-1],[1,0,0]]
        (
            (math.pi / 2, math.pi / 2),
            [[0, 0, 1], [1, 0, 0], [0, 1, 0]],
            [0.0, 0.1, 0.9],
            [0.0, 0.1, 1.2],
        ),
    ],
)
def test_rotational_zx_with_pivot_by_hand(
    q: tuple[float, float], rotation: list[list[float]], upper_t: list[float], elbow_t: list[float]
) -> None:
    poses = link_poses(_shoulder_zx(), np.array(q))
    assert_allclose(poses["upper"], pose(np.array(rotation, float), upper_t), rtol=0.0, atol=1e-15)
    assert_allclose(poses["elbow"], pose(np.array(rotation, float), elbow_t), rtol=0.0, atol=1e-15)


def test_rotational_pivot_formula(rng: np.random.Generator) -> None:
    chain = _shoulder_zx()
    o, p = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.1, 0.0])
    for _ in range(20):
        a, b = rng.uniform(-3.0, 3.0, size=2)
        r = rot_z(a) @ rot_x(b)
        expected = pose(r, o + p - r @ p)  # origin * Tr(p) * Rz(a) Rx(b) * Tr(-p)
        assert_allclose(link_poses(chain, np.array([a, b]))["upper"], expected, rtol=0.0, atol=ATOL)


def test_terminator_does_not_change_fk(rng: np.random.Generator) -> None:
    with_terminators = two_arm_torso()
    assert any(j.terminator for j in with_terminators.joints)
    without = build_chain(
        [dataclasses.replace(j, terminator=False) for j in with_terminators.joints],
        list(with_terminators.effectors),
    )
    for _ in range(10):
        q = sample(with_terminators, rng)
        a, b = link_poses(with_terminators, q), link_poses(without, q)
        for link in a:
            assert_allclose(a[link], b[link], rtol=0.0, atol=0.0)
        for ea, eb in zip(
            effector_poses(with_terminators, q), effector_poses(without, q), strict=True
        ):
            assert_allclose(ea, eb, rtol=0.0, atol=0.0)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' formula, R = I + sin(t) K + (1 - cos(t)) K^2 (Murray, Li, Sastry eq. 2.14)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def reference_link_poses(chain: Chain, q: np.ndarray) -> dict[str, np.ndarray]:
    """The module docstring's formula, walked in numpy over ``chain.joints``."""
    values = dict(zip(chain.dof_names, q, strict=True))
    out = {chain.root: np.eye(4)}
    for j in chain.joints:  # topological order
        motion = np.eye(4)
        if j.kind in (JointKind.REVOLUTE, JointKind.CONTINUOUS):
            motion[:3, :3] = _axis_angle(j.axis, values[j.name])
        elif j.kind is JointKind.PRISMATIC:
            motion[:3, 3] = values[j.name] * j.axis
        elif j.kind is JointKind.ROTATIONAL:
            for name, letter in zip(j.dof_names, j.axes, strict=True):
                unit = np.eye(3)["xyz".index(letter)]
                motion[:3, :3] = motion[:3, :3] @ _axis_angle(unit, values[name])
        origin = pose(j.origin.rotation, j.origin.translation)
        out[j.child] = (
            out[j.parent] @ origin @ pose(np.eye(3), j.pivot) @ motion @ pose(np.eye(3), -j.pivot)
        )
    return out


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_examples_against_numpy_walk(name: str, rng: np.random.Generator) -> None:
    chain = EXAMPLES[name]()
    for _ in range(20):
        q = sample(chain, rng)
        got, ref = link_poses(chain, q), reference_link_poses(chain, q)
        assert got.keys() == ref.keys()
        for link in ref:
            assert_allclose(got[link], ref[link], rtol=0.0, atol=ATOL, err_msg=link)


# --- (b) pytransform3d --------------------------------------------------------------------


def assert_matches_pytransform3d(
    text: str, chain: Chain, rng: np.random.Generator, n_samples: int
) -> None:
    tm = UrdfTransformManager()
    tm.load_urdf(text)
    for _ in range(n_samples):
        q = sample(chain, rng)
        for name, value in zip(chain.dof_names, q, strict=True):
            tm.set_joint(name, float(value))
        for link, link2base in link_poses(chain, q).items():
            expected = tm.get_transform(link, chain.root)
            assert_allclose(link2base, expected, rtol=0.0, atol=ATOL, err_msg=link)


def test_panda_urdf_against_pytransform3d(rng: np.random.Generator) -> None:
    chain = chain_from_urdf(
        PANDA, base_link="panda_link0", tip_links=["panda_hand_tcp", "panda_leftfinger"]
    )
    assert chain.n_dof == 8
    assert len(chain.link_names) == 12
    assert_matches_pytransform3d(PANDA, chain, rng, n_samples=50)


def _random_urdf(rng: np.random.Generator, n_joints: int) -> tuple[str, list[str]]:
    """A random tree: general rpy and non-unit axes, all four joint types; returns tips."""

    def num(v: float) -> str:
        return repr(float(v))

    def vec(v: np.ndarray) -> str:
        return " ".join(num(x) for x in v)

    links = ['<link name="base"/>']
    joints = []
    children: dict[str, int] = {"base": 0}
    for i in range(n_joints):
        parent = "base" if i == 0 else f"l{rng.integers(max(0, i - 2), i)}"  # mostly a chain
        child = f"l{i}"
        children[parent] = children.get(parent, 0) + 1
        children.setdefault(child, 0)
        kind = str(rng.choice(["revolute", "continuous", "prismatic", "fixed"]))
        inner = (
            f'<origin xyz="{vec(rng.uniform(-0.5, 0.5, 3))}" '
            f'rpy="{vec(rng.uniform(-math.pi, math.pi, 3))}"/>'
        )
        if kind != "fixed":
            inner += f'<axis xyz="{vec(rng.normal(size=3))}"/>'
        if kind in ("revolute", "prismatic"):
            lo = rng.uniform(-2.0, 0.0)
            inner += f'<limit lower="{num(lo)}" upper="{num(lo + rng.uniform(0.1, 2.0))}"/>'
        links.append(f'<link name="{child}"/>')
        joints.append(
            f'<joint name="j{i}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f"{inner}</joint>"
        )
    tips = [link for link, n in children.items() if n == 0]
    return f'<robot name="random">{"".join(links)}{"".join(joints)}</robot>', tips


def test_random_urdfs_against_pytransform3d(rng: np.random.Generator) -> None:
    kinds_seen: set[JointKind] = set()
    for _ in range(20):
        text, tips = _random_urdf(rng, n_joints=8)
        chain = chain_from_urdf(text, base_link="base", tip_links=tips)
        kinds_seen.update(j.kind for j in chain.joints)
        assert_matches_pytransform3d(text, chain, rng, n_samples=5)
    assert kinds_seen == {
        JointKind.REVOLUTE,
        JointKind.CONTINUOUS,
        JointKind.PRISMATIC,
        JointKind.FIXED,
    }


def installed_robot(name: str) -> Any:
    """bench.robots.robot(name), or a skip if bench/robots.py or the URDF cannot be found."""
    path = REPO / "bench" / "robots.py"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    module_name = "_bench_robots_for_tests"
    module = sys.modules.get(module_name)
    if module is None:
        spec = importlib.util.spec_from_file_location(module_name, path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[module_name] = module  # dataclasses look their module up
        spec.loader.exec_module(module)
    try:
        return module.robot(name)
    except FileNotFoundError as e:
        pytest.skip(f"URDF for {name!r} not found: {e}")


@pytest.mark.parametrize("name", ["panda", "ur5", "iiwa"])
def test_installed_robot_against_pytransform3d(name: str, rng: np.random.Generator) -> None:
    spec = installed_robot(name)
    text = spec.kinematic_urdf_text()
    chain = chain_from_urdf(text, base_link=spec.base_link, tip_links=spec.tip_link)
    assert_matches_pytransform3d(text, chain, rng, n_samples=20)


# --- (c) URDF Panda vs the modified-DH example ---------------------------------------------


def test_panda_urdf_matches_modified_dh_example(rng: np.random.Generator) -> None:
    urdf = chain_from_urdf(PANDA, base_link="panda_link0", tip_links="panda_link8")
    dh = panda_arm()
    assert_allclose(urdf.lower, dh.lower, rtol=0.0, atol=0.0)
    assert_allclose(urdf.upper, dh.upper, rtol=0.0, atol=0.0)
    for _ in range(50):
        q = sample(dh, rng)
        a, b = link_poses(urdf, q), link_poses(dh, q)
        for i in range(1, 8):  # same frames, not just the same flange: no hidden offsets
            assert_allclose(a[f"panda_link{i}"], b[f"link{i}"], rtol=0.0, atol=ATOL)
        assert_allclose(effector_poses(urdf, q)[0], effector_poses(dh, q)[0], rtol=0.0, atol=ATOL)
        assert_allclose(a["panda_link8"], b["flange"], rtol=0.0, atol=ATOL)
