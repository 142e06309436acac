"""Per-frame cost of a game character: import, a 2-arm + 2-leg stream, bone output.

CesiumMan.glb (shared/assets) becomes a chain with pose effectors on both hands and
position effectors on both feet; ``IKSolver.track`` with the stream defaults follows
targets taken from a smooth joint path near the rest pose (so every target is within
reach); each frame's answer is then turned into what a game engine applies
(``SkeletonChain.local_rotations`` for the moving bones, ``world_transforms`` of the
four effector bones). Reported: import times, frames solved, per-frame solve and output
times (median and 99th percentile, microseconds), for every bone moving (the default)
and for the limbs only; then the same stream with blend weights (0.5 on the feet's
positions and the hands' rotations: the blend towards the start pose) and with a pole
on each limb (knees and elbows, the default bone; each pole 0.3 m in front of that
bone in the path's pose, so the poles move with the path), and the poles' first frame
held for every frame (a character standing still). Each line ends with the largest
joint step from one answer to the next (median, largest, median over the last half:
0 for a stream that settles).

    OPENBLAS_NUM_THREADS=1 python -m bench.skeleton --frames 300 [--budget-us 0]
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from solver.ik import (  # noqa: E402
    STREAM_DEFAULTS,
    IKSolver,
    Pole,
    Target,
    default_pole_link,
    pose_targets,
)
from solver.model import Chain, Effector, EffectorMode  # noqa: E402
from solver.model.bvh import read_bvh  # noqa: E402
from solver.model.forward import link_poses  # noqa: E402
from solver.model.gltf import read_gltf  # noqa: E402
from solver.model.skeleton import SkeletonSettings, chain_from_skeleton  # noqa: E402

# CesiumMan's joint nodes (shared/assets/README.md gives RiggedFigure's upstream names,
# same indices): arms 13-15 (right), 16-18 (left); legs 3-6 (right), 7-10 (left).
LIMBS = tuple(f"node_{i}" for i in range(3, 11)) + tuple(f"node_{i}" for i in range(13, 19))


def assets_dir(given: str | None) -> Path:
    """--assets, $IK_SHARED_ASSETS, or shared/assets beside a parent of this repository."""
    if given:
        return Path(given)
    env = os.environ.get("IK_SHARED_ASSETS")
    if env:
        return Path(env)
    for parent in Path(__file__).resolve().parents:
        if (parent / "shared" / "assets" / "CesiumMan.glb").is_file():
            return parent / "shared" / "assets"
    raise SystemExit("shared/assets not found: pass --assets or set IK_SHARED_ASSETS")


def per_call_us(fn: object, repeat: int) -> float:
    start = time.perf_counter()
    for _ in range(repeat):
        fn()  # type: ignore[operator]
    return (time.perf_counter() - start) / repeat * 1e6


def smooth_poses(chain: Chain, frames: int, amplitude_rad: float, seed: int) -> list[np.ndarray]:
    """A smooth joint path from the rest pose: each joint a sine over ``frames`` frames
    with a random amplitude within ``amplitude_rad`` and a random phase, starting at 0;
    each pose clipped into the limits (so every target it gives is within reach)."""
    rng = np.random.default_rng(seed)
    amplitude = rng.uniform(-amplitude_rad, amplitude_rad, chain.n_dof)
    phase = rng.uniform(0.0, 2.0 * np.pi, chain.n_dof)
    t = np.arange(frames)[:, None] / frames
    path = amplitude * (np.sin(2.0 * np.pi * t + phase) - np.sin(phase))
    return [np.clip(q, chain.lower, chain.upper) for q in path]


def weighted(targets: list[Target]) -> list[Target]:
    """Position weight 0.5 on position effectors, rotation weight 0.5 on pose ones."""
    return [
        Target(
            effector=t.effector,
            position=t.position,
            rotation=t.rotation,
            position_weight=0.5 if t.rotation is None else 1.0,
            rotation_weight=0.5,
        )
        for t in targets
    ]


def with_poles(targets: list[Target], poles: list[np.ndarray]) -> list[Target]:
    return [
        Target(effector=t.effector, position=t.position, rotation=t.rotation, pole=Pole(p))
        for t, p in zip(targets, poles, strict=True)
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--assets", default=None)
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--budget-us",
        type=float,
        default=STREAM_DEFAULTS.time_budget_us,
        help="time budget per frame (0: none); default the stream defaults'",
    )
    args = ap.parse_args(argv)
    folder = assets_dir(args.assets)

    glb = (folder / "CesiumMan.glb").read_bytes()
    with open(folder / "walk.bvh", encoding="ascii", newline="") as f:
        walk = f.read()
    print(f"read_gltf CesiumMan.glb: {per_call_us(lambda: read_gltf(glb), 20) / 1e3:.2f} ms")
    print(f"read_bvh walk.bvh (344 frames): {per_call_us(lambda: read_bvh(walk), 5) / 1e3:.2f} ms")

    skeleton = read_gltf(glb)
    effectors = [
        Effector(name="left_hand", link="node_18", mode=EffectorMode.POSE),
        Effector(name="right_hand", link="node_15", mode=EffectorMode.POSE),
        Effector(name="left_foot", link="node_10"),
        Effector(name="right_foot", link="node_6"),
    ]
    for label, moving in (("every bone moves", None), ("limbs only", LIMBS)):
        built = chain_from_skeleton(skeleton, SkeletonSettings(effectors=effectors, moving=moving))
        chain = built.chain
        poses = smooth_poses(chain, args.frames, 0.4, args.seed)
        plain = [pose_targets(chain, q) for q in poses]
        bent = [default_pole_link(chain, i) for i in range(len(effectors))]
        forward = np.array([0.0, 0.0, 0.3])  # glTF's front (+z), 0.3 m
        poled = [
            with_poles(t, [link_poses(chain, q)[b][:3, 3] + forward for b in bent])  # type: ignore[index]
            for t, q in zip(plain, poses, strict=True)
        ]
        streams = (
            ("", plain),
            (" + weights 0.5", [weighted(t) for t in plain]),
            (f" + poles on {', '.join(b or '-' for b in bent)}", poled),
            # A character standing still: the first frame, poles and all, every frame.
            (" + poles, the first frame held", [poled[0]] * len(poled)),
        )
        for variant, stream in streams:
            budget = args.budget_us if args.budget_us > 0 else None
            options = replace(STREAM_DEFAULTS, time_budget_us=budget)
            solver = IKSolver(chain, options, seed=args.seed)
            solve_us, output_us, steps, solved = [], [], [], 0
            bones = [e.link for e in effectors]
            previous = None
            for targets in stream:
                start = time.perf_counter()
                result = solver.track(targets)
                mid = time.perf_counter()
                if previous is not None:  # the largest joint step from the last answer
                    steps.append(float(np.abs(result.q - previous).max()))
                previous = result.q.copy()
                built.local_rotations(result.q)
                built.world_transforms(result.q, bones)
                end = time.perf_counter()
                solve_us.append((mid - start) * 1e6)
                output_us.append((end - mid) * 1e6)
                solved += result.success
            print(
                f"{label}{variant}: {len(built.moving)} bones, {chain.n_dof} variables, "
                f"solved {solved}/{args.frames}; solve p50 {np.median(solve_us):.0f} us, "
                f"p99 {np.percentile(solve_us, 99):.0f} us; bone output p50 "
                f"{np.median(output_us):.0f} us, p99 {np.percentile(output_us, 99):.0f} us; "
                f"largest joint step per frame p50 {np.median(steps):.4f} rad, max "
                f"{max(steps):.4f} rad, p50 over the last half "
                f"{np.median(steps[len(steps) // 2 :]):.4f} rad"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
