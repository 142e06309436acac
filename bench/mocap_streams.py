"""The streams of bench/character_tracking.py: walk.bvh replayed at random.

The source is shared/assets/walk.bvh (CMU motion capture via cgspeed, 120 fps; frame 0
is a T-pose, the walk is frames 1-343), read with ``solver.model.bvh.read_bvh`` in
metres (``WALK_UNIT_M``, the tests' assumed unit). A character is the chain
``chain_from_skeleton`` builds for some of its hands and feet (the effectors) and a
set of moving bones; its reference joint path is the clip's own rotation channels
(``SkeletonChain.clip``: the chain's axes are the channels' order, so a frame maps to
q directly), and its targets are the chain's FK of that path.

A stream (``draw``) is a random start frame, a random playback speed in [0.5, 2] and a
random subset of 2-4 of the four effectors, from ``default_rng([seed, index])``: a
stream does not depend on how many streams run, and every variant (policy, effector
modes, moving set) replays the same streams. Playback resamples the clip's channels
by linear interpolation at 60 Hz and loops it back and forth (forwards, then
backwards): the clip's last frame is up to 1.1 rad (RightArm's x) from its first, so a
wrap-around loop would put a jump in the reference itself.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from solver.model import Effector, EffectorMode
from solver.model.bones import Motion, Skeleton
from solver.model.bvh import read_bvh
from solver.model.skeleton import SkeletonChain, SkeletonSettings, chain_from_skeleton

WALK_UNIT_M = 0.0254 / 0.45  # the CMU/cgspeed unit (shared/assets/README.md: an assumption)
FIRST_FRAME = 1  # frame 0 is a T-pose
HANDS = ("LeftHand", "RightHand")
FEET = ("LeftFoot", "RightFoot")
EFFECTORS = (*HANDS, *FEET)
# Each effector's limb, from its root (shoulder, hip) down to the effector's bone.
LIMBS: dict[str, tuple[str, ...]] = {
    "LeftHand": ("LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand"),
    "RightHand": ("RightShoulder", "RightArm", "RightForeArm", "RightHand"),
    "LeftFoot": ("LHipJoint", "LeftUpLeg", "LeftLeg", "LeftFoot"),
    "RightFoot": ("RHipJoint", "RightUpLeg", "RightLeg", "RightFoot"),
}
SPEEDS = (0.5, 2.0)


def walk_path(given: str | None = None) -> Path:
    """--bvh, $IK_SHARED_ASSETS/walk.bvh, or shared/assets/walk.bvh beside a parent."""
    if given:
        return Path(given)
    env = os.environ.get("IK_SHARED_ASSETS")
    if env:
        return Path(env) / "walk.bvh"
    for parent in Path(__file__).resolve().parents:
        path = parent / "shared" / "assets" / "walk.bvh"
        if path.is_file():
            return path
    raise SystemExit("walk.bvh not found: pass --bvh or set IK_SHARED_ASSETS")


@cache
def walk(path: Path) -> tuple[Skeleton, Motion]:
    """The skeleton and the motion of a BVH file (newline="" keeps its line endings)."""
    with open(path, encoding="ascii", newline="") as f:
        bvh = read_bvh(f.read(), unit_m=WALK_UNIT_M)
    assert bvh.motion is not None
    return bvh.skeleton, bvh.motion


@dataclass(frozen=True)
class StreamSpec:
    """One stream: where the clip starts, how fast it plays, which effectors it drives."""

    index: int
    start_frame: int  # into the walk (frames FIRST_FRAME..), at the stream's frame 0
    speed: float
    effectors: tuple[str, ...]  # a subset of EFFECTORS, in EFFECTORS order


def draw(seed: int, index: int, n_clip: int) -> StreamSpec:
    rng = np.random.default_rng([seed, index])
    start = int(rng.integers(0, n_clip))
    speed = float(rng.uniform(*SPEEDS))
    count = int(rng.integers(2, 5))
    chosen = set(rng.choice(len(EFFECTORS), size=count, replace=False).tolist())
    return StreamSpec(index, start, speed, tuple(e for i, e in enumerate(EFFECTORS) if i in chosen))


def character(
    path: Path, effectors: tuple[str, ...], *, hands_pose: bool, limbs_only: bool
) -> SkeletonChain:
    """The chain for these effectors: hands as POSE effectors if ``hands_pose`` (else
    POSITION), feet POSITION; moving bones the effectors' limbs or every bone."""
    skeleton, _ = walk(path)
    effs = [
        Effector(
            name=bone,
            link=bone,
            mode=EffectorMode.POSE if hands_pose and bone in HANDS else EffectorMode.POSITION,
        )
        for bone in effectors
    ]
    moving = [b for e in effectors for b in LIMBS[e]] if limbs_only else None
    return chain_from_skeleton(skeleton, SkeletonSettings(effectors=effs, moving=moving))


def reference(
    built: SkeletonChain, path: Path, spec: StreamSpec, frames: int, fps: float
) -> np.ndarray:
    """The stream's reference joint path, shape (frames, n_dof): the clip resampled at
    ``fps`` from ``spec.start_frame`` at ``spec.speed``, looped back and forth."""
    _, motion = walk(path)
    clip = built.clip(motion)[FIRST_FRAME:]
    n = clip.shape[0]
    step = spec.speed / (fps * motion.frame_time_s)  # clip frames per stream frame
    u = spec.start_frame + step * np.arange(frames)
    period = 2 * (n - 1)
    u = np.mod(u, period)
    u = np.where(u > n - 1, period - u, u)  # the way back
    lo = np.minimum(np.floor(u).astype(np.int64), n - 2)
    w = (u - lo)[:, None]
    out: np.ndarray = (1.0 - w) * clip[lo] + w * clip[lo + 1]
    return out
