"""One sweep chain solved in this checkout, for an A/B of two checkouts run one after
the other (bench/history/2026-11-29-metric-factor.md): the same seeded targets from the
mid-limits seed, default options with a 100 ms budget.

    cd CHECKOUT && ROOT=$PWD TIPS=hand_index_flex_3_link,hand_middle_flex_3_link,hand_thumb_flex_2_link \\
        OPENBLAS_NUM_THREADS=1 python /work/main/bench/history/checkout_ab.py tiago.urdf 1000

prints the share within 5 ms of CPU, us p50/p90/p99, iterations and us per iteration;
``WHOLE=1`` solves the whole group at once with no restart (``split_limbs=False``) and
prints the compiled us per iteration (``r.solve_us / r.iterations``).
"""

# ruff: noqa: E402  (the checkout's root goes on sys.path before the imports)

import os
import pathlib
import sys
import time
import warnings

import numpy as np

warnings.simplefilter("ignore")
sys.path.insert(0, os.environ.get("ROOT", "."))
from bench import urdf_sweep as us
from solver.ik import IKOptions, IKSolver, pose_targets
from solver.model.urdf import chain_from_urdf

name, n = sys.argv[1], int(sys.argv[2])
TIPS = [x for x in os.environ.get("TIPS", "").split(",") if x]
whole = os.environ.get("WHOLE") == "1"
f = [f for f in us.urdf_files(pathlib.Path("/tmp/pyb/pybullet_data")) if f[1].name == name][0]
text = us.read_text(f[1])
base, tips = us.chains_of(us.tree_of(text))
chain = us.with_modes(chain_from_urdf(text, base_link=base, tip_links=TIPS or [t[0] for t in tips]))
options = IKOptions(time_budget_us=100000.0)
if whole:
    options = IKOptions(time_budget_us=100000.0, split_limbs=False, max_restarts=0)
solver = IKSolver(chain, options)
seed = chain.mid_limits()
rng = np.random.default_rng(int(os.environ.get("SEED", "11")))
rows = []
for k in range(n + 2):
    targets = pose_targets(chain, us.random_q(chain, rng))
    c0 = time.thread_time()
    r = solver.solve(targets, seed=seed, rng=np.random.default_rng(k))
    cpu = (time.thread_time() - c0) * 1e6
    if k >= 2:  # the first two load the compiled code
        u = r.solve_us if whole else min(cpu, r.solve_us)
        rows.append((r.success and u <= 5000, u, r.iterations, r.function_evals))
x = np.array(rows, float)
its = x[:, 2].sum()
if whole:
    print(
        f"{name}: compiled us per iteration {x[:, 1].sum() / its:.2f}, "
        f"evaluations per iteration {x[:, 3].sum() / its:.2f}, iterations {its:.0f}"
    )
else:
    print(
        f"{name}: within 5 ms {x[:, 0].mean():.4f} us p50/p90/p99 "
        f"{np.percentile(x[:, 1], [50, 90, 99]).round()} iterations p50/p99 "
        f"{np.percentile(x[:, 2], [50, 99])} us per iteration {x[:, 1].sum() / its:.2f}"
    )
