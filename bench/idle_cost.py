"""What one tracked frame costs in CPU, back to back and after the process sat idle.

Issue 24's bar puts the service's CPU per WebSocket frame against a bare echo's at the
same load. A stream at 60 Hz leaves the worker idle between messages, and on these
machines (2 shared virtual cores) work that follows an idle gap costs several times
its back-to-back CPU: caches and the core's clock have moved on. Compute (a solve)
pays that more than an echo, so the ratio depends on how idle the worker is.

This isolates it: ``IKSolver.track`` (the session's stream options) on the 7-DOF panda
arm following ``loadtest.paths``' path (the load tests' targets, pose mode), one frame
after another, with a sleep of ``--gaps`` ms before each. It prints, per gap, the
median and p90 CPU time of the call (``time.thread_time``), the median time inside the
compiled solve (``IKResult.solve_us``, a wall clock) and the median iterations (the
same work at every gap).

    OPENBLAS_NUM_THREADS=1 python -m bench.idle_cost [--frames 1200] [--gaps 0,0.5,2]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from dataclasses import dataclass

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from loadtest.paths import make_path  # noqa: E402
from solver.ik import STREAM_DEFAULTS, IKSolver, Target  # noqa: E402
from solver.model import examples  # noqa: E402
from solver.model.rotations import quaternion_to_matrix  # noqa: E402

CHAIN = "panda_arm"
RATE_HZ = 60.0


@dataclass(frozen=True, slots=True)
class GapRow:
    gap_ms: float
    cpu_us_median: float
    cpu_us_p90: float
    solve_us_median: float
    iterations_median: float


def path_targets() -> list[Target]:
    """The load tests' path for the panda arm, as solver targets (its FK poses)."""
    chain = examples.panda_arm()
    path = make_path(CHAIN, RATE_HZ)
    (effector,) = chain.effectors
    targets = []
    for frame in path.target_objs:
        (t,) = frame
        p, o = t["position"], t["orientation"]
        assert isinstance(p, dict) and isinstance(o, dict)
        rotation = quaternion_to_matrix(np.array([float(o[k]) for k in "wxyz"]))
        position = np.array([float(p[k]) for k in "xyz"])
        targets.append(Target(effector=effector.name, position=position, rotation=rotation))
    return targets


def measure(gaps_ms: list[float], frames: int) -> list[GapRow]:
    chain = examples.panda_arm()
    solver = IKSolver(chain, STREAM_DEFAULTS)
    targets = path_targets()
    for t in targets[:60]:  # warm: compiled entries resolved, the stream under way
        solver.track([t])
    rows = []
    k = 60
    for gap_ms in gaps_ms:
        cpu, solve, its = [], [], []
        for _ in range(frames):
            if gap_ms > 0:
                time.sleep(gap_ms * 1e-3)
            t0 = time.thread_time()
            r = solver.track([targets[k % len(targets)]])
            cpu.append((time.thread_time() - t0) * 1e6)
            solve.append(r.solve_us)
            its.append(r.iterations)
            k += 1
        cpu.sort()
        rows.append(
            GapRow(
                gap_ms,
                statistics.median(cpu),
                cpu[int(0.9 * len(cpu))],
                statistics.median(solve),
                statistics.median(its),
            )
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=1200, help="frames per gap")
    ap.add_argument("--gaps", default="0,0.5,2", help="idle ms before each frame, comma-separated")
    args = ap.parse_args()
    gaps = [float(g) for g in args.gaps.split(",")]
    rows = measure(gaps, args.frames)
    base = rows[0].cpu_us_median
    print(f"IKSolver.track, {CHAIN} pose path of loadtest.paths, {args.frames} frames per gap")
    print(
        "| idle before each frame | CPU per call median | p90 | / first row | compiled solve median | iterations median |"
    )
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r.gap_ms:g} ms | {r.cpu_us_median:.1f} us | {r.cpu_us_p90:.1f} us | "
            f"{r.cpu_us_median / base:.2f} | {r.solve_us_median:.1f} us | {r.iterations_median:g} |"
        )


if __name__ == "__main__":
    main()
