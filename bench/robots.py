"""Robot models for the IK benchmark, taken from URDFs that ship inside PyPI packages.

Nothing here is downloaded at run time: the URDFs come from the `example-robot-data`
wheel (Panda, UR5) and the `rtb-data` wheel (KUKA LBR iiwa 14 R820), both benchmark
extras (see bench/PEERS.md). Only joints matter for IK, so mesh references
(`package://...`) are left as they are and never resolved.
"""

from __future__ import annotations

import importlib.metadata
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

ROBOTS: tuple[str, ...] = ("panda", "ur5", "iiwa")
# Two more arms for the tracking benchmark (bench/tracking.py): 7-DOF, both in
# example-robot-data; not in ROBOTS, which bench/ik/'s tables and bars are about.
TRACKING_ARMS: tuple[str, ...] = ("baxter_left", "pr2_right")

# (distribution name, path inside the distribution, base link, tip link)
# Tips are the flange frames, chosen so the chain has 7 (Panda, iiwa) / 6 (UR5) DOF:
#  - panda_link8: flange, 0.107 m past joint 7; the hand and fingers hang below it.
#  - tool0: REP-199 flange frame on UR5 and iiwa (0.126 m past joint a7 on the iiwa).
_ERD = "cmeel.prefix/share/example-robot-data/robots"
_SOURCES: dict[str, tuple[str, str, str, str]] = {
    "panda": (
        "example-robot-data",
        f"{_ERD}/panda_description/urdf/panda.urdf",
        "panda_link0",
        "panda_link8",
    ),
    # ur5_robot.urdf has +-2pi limits (elbow +-pi); the *_joint_limited file has +-pi.
    # The unlimited one matches the stock UR5 and TRAC-IK's UR5 setup.
    "ur5": (
        "example-robot-data",
        f"{_ERD}/ur_description/urdf/ur5_robot.urdf",
        "base_link",
        "tool0",
    ),
    "iiwa": (
        "rtb-data",
        "rtbdata/xacro/kuka_description/kuka_lbr_iiwa/urdf/lbr_iiwa_14_r820.urdf",
        "base_link",
        "tool0",
    ),
    # Baxter's left arm from its mount on the torso to the gripper frame (s0 .. w2).
    "baxter_left": (
        "example-robot-data",
        f"{_ERD}/baxter_description/urdf/baxter.urdf",
        "left_arm_mount",
        "left_gripper",
    ),
    # PR2's right arm from the torso lift link (the lift itself stays out) to the tool
    # frame: forearm and wrist roll are continuous joints (no limits).
    "pr2_right": (
        "example-robot-data",
        f"{_ERD}/pr2_description/urdf/pr2.urdf",
        "torso_lift_link",
        "r_gripper_tool_frame",
    ),
}


@dataclass(frozen=True)
class Joint:
    name: str
    type: str  # "revolute", "prismatic", "continuous" or "fixed"
    lower: float
    upper: float
    child: str  # the link this joint moves


@dataclass(frozen=True)
class RobotSpec:
    name: str
    urdf_path: Path
    base_link: str
    tip_link: str

    def urdf_text(self) -> str:
        """The URDF as shipped (package:// mesh refs untouched)."""
        return self.urdf_path.read_text()

    def kinematic_urdf_text(self) -> str:
        """The URDF without <visual>/<collision>: loaders that try to resolve
        package:// mesh paths (roboticstoolbox's xacrodoc) choke on the originals."""
        return re.sub(r"<(visual|collision)\b.*?</\1>", "", self.urdf_text(), flags=re.S)

    def chain(self) -> tuple[Joint, ...]:
        """Movable joints from base_link to tip_link, in chain order."""
        return tuple(
            j for j in _path(self.urdf_path, self.base_link, self.tip_link) if j.type != "fixed"
        )

    def path_elements(self) -> tuple[str, ...]:
        """[base_link, joint, link, ..., tip_link], fixed joints included (ikpy's base_elements)."""
        out = [self.base_link]
        for j in _path(self.urdf_path, self.base_link, self.tip_link):
            out += [j.name, j.child]
        return tuple(out)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.chain())

    @property
    def lower(self) -> np.ndarray:
        return np.array([j.lower for j in self.chain()])

    @property
    def upper(self) -> np.ndarray:
        return np.array([j.upper for j in self.chain()])

    @property
    def dof(self) -> int:
        return len(self.chain())

    def mid(self) -> np.ndarray:
        """The mid-limits seed of the TRAC-IK protocol."""
        return 0.5 * (self.lower + self.upper)


@cache
def _path(path: Path, base: str, tip: str) -> tuple[Joint, ...]:
    """All joints (fixed ones too) from base to tip, walking up from the tip."""
    root = ET.parse(path).getroot()
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    joints: list[Joint] = []
    link = tip
    while link != base:
        if link not in by_child:
            raise ValueError(f"{tip} is not below {base} in {path}")
        j = by_child[link]
        kind, lim = j.get("type"), j.find("limit")
        if kind in ("continuous", "fixed") or lim is None:
            lo, hi = -np.inf, np.inf
        else:
            lo, hi = float(lim.get("lower", 0.0)), float(lim.get("upper", 0.0))
        joints.append(Joint(j.get("name"), kind, lo, hi, link))
        link = j.find("parent").get("link")
    return tuple(reversed(joints))


@cache
def robot(name: str) -> RobotSpec:
    if name not in _SOURCES:
        raise KeyError(f"unknown robot {name!r}; known: {ROBOTS}")
    dist, rel, base, tip = _SOURCES[name]
    try:
        path = Path(str(importlib.metadata.distribution(dist).locate_file(rel)))
    except importlib.metadata.PackageNotFoundError as e:
        raise FileNotFoundError(f"{name}: pip install {dist} (benchmark extra)") from e
    if not path.is_file():
        raise FileNotFoundError(f"{name}: {path} missing from {dist}")
    return RobotSpec(name, path, base, tip)


if __name__ == "__main__":
    for n in ROBOTS:
        r = robot(n)
        print(f"{n}: {r.urdf_path}\n  {r.base_link} -> {r.tip_link}, {r.dof} DOF")
        for j in r.chain():
            print(f"    {j.name:22s} {j.type:10s} [{j.lower:+.4f}, {j.upper:+.4f}]")
