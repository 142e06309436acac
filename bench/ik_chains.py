"""Chains for bench/ik/: the three URDF arms and our two example chains, each with a
pose-mode chain, a position-mode chain, and (where one exists) a URDF the peers can load.

The URDF arms come from bench/robots.py and are built with solver.model.urdf.chain_from_urdf.
The examples (solver.examples.tail(20): 40 DOF; humanoid_arm(): 7 DOF with a three-axis
shoulder) have no URDF, so `example_urdf` writes one from the Chain itself into
bench/out/urdf/: a rotational joint with axes "zxy" becomes three revolute joints about
z, x, y (intrinsic, as our model composes them) joined by massless links; a pivot p
becomes origin * Tr(p) on the first of them and a fixed Tr(-p) joint after the last; the
effector's tip offset becomes a fixed joint to a `<effector>__tip` link. The peers'
FK is compared with ours on random q before any timing (python -m bench.ik prints it), so a
mistake here shows up as a peer skipped for FK mismatch, not as a silent handicap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from bench.robots import ROBOTS, RobotSpec, robot
from solver.model import Chain, EffectorMode, JointKind
from solver.model.examples import humanoid_arm, tail
from solver.model.urdf import chain_from_urdf

OUT_DIR = Path(__file__).resolve().parent / "out" / "urdf"
EXAMPLES: tuple[str, ...] = ("tail40", "humanoid_arm")
CHAINS: tuple[str, ...] = ROBOTS + EXAMPLES


@dataclass(frozen=True)
class BenchChain:
    name: str
    pose: Chain  # POSE effector: parts (a) and (c), and the FK that judges every answer
    position: Chain  # same kinematics, POSITION effector: part (b)
    spec: RobotSpec | None  # URDF the peers load (None: peers skip this chain)
    source: str  # where the model comes from, for the report
    arm: bool  # one of the three URDF arms the PASS/FAIL targets are about
    # peer joint order (spec.joint_names) -> our variable index: q_ours[perm] = q_peer
    perm: np.ndarray

    @property
    def effector(self) -> str:
        return self.pose.effectors[0].name

    def to_ours(self, q_peer: np.ndarray) -> np.ndarray:
        q = np.empty(self.pose.n_dof)
        q[self.perm] = q_peer
        return q

    def to_peer(self, q_ours: np.ndarray) -> np.ndarray:
        q: np.ndarray = np.asarray(q_ours, dtype=float)[self.perm]
        return q


def load(name: str, *, peer_urdf: bool = True) -> BenchChain:
    """The chain called `name` (one of CHAINS). peer_urdf=False skips writing URDFs for
    the examples (their peers are then skipped)."""
    if name in ROBOTS:
        spec = robot(name)
        text = spec.urdf_text()
        pose = chain_from_urdf(
            text, base_link=spec.base_link, tip_links=[spec.tip_link], mode=EffectorMode.POSE
        )
        position = chain_from_urdf(
            text, base_link=spec.base_link, tip_links=[spec.tip_link], mode=EffectorMode.POSITION
        )
        source = (
            f"{spec.urdf_path.name} ({spec.base_link} -> {spec.tip_link}), "
            "solver.model.urdf.chain_from_urdf"
        )
        return BenchChain(name, pose, position, spec, source, True, _perm(pose, spec.joint_names))
    if name == "tail40":
        pose, position = tail(20, EffectorMode.POSE), tail(20, EffectorMode.POSITION)
        source = (
            "solver.examples.tail(n_links=20): 20 two-axis (x, z) joints, +-40 deg, 0.1 m links"
        )
    elif name == "humanoid_arm":
        pose, position = humanoid_arm(EffectorMode.POSE), humanoid_arm(EffectorMode.POSITION)
        source = (
            "solver.examples.humanoid_arm(): 3-axis shoulder (zxy, with pivot), elbow, "
            "forearm twist, 2-axis wrist"
        )
    else:
        raise KeyError(f"unknown chain {name!r}; known: {CHAINS}")
    gen = example_urdf(name, pose) if peer_urdf else None
    perm = _perm(pose, gen.joint_names) if gen else np.arange(pose.n_dof)
    if gen:
        source += (
            f"; peers load the generated {gen.urdf_path.relative_to(OUT_DIR.parent.parent.parent)}"
        )
    return BenchChain(name, pose, position, gen, source, False, perm)


def _perm(chain: Chain, peer_names: tuple[str, ...]) -> np.ndarray:
    if sorted(peer_names) != sorted(chain.dof_names):
        raise ValueError(f"peer joints {peer_names} != our variables {chain.dof_names}")
    return np.array([chain.dof_names.index(n) for n in peer_names])


# ---- URDF from a Chain ------------------------------------------------------------------
def _f(x: float) -> str:
    return repr(float(x))


def _rpy(r: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw with R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -float(r[2, 0]))))
    if abs(r[2, 0]) < 1.0 - 1e-12:
        roll = math.atan2(r[2, 1], r[2, 2])
        yaw = math.atan2(r[1, 0], r[0, 0])
    else:  # gimbal lock: put everything in yaw
        roll = 0.0
        yaw = math.atan2(-r[0, 1], r[1, 1])
    return roll, pitch, yaw


def _origin(t: np.ndarray, r: np.ndarray) -> str:
    from solver.model import rpy_to_matrix

    rpy = _rpy(r)
    if not np.allclose(rpy_to_matrix(*rpy), r, atol=1e-12):
        raise ValueError("rotation does not round-trip through rpy")
    return f'<origin xyz="{" ".join(map(_f, t))}" rpy="{" ".join(map(_f, rpy))}"/>'


def chain_to_urdf(chain: Chain, robot_name: str) -> tuple[str, str]:
    """URDF text of a single-effector chain and the tip link's name."""
    if len(chain.effectors) != 1:
        raise ValueError("one effector only")
    links: list[str] = [chain.root]
    joints: list[str] = []

    def joint(
        name: str,
        kind: str,
        parent: str,
        child: str,
        origin: str,
        axis: np.ndarray | None = None,
        lo: float | None = None,
        hi: float | None = None,
    ) -> None:
        parts = [
            f"<joint name={quoteattr(name)} type={quoteattr(kind)}>",
            origin,
            f"<parent link={quoteattr(parent)}/>",
            f"<child link={quoteattr(child)}/>",
        ]
        if axis is not None:
            parts.append(f'<axis xyz="{" ".join(map(_f, axis))}"/>')
        if lo is not None and hi is not None:
            parts.append(f'<limit lower="{_f(lo)}" upper="{_f(hi)}" effort="1" velocity="1"/>')
        joints.append("  " + "".join(parts) + "</joint>")

    unit = {"x": np.array([1.0, 0, 0]), "y": np.array([0, 1.0, 0]), "z": np.array([0, 0, 1.0])}
    for j in chain.joints:
        r0 = np.asarray(j.origin.rotation)
        t0 = np.asarray(j.origin.translation)
        pivot = np.asarray(j.pivot, dtype=float)
        if j.kind is JointKind.FIXED:
            joint(j.name, "fixed", j.parent, j.child, _origin(t0, r0))
            links.append(j.child)
            continue
        motions: list[tuple[str, str, np.ndarray, float | None, float | None]]
        if j.kind is JointKind.ROTATIONAL:
            motions = [
                (f"{j.name}.{a}", "revolute", unit[a], j.lower[k], j.upper[k])
                for k, a in enumerate(j.axes)
            ]
        else:
            kind = {
                JointKind.REVOLUTE: "revolute",
                JointKind.CONTINUOUS: "continuous",
                JointKind.PRISMATIC: "prismatic",
            }[j.kind]
            lo, hi = (None, None) if j.kind is JointKind.CONTINUOUS else (j.lower[0], j.upper[0])
            motions = [(j.name, kind, np.asarray(j.axis), lo, hi)]
        has_pivot = bool(np.any(pivot != 0.0))
        parent = j.parent
        origin = _origin(t0 + r0 @ pivot, r0)  # origin * Tr(pivot)
        for k, (name, kind, axis, lo, hi) in enumerate(motions):
            last = k == len(motions) - 1
            child = j.child if last and not has_pivot else f"{j.name}__{k}"
            joint(name, kind, parent, child, origin, axis, lo, hi)
            links.append(child)
            parent, origin = child, _origin(np.zeros(3), np.eye(3))
        if has_pivot:
            joint(f"{j.name}__unpivot", "fixed", parent, j.child, _origin(-pivot, np.eye(3)))
            links.append(j.child)
    eff = chain.effectors[0]
    tip = f"{eff.name}__tip"
    joint(
        f"{eff.name}__tip_joint",
        "fixed",
        eff.link,
        tip,
        _origin(np.asarray(eff.tip_offset), np.asarray(eff.tip_rotation)),
    )
    links.append(tip)
    body = "\n".join([f"  <link name={quoteattr(n)}/>" for n in links] + joints)
    return f'<?xml version="1.0"?>\n<robot name={quoteattr(robot_name)}>\n{body}\n</robot>\n', tip


def example_urdf(name: str, chain: Chain) -> RobotSpec:
    text, tip = chain_to_urdf(chain, name)
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    path = OUT_DIR / f"{name}.urdf"
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)
    return RobotSpec(name, path, chain.root, tip)
