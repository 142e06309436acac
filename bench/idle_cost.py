"""What one tracked frame costs in CPU, back to back and after the process sat idle.

Issue 24's bar puts the service's CPU per WebSocket frame against a bare echo's at the
same load. A stream at 60 Hz leaves the worker idle between messages, and on these
machines (2 shared virtual cores) work that follows an idle gap costs several times
its back-to-back CPU: caches and the core's clock have moved on. Compute (a solve)
pays that more than an echo, so the ratio depends on how idle the worker is.

This isolates it: ``IKSolver.track`` (the session's stream options) on the 7-DOF panda
arm following ``loadtest.paths``' path (the load tests' targets, pose mode), one frame
after another, with a sleep of ``--gaps`` ms before each. Each gap has its own solver
tracking the same targets from the same start, and the gaps take turns 60 frames at a
time, so that they do the same work under the same load. It prints, per gap, the
median and p90 CPU time of the call (``time.thread_time``), the median time inside the
compiled solve (``IKResult.solve_us``, a wall clock), the median per call of the
difference (the Python around the compiled solve, roughly), and the iterations over
all frames (equal at every gap: the same work).

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
    around_us_median: float  # per call: its CPU minus its solve_us (the Python around it)
    iterations: int  # over all frames: the same at every gap (the same targets)


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


def measure(gaps_ms: list[float], frames: int, block: int = 60) -> list[GapRow]:
    """Each gap's own solver tracks the same targets from the same start; the gaps take
    turns block by block (the order rotating), so that a change of the machine's load
    falls on every gap alike."""
    targets = path_targets()
    solvers = [IKSolver(examples.panda_arm(), STREAM_DEFAULTS) for _ in gaps_ms]
    for solver in solvers:
        for t in targets[:60]:  # warm: compiled entries resolved, the stream under way
            solver.track([t])
    cpu: list[list[float]] = [[] for _ in gaps_ms]
    solve: list[list[float]] = [[] for _ in gaps_ms]
    iterations = [0 for _ in gaps_ms]
    for b, first in enumerate(range(60, 60 + frames, block)):
        order = list(range(len(gaps_ms)))
        order = order[b % len(order) :] + order[: b % len(order)]
        for g in order:
            pause = gaps_ms[g] * 1e-3
            for k in range(first, min(first + block, 60 + frames)):
                if pause > 0:
                    time.sleep(pause)
                t0 = time.thread_time()
                r = solvers[g].track([targets[k % len(targets)]])
                cpu[g].append((time.thread_time() - t0) * 1e6)
                solve[g].append(r.solve_us)
                iterations[g] += r.iterations
    rows = []
    for g, gap_ms in enumerate(gaps_ms):
        around = sorted(c - s for c, s in zip(cpu[g], solve[g], strict=True))
        ordered = sorted(cpu[g])
        rows.append(
            GapRow(
                gap_ms,
                statistics.median(ordered),
                ordered[int(0.9 * len(ordered))],
                statistics.median(solve[g]),
                statistics.median(around),
                iterations[g],
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
        "| idle before each frame | CPU per call median | p90 | / back to back "
        "| compiled solve (solve_us) median | the call's CPU minus its solve_us, median "
        "| iterations, all frames |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r.gap_ms:g} ms | {r.cpu_us_median:.1f} us | {r.cpu_us_p90:.1f} us | "
            f"{r.cpu_us_median / base:.2f} | {r.solve_us_median:.1f} us | "
            f"{r.around_us_median:.1f} us | {r.iterations} |"
        )


if __name__ == "__main__":
    main()
