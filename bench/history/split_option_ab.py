"""Interleaved A/B of one IKOptions field on one sweep chain: the same targets, each
solved with both values in one process, alternating which goes first. The field is
a boolean (off and on) or ``name=a,b`` (two numbers).

    SEED=1 OPENBLAS_NUM_THREADS=1 python bench/history/split_option_ab.py freeze_trunk pr2.urdf 1000
    ... split_option_ab.py inner_first baxter.urdf 1000   (2026-11-28-limb-split.md)
    TIPS=left_hand,right_hand,middle_head ... split_option_ab.py freeze_trunk human.urdf 1000
    ... split_option_ab.py full_restart_every=8,4 human.urdf 1000
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
from solver.ik import IKOptions, IKSolver, pose_targets
from solver.model.urdf import chain_from_urdf

option, name, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
values: tuple[object, object] = (False, True)
if "=" in option:
    option, pair = option.split("=")
    a, b = (float(v) if "." in v else int(v) for v in pair.split(","))
    values = (a, b)
TIPS = [x for x in os.environ.get("TIPS", "").split(",") if x]
f = [f for f in us.urdf_files(pathlib.Path("/tmp/pyb/pybullet_data")) if f[1].name == name][0]
text = us.read_text(f[1])
tree = us.tree_of(text)
base, tips = us.chains_of(tree)
chain = us.with_modes(chain_from_urdf(text, base_link=base, tip_links=TIPS or [t[0] for t in tips]))
solvers = {
    v: IKSolver(chain, IKOptions(time_budget_us=100000.0, **{option: v}))  # type: ignore[arg-type]
    for v in values
}
seed = chain.mid_limits()
rng = np.random.default_rng(int(os.environ.get("SEED", "11")))
res: dict[object, list[tuple[bool, float, int, int]]] = {v: [] for v in values}
for k in range(n + 2):
    targets = pose_targets(chain, us.random_q(chain, rng))
    for on in values[::-1] if k % 2 else values:
        c0 = time.thread_time()
        r = solvers[on].solve(targets, seed=seed)
        cpu = (time.thread_time() - c0) * 1e6
        if k >= 2:  # the first two load the compiled code
            us_ = min(cpu, r.solve_us)
            res[on].append((r.success and us_ <= 5000, us_, r.iterations, r.restarts))
print(f"{name} ({chain.n_dof} variables, {len(chain.effectors)} effectors), {n} targets")
for on, rows in res.items():
    x = np.array(rows, float)
    p = np.percentile(x[:, 1], [50, 90, 99]).round()
    print(
        f"  {option}={on!s:5}: within 5 ms {x[:, 0].mean():.4f}  us p50/p90/p99 {p}"
        f"  iterations p50/p99 {np.percentile(x[:, 2], [50, 99])}  restarts max {x[:, 3].max():.0f}"
    )
