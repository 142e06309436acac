"""Solve fixed targets on the multi-tip chains of the URDF sweep (no time budget) and
save each solve's iterations, evaluations and q, to compare two checkouts bit for bit.

PYTHONPATH=<checkout> python bench/history/iteration_cost_same.py PYBULLET_DATA OUT.npz
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from bench.urdf_sweep import (
    NAMED_MULTI,
    chains_of,
    random_q,
    read_text,
    tree_of,
    urdf_files,
    with_modes,
)
from solver import IKOptions, IKSolver, Target
from solver.model.forward import link_poses
from solver.model.urdf import chain_from_urdf

FILES = ("g1_29dof_rev_1_0.urdf", "tiago.urdf", "baxter.urdf", "pr2.urdf", "icub_reduced.urdf")


def main() -> None:
    out: dict[str, np.ndarray] = {}
    for _, path in urdf_files(Path(sys.argv[1])):
        if path.name not in FILES:
            continue
        text = read_text(path)
        tree = tree_of(text)
        if tree is None:
            continue
        base, tips = chains_of(tree)
        groups = [[t[0] for t in tips]] + NAMED_MULTI.get(path.name, [])
        for k, tip_links in enumerate(groups):
            chain = with_modes(chain_from_urdf(text, base_link=base, tip_links=tip_links))
            if chain.n_dof > 30:
                continue
            solver = IKSolver(chain, IKOptions(time_budget_us=None, max_restarts=3), seed=7)
            rng = np.random.default_rng(11)
            qs, counts = [], []
            for _ in range(40):
                frames = link_poses(chain, random_q(chain, rng))
                targets = [
                    Target(
                        effector=e.name,
                        position=frames[e.link][:3, 3].copy(),
                        rotation=frames[e.link][:3, :3].copy() if e.mode.value == "pose" else None,
                    )
                    for e in chain.effectors
                ]
                r = solver.solve(targets, seed=chain.mid_limits())
                qs.append(r.q)
                counts.append((r.iterations, r.function_evals, r.restarts, r.success))
            key = f"{path.name}#{k}"
            out[key + ".q"] = np.array(qs)
            out[key + ".n"] = np.array(counts)
            print(
                key, chain.n_dof, "dof; iterations", int(np.sum(np.array(counts)[:, 0])), flush=True
            )
    np.savez(sys.argv[2], **out)


if __name__ == "__main__":
    main()
