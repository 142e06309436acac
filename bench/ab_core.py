"""A/B of the compiled solve between two checkouts, in one session.

How the per-commit ratios in ``bench/history/2026-11-23-solver-changes.md`` ("Solver
changes of the afternoon") were taken: one worker process per checkout (each imports
its own ``solver`` and uses its own numba cache), both warmed on the same 400 random
targets of one arm, then alternating batches (A then B, B then A, ...), each reporting
the median in-core ``solve_us`` of one pass over the targets. Paired ratios of batch
medians cancel most of the shared machine's drift: the same build against itself gave
0.997-1.006 over 11 rounds, while a 5-round run was once off by 25%, hence the default
of 15.

    OPENBLAS_NUM_THREADS=1 python -m bench.ab_core CHECKOUT_A CHECKOUT_B --chain panda --part a

Parts: (a) pose targets, (b) position targets, both solved from the mid-limits seed
(``IKSolver.solve``); (c) tracking: ``bench/ik/`` part (c)'s first reference
streams (``--streams``, 600 frames at 60 fps each), each tracked from its first pose
with the stream options (``IKSolver.track``), a batch's median over all their frames.

A checkout is a directory with ``solver/`` and ``bench/`` (e.g. ``git worktree add
/tmp/base HEAD~1``); its first run compiles the solver (~45 s). The worker runs inside
each checkout, so it only uses names both layouts of ``solver/`` have (before and
after the split into optim/, model/, ik/, path/).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys

_WORKER = """
import sys
sys.path.insert(0, sys.argv[1])
import numpy as np
from bench import ik, ik_chains
from solver.ik import IKSolver
import os
# Decided by the checkout's files, not by trying the import: the editable install's
# finder can resolve a missing subpackage to another tree's directory.
if os.path.exists(os.path.join(sys.argv[1], "solver", "model", "forward.py")):
    from solver.model.forward import effector_poses
else:  # a checkout from before solver/ had layers
    from solver.fk import effector_poses
bc = ik_chains.load(sys.argv[2], peer_urdf=False)
part = sys.argv[3]
c = bc.pose
if part == "c":
    cfg = ik.Config(0, 0, 0, 0.0, 600, 60.0, int(sys.argv[4]), (), ())
    streams = [(s.path[0], s.targets) for s in ik.reference_streams(cfg, bc)]
    solver = IKSolver(c, ik.ours_options(1, stream=True))

    def batch():
        out = []
        for q0, frames in streams:
            solver.set_pose(q0)
            out += [solver.track(t).solve_us for t in frames]
        return out
else:
    position = part == "b"
    qs = np.random.default_rng(0).uniform(c.lower, c.upper, size=(400, c.n_dof))
    targets = ik._targets_for(bc, np.array([effector_poses(c, q)[0] for q in qs]), position)
    solver = IKSolver(bc.position if position else c, ik.ours_options())
    seed = 0.5 * (c.lower + c.upper)

    def batch():
        return [solver.solve(t, seed).solve_us for t in targets]
batch()
print("ready", flush=True)
for _ in sys.stdin:
    print(float(np.median(batch())), flush=True)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("a", help="checkout A (the baseline)")
    parser.add_argument("b", help="checkout B")
    parser.add_argument("--chain", default="panda", help="panda, ur5 or iiwa")
    parser.add_argument(
        "--part", choices=("a", "b", "c"), default="a", help="a: pose, b: position, c: tracking"
    )
    parser.add_argument("--streams", type=int, default=1, help="part (c): streams per batch")
    parser.add_argument("--rounds", type=int, default=15)
    args = parser.parse_args()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    workers = [
        subprocess.Popen(
            [
                sys.executable,
                "-c",
                _WORKER,
                os.path.abspath(path),
                args.chain,
                args.part,
                str(args.streams),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
        )
        for path in (args.a, args.b)
    ]
    for w in workers:
        assert w.stdin is not None and w.stdout is not None
        if w.stdout.readline().strip() != "ready":
            sys.exit("a worker failed to start (see its error above)")
    medians: list[list[float]] = [[], []]
    for i in range(args.rounds):
        for k in (0, 1) if i % 2 == 0 else (1, 0):
            w = workers[k]
            assert w.stdin is not None and w.stdout is not None
            w.stdin.write("go\n")
            w.stdin.flush()
            medians[k].append(float(w.stdout.readline()))
    for w in workers:
        assert w.stdin is not None
        w.stdin.close()
        w.wait()
    ratios = [b / a for a, b in zip(medians[0], medians[1], strict=True)]
    print(
        "| chain | part | A core median us | B core median us | B / A (median of paired batches) |"
    )
    print("|---|---|---|---|---|")
    print(
        f"| {args.chain} | {args.part} | {statistics.median(medians[0]):.2f} | "
        f"{statistics.median(medians[1]):.2f} | {statistics.median(ratios):.3f} |"
    )


if __name__ == "__main__":
    main()
