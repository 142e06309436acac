"""Probe of 2026-11-29-bvh-euler-wall.md: circles tracked by a hand (or foot) whose limb
has 3-angle ball joints, with the middle angle of each joint limited to +-pi/2 (main's
default until this branch) or to +-pi like the other two, under the session's stream
options (``service.convert.options.session_defaults``: ``smooth``, 0.1 rad per frame)
and under ``reach``; both limit sets are given explicitly, so the run does not depend
on which default the checkout has.

    OPENBLAS_NUM_THREADS=1 python bench/history/bvh_euler_wall_probe.py [random circles per limb]

(from the repository root; the assets from /work/shared/assets or $IK_ASSETS). Per limb:
the fixed streams A-D (walk.bvh's left arm, circles of 8 cm whose centres are 0.15-0.19 m
from the shoulder, so the elbow bends a lot), then random circles of 8 cm (seeded),
each one turn in 5 s at 60 Hz (300 frames), every point within the limb's reach.
Reported per configuration: frames not reached, worst position error, longest run of
failures, the largest joint step after the first frame, the median time per frame.
"""

# ruff: noqa: E402  (the repository root goes on sys.path before the imports)

import math
import os
import pathlib
import sys
import time
from dataclasses import replace

sys.path.insert(0, ".")
import numpy as np

from service.config import Settings
from service.convert.options import session_defaults
from solver.ik import Continuity, IKOptions, IKSolver, Target
from solver.model import Effector
from solver.model.bvh import read_bvh
from solver.model.gltf import read_gltf
from solver.model.skeleton import BoneSettings, SkeletonSettings, chain_from_skeleton

ASSETS = pathlib.Path(os.environ.get("IK_ASSETS", "/work/shared/assets"))
PI = math.pi
SMOOTH = session_defaults(Settings())
REACH = replace(SMOOTH, continuity=Continuity.REACH)
# A limit band a client could ask for instead (limit_margin, limit_weight).
BAND = replace(SMOOTH, limit_margin=0.1, limit_weight=1e-2)
# (outer axes, middle axis) bounds [rad]
LIMITS = {
    "middle +-pi/2": (PI, PI / 2),
    "every axis +-pi": (PI, PI),
    "every axis +-2pi": (2 * PI, 2 * PI),
}
RADIUS_M = 0.08
FRAMES = 300


def limb(source: str, moving: tuple[str, ...], pivot: str, tip: str, bounds: tuple[float, float]):  # type: ignore[no-untyped-def]
    """The chain, its pivot's world position and its two segment lengths."""
    if source == "walk.bvh":
        skeleton = read_bvh((ASSETS / source).read_text(), unit_m=0.056).skeleton
    else:
        skeleton = read_gltf((ASSETS / source).read_bytes())
    outer, middle = bounds
    bones = {
        b: BoneSettings(lower=(-outer, -middle, -outer), upper=(outer, middle, outer))
        for b in moving
    }
    built = chain_from_skeleton(
        skeleton,
        SkeletonSettings(effectors=[Effector(name=tip, link=tip)], moving=moving, bones=bones),
    )
    names = list(built.moving)
    joint = names[names.index(pivot) + 1]
    w = built.world_transforms(np.zeros(built.chain.n_dof), [pivot, joint, tip])
    a = float(np.linalg.norm(w[joint][:3, 3] - w[pivot][:3, 3]))
    b = float(np.linalg.norm(w[tip][:3, 3] - w[joint][:3, 3]))
    return built.chain, w[pivot][:3, 3], a, b


def circle(centre: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """FRAMES points, one turn in 5 s at 60 Hz, starting at angle 0."""
    normal = normal / np.linalg.norm(normal)
    u = np.cross(normal, [0.0, 1.0, 0.0] if abs(normal[1]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    angle = 2.0 * PI * np.arange(FRAMES) / 300.0
    return centre + RADIUS_M * (np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v)


def track(chain, tip: str, points: np.ndarray, options: IKOptions) -> dict[str, float]:  # type: ignore[no-untyped-def]
    solver = IKSolver(chain, options)  # a new session: starts at the rest pose
    prev = solver.q.copy()
    ok, err, steps, us = [], [], [], []
    for p in points:
        t0 = time.perf_counter()
        r = solver.track([Target(effector=tip, position=p)], options=options)
        us.append((time.perf_counter() - t0) * 1e6)
        ok.append(r.success)
        err.append(r.max_position_error_m)
        steps.append(float(np.abs(r.q - prev).max()))
        prev = r.q.copy()
    run = longest = 0
    for good in ok:
        run = 0 if good else run + 1
        longest = max(longest, run)
    return {
        "fail": FRAMES - sum(ok),
        "worst_cm": 100.0 * max(err),
        "run": longest,
        "step": max(steps[1:]),
        "us": float(np.median(us)),
    }


LIMBS = {  # name: source, moving bones, pivot (the ball joint the circle centres on), tip
    "walk L arm": ("walk.bvh", ("LeftArm", "LeftForeArm"), "LeftArm", "LeftHand"),
    "walk L arm+clavicle+hand": (
        "walk.bvh",
        ("LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand"),
        "LeftArm",
        "LeftHand",
    ),
    "walk R arm+clavicle+hand": (
        "walk.bvh",
        ("RightShoulder", "RightArm", "RightForeArm", "RightHand"),
        "RightArm",
        "RightHand",
    ),
    "walk L leg": ("walk.bvh", ("LeftUpLeg", "LeftLeg"), "LeftUpLeg", "LeftFoot"),
    "CesiumMan L arm": ("CesiumMan.glb", ("node_16", "node_17"), "node_16", "node_18"),
}
FIXED = {  # the stream (limb, centre - pivot [m], circle normal)
    "A": ("walk L arm", (0.05, 0.10, -0.10), (0.2, 0.9, -0.35)),
    "B": ("walk L arm+clavicle+hand", (0.0, 0.06, 0.175), (0.8, -0.36, -0.46)),
    "C": ("walk L arm+clavicle+hand", (-0.10, 0.14, 0.0), (0.73, -0.6, -0.33)),
    "D": ("walk L arm", (0.087, 0.0, -0.12), (0.05, 0.27, -0.96)),
}
CONFIGS = (
    ("middle +-pi/2", "smooth", SMOOTH),
    ("middle +-pi/2", "smooth+band", BAND),
    ("middle +-pi/2", "reach", REACH),
    ("every axis +-pi", "smooth", SMOOTH),
    ("every axis +-pi", "reach", REACH),
    ("every axis +-2pi", "smooth", SMOOTH),
    ("every axis +-2pi", "reach", REACH),
)


def line(label: str, rows: list[dict[str, float]]) -> str:
    fails = [r["fail"] for r in rows]
    return (
        f"{label:44s} fail {sum(fails):4d} (streams {sum(f > 0 for f in fails):2d}/{len(rows)})"
        f"  worst {max(r['worst_cm'] for r in rows):5.2f} cm  run {max(r['run'] for r in rows):3d}"
        f"  step {max(r['step'] for r in rows):5.3f}"
        f"  median us {float(np.median([r['us'] for r in rows])):6.1f}"
    )


def main() -> None:
    per_limb = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    chains = {
        (name, lim): limb(*spec, bounds)
        for name, spec in LIMBS.items()
        for lim, bounds in LIMITS.items()
    }
    for stream, (name, offset, normal) in FIXED.items():
        tip = LIMBS[name][3]
        for lim, policy, options in CONFIGS:
            chain, pivot, _, _ = chains[(name, lim)]
            points = circle(pivot + np.array(offset), np.array(normal, dtype=float))
            print(
                line(f"{stream} {lim} {policy}", [track(chain, tip, points, options)]), flush=True
            )
    rng = np.random.default_rng(0)
    for name, spec in LIMBS.items():
        tip = spec[3]
        _, pivot, a, b = chains[(name, "middle +-pi/2")]
        inner, outer = abs(a - b) + 0.02, a + b - 0.02
        streams = []
        while len(streams) < per_limb:
            d = rng.normal(size=3)
            centre = pivot + d / np.linalg.norm(d) * rng.uniform(inner + RADIUS_M, 0.6 * (a + b))
            points = circle(centre, rng.normal(size=3))
            dist = np.linalg.norm(points - pivot, axis=1)
            if dist.min() >= inner and dist.max() <= outer:
                streams.append(points)
        for lim, policy, options in CONFIGS:
            chain = chains[(name, lim)][0]
            rows = [track(chain, tip, points, options) for points in streams]
            print(line(f"{name} {lim} {policy}", rows), flush=True)


if __name__ == "__main__":
    main()
