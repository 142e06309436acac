"""Targets beyond the arm: what a one-shot solve answers, with and without the reach
bound's judgement (solver/ik/reach.py), and what cutting the restarts would cost.

For each chain (the examples ``panda_arm`` and ``humanoid_arm``, position mode), 30
targets drawn from a seeded generator at 1.6-3 m from the root in random directions
(beyond both arms), one-shot ``IKSolver.solve`` from mid-limits:

- statuses and median wall time per solve, with the judgement (today) and without it
  (``ReachBounds.judged`` left out: what the service answered before 2026-11-30), at
  ``--budget-us`` (the service's default, 1000);
- the closest pose's distance to the target with ``max_restarts`` 0, 4 and 16 against
  all restarts (126) at 5 ms: why the judgement keeps the restarts.

    OPENBLAS_NUM_THREADS=1 python -m bench.out_of_reach [--budget-us 1000]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections import Counter
from dataclasses import replace

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from solver.ik import IKOptions, IKResult, IKSolver, Target  # noqa: E402
from solver.model import EffectorMode  # noqa: E402
from solver.model.examples import humanoid_arm, panda_arm  # noqa: E402

CHAINS = {"panda_arm": panda_arm, "humanoid_arm": humanoid_arm}


def far_targets(effector: str, n: int, seed: int) -> list[list[Target]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        d = rng.normal(size=3)
        out.append(
            [Target(effector=effector, position=d / np.linalg.norm(d) * rng.uniform(1.6, 3.0))]
        )
    return out


def solve(solver: IKSolver, targets: list[Target], judged: bool) -> tuple[IKResult, float]:
    if not judged:  # as before the bound: the status the optimizer's run gives
        solver._reach.judged = lambda result, targets, options: result  # type: ignore[method-assign]
    t0 = time.perf_counter()
    r = solver.solve(targets)
    return r, (time.perf_counter() - t0) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--budget-us", type=float, default=1000.0)
    ap.add_argument("--targets", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"one-shot solves of {args.targets} targets 1.6-3 m away, budget {args.budget_us:g} us")
    print("| chain | judgement | statuses | median us per solve |")
    print("|---|---|---|---|")
    quality: list[str] = []
    for name, make in CHAINS.items():
        chain = make(EffectorMode.POSITION)
        frames = far_targets(chain.effector_names[0], args.targets, args.seed)
        for judged in (False, True):
            statuses: Counter[str] = Counter()
            times = []
            for t in frames:
                r, us = solve(IKSolver(chain, IKOptions(time_budget_us=args.budget_us)), t, judged)
                statuses[r.status.value] += 1
                times.append(us)
            label = "with (today)" if judged else "without"
            counts = ", ".join(f"{k} {v}" for k, v in sorted(statuses.items()))
            print(f"| {name} | {label} | {counts} | {statistics.median(times):.0f} |")
        full = [
            IKSolver(chain, IKOptions(time_budget_us=5000.0)).solve(t).effectors[0].position_error_m
            for t in frames
        ]
        for cap in (0, 4, 16):
            options = replace(IKOptions(time_budget_us=5000.0), max_restarts=cap)
            farther = np.array(
                [IKSolver(chain, options).solve(t).effectors[0].position_error_m for t in frames]
            ) - np.array(full)
            quality.append(
                f"| {name} | {cap} | {np.median(farther) * 100:.2f} | {farther.max() * 100:.1f} | "
                f"{int((farther > 1e-3).sum())} of {len(frames)} |"
            )
    print("\nthe closest pose with fewer restarts, against all (126), 5 ms budget")
    print(
        "| chain | restarts | farther from the target, median [cm] | max [cm] | farther by > 1 mm |"
    )
    print("|---|---|---|---|---|")
    print("\n".join(quality))


if __name__ == "__main__":
    main()
