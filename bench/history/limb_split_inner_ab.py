"""Interleaved A/B of IKOptions.inner_first on one sweep chain (2026-11-28-limb-split.md):
the same targets, each solved by both in one process, alternating which goes first.

    SEED=1 OPENBLAS_NUM_THREADS=1 python bench/history/limb_split_inner_ab.py baxter.urdf 1000
"""

# ruff: noqa: E402  (the repository root goes on sys.path before the imports)

import os
import pathlib
import sys
import time
import warnings

import numpy as np

warnings.simplefilter("ignore")
sys.path.insert(0, ".")
from bench import urdf_sweep as us
from solver.ik import IKOptions, IKSolver, Target
from solver.model import EffectorMode
from solver.model.forward import link_poses
from solver.model.urdf import chain_from_urdf

name = sys.argv[1]
n = int(sys.argv[2])
TIPS = [x for x in os.environ.get("TIPS", "").split(",") if x]
f = [f for f in us.urdf_files(pathlib.Path("/tmp/pyb/pybullet_data")) if f[1].name == name][0]
text = us.read_text(f[1])
tree = us.tree_of(text)
base, tips = us.chains_of(tree)
chain = us.with_modes(chain_from_urdf(text, base_link=base, tip_links=TIPS or [t[0] for t in tips]))
full = {e.name: e.mode is EffectorMode.POSE for e in chain.effectors}
A = IKSolver(chain, IKOptions(time_budget_us=100000.0, inner_first=False))
B = IKSolver(chain, IKOptions(time_budget_us=100000.0, inner_first=True))
seed = chain.mid_limits()
rng = np.random.default_rng(int(os.environ.get("SEED", "11")))
res = {"off": [], "on": []}
for k in range(n + 2):
    frames = link_poses(chain, us.random_q(chain, rng))
    targets = [
        Target(
            effector=e.name,
            position=frames[e.link][:3, 3].copy(),
            rotation=frames[e.link][:3, :3].copy() if full[e.name] else None,
        )
        for e in chain.effectors
    ]
    for lab, s in (("off", A), ("on", B)) if k % 2 else (("on", B), ("off", A)):
        c0 = time.thread_time()
        r = s.solve(targets, seed=seed)
        cpu = (time.thread_time() - c0) * 1e6
        if k >= 2:
            res[lab].append(
                (r.success and min(cpu, r.solve_us) <= 5000, min(cpu, r.solve_us), r.iterations)
            )
for lab, X in res.items():
    X = np.array(X, float)
    print(
        f"{name} {lab}: within5ms {X[:, 0].mean():.4f}  us p50/p90/p99 {np.percentile(X[:, 1], [50, 90, 99]).round()}  iters p50/p99 {np.percentile(X[:, 2], [50, 99])}"
    )
