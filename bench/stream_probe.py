"""One tracking stream of ``bench/ik.py`` part (c), frame by frame: ours beside the reference.

What ``bench/RESULTS.md`` ("iiwa tracking") quotes comes from this: the stream is built
by the benchmark's own generator (same seed, same order), tracked by
``IKSolver.track`` with the benchmark's stream options, and the frames around the
largest joint step are printed with the reference path's joints, each frame's largest
step, and the smallest singular value of the 6-D Jacobian (finite differences) there.

    OPENBLAS_NUM_THREADS=1 python -m bench.stream_probe --chain iiwa --stream 1
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from solver.chain import Chain  # noqa: E402
from solver.fk import effector_poses  # noqa: E402
from solver.ik import IKSolver  # noqa: E402

from .ik import Config, max_step, ours_options, reference_streams  # noqa: E402
from .ik_chains import CHAINS, load  # noqa: E402


def jacobian(chain: Chain, q: np.ndarray, h: float = 1e-7) -> np.ndarray:
    """6 x n, by forward differences: the first effector's position and its rotation as
    a world rotation vector."""
    p0 = effector_poses(chain, q)[0]
    jac = np.empty((6, q.size))
    for j in range(q.size):
        dq = q.copy()
        dq[j] += h
        p = effector_poses(chain, dq)[0]
        jac[:3, j] = (p[:3, 3] - p0[:3, 3]) / h
        r = p0[:3, :3].T @ p[:3, :3]
        w = 0.5 * np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
        jac[3:, j] = p0[:3, :3] @ w / h
    return jac


def smallest_singular_value(chain: Chain, q: np.ndarray) -> float:
    """Of the first effector's 6-D Jacobian."""
    return float(np.linalg.svd(jacobian(chain, q, 1e-6), compute_uv=False)[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--chain", default="iiwa", choices=CHAINS)
    ap.add_argument("--stream", type=int, default=1, help="0-based, as in the benchmark")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument("--around", type=int, default=8, help="frames shown each side")
    args = ap.parse_args(argv)

    bc = load(args.chain, peer_urdf=False)
    cfg = Config(1, 0, args.seed, 0.005, args.frames, args.fps, args.stream + 1, (), ())
    stream = list(reference_streams(cfg, bc))[args.stream]
    path, targets = stream.path, stream.targets
    solver = IKSolver(bc.pose, ours_options(1, stream=True, budget_us=cfg.timeout_s * 1e6))
    solver.set_pose(path[0])
    ours = np.empty_like(path)
    solved = np.empty(args.frames, dtype=bool)
    for k in range(args.frames):
        r = solver.track(targets[k])
        ours[k] = r.q
        solved[k] = r.success
    steps = np.abs(np.diff(ours, axis=0)).max(axis=1)
    worst = int(np.argmax(steps)) + 1
    ref = max_step(path)
    print(
        f"{args.chain} stream {args.stream}: reference's largest step {ref:.4f} rad; ours "
        f"{steps.max():.4f} rad at frame {worst} ({steps.max() / ref:.1f}x); "
        f"{int((~solved).sum())} frames outside tolerance"
    )
    np.set_printoptions(precision=3, suppress=True, linewidth=160)
    lo, hi = max(1, worst - args.around), min(args.frames, worst + args.around + 1)
    for k in range(lo, hi):
        print(
            f"{k:4d} step {steps[k - 1]:6.3f}  sigma_min {smallest_singular_value(bc.pose, ours[k]):.3f}"
            f"  ours {ours[k]}  reference {path[k]}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
