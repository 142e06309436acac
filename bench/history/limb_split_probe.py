"""Probe of 2026-11-28-limb-split.md: a sweep chain's targets solved whole, and group
by group on chains of their own (argv[3] = 1: each group's inner effectors first).

    OPENBLAS_NUM_THREADS=1 python bench/history/limb_split_probe.py g1_29dof_rev_1_0.urdf 200 1

(from the repository root, with pybullet_data at /tmp/pyb as bench/urdf_sweep.py says;
written before split.py, it builds the groups' chains with chain_from_urdf itself).
"""

# ruff: noqa: E402  (the repository root goes on sys.path before the imports)

import pathlib
import sys
import warnings

import numpy as np

warnings.simplefilter("ignore")
sys.path.insert(0, ".")
from bench import urdf_sweep as us
from solver.ik import IKOptions, IKSolver, Target
from solver.model import EffectorMode
from solver.model.forward import link_poses
from solver.model.urdf import chain_from_urdf

TRUNK = int(sys.argv[3])
name = sys.argv[1]
n = int(sys.argv[2])
files = [f for f in us.urdf_files(pathlib.Path("/tmp/pyb/pybullet_data")) if f[1].name == name]
text = us.read_text(files[0][1])
tree = us.tree_of(text)
base, tips = us.chains_of(tree)
chain = us.with_modes(chain_from_urdf(text, base_link=base, tip_links=[t[0] for t in tips]))
by_child = {j.child: j for j in chain.joints}


def pathvars(link):
    s = set()
    while link in by_child:
        j = by_child[link]
        s |= set(j.dof_names)
        link = j.parent
    return s


# components by shared variables
comps = []
for e in chain.effectors:
    vs = pathvars(e.link)
    group = [[e], vs]
    for c in list(comps):
        if c[1] & vs:
            group[0] += c[0]
            group[1] |= c[1]
            comps.remove(c)
    comps.append(group)
print("components", [([e.name for e in c[0]], len(c[1])) for c in comps])
subs = []
for effs, _vs in comps:
    sc = us.with_modes(chain_from_urdf(text, base_link=base, tip_links=[e.link for e in effs]))
    subs.append((sc, IKSolver(sc, IKOptions(time_budget_us=200000.0))))
solver = IKSolver(chain, IKOptions(time_budget_us=200000.0))
full = {e.name: e.mode is EffectorMode.POSE for e in chain.effectors}
seed = chain.mid_limits()
rng = np.random.default_rng(7)
A = []
B = []
C = []
for _k in range(n):
    frames = link_poses(chain, us.random_q(chain, rng))
    targets = {
        e.link: Target(
            effector=e.name,
            position=frames[e.link][:3, 3].copy(),
            rotation=frames[e.link][:3, :3].copy() if full[e.name] else None,
        )
        for e in chain.effectors
    }
    r = solver.solve(list(targets.values()), seed=seed)
    A.append((r.iterations, r.restarts, r.solve_us, r.success))
    it = rs = t = 0
    ok = True
    per = []
    for sc, s in subs:
        tt = [
            Target(
                effector=e.name,
                position=targets[e.link].position,
                rotation=targets[e.link].rotation,
            )
            for e in sc.effectors
        ]
        paths = {e.name: frozenset(pathvars(e.link)) for e in sc.effectors}
        inner = {e for e in paths if any(paths[e] < paths[f] for f in paths)}
        r0us = 0.0
        sd = sc.mid_limits()
        if inner and TRUNK:
            r0 = s.solve([x for x in tt if x.effector in inner], seed=sd)
            sd = r0.q
            r0us = r0.solve_us
        rr = s.solve(tt, seed=sd)
        rr = rr._replace(solve_us=rr.solve_us + r0us)
        per.append((rr.solve_us, rr.restarts, rr.iterations))
        it += rr.iterations
        rs = max(rs, rr.restarts)
        t += rr.solve_us
        ok &= rr.success
    B.append((it, rs, t, ok))
    C.append(per)
for lab, X in (("whole", A), ("split", B)):
    X = np.array(X, dtype=float)
    print(
        lab,
        "success",
        X[:, 3].mean(),
        "iters p50/p90/p99",
        np.percentile(X[:, 0], [50, 90, 99]),
        "restarts p50/p90/p99",
        np.percentile(X[:, 1], [50, 90, 99]),
        "us p50/p90/p99",
        np.percentile(X[:, 2], [50, 90, 99]).round(),
        "within 5ms",
        (X[:, 2] <= 5000).mean(),
    )

C = np.array(C)
for i in range(C.shape[1]):
    print(
        "component",
        i,
        "us p50/p90/p99",
        np.percentile(C[:, i, 0], [50, 90, 99]).round(),
        "restarts p50/p90/p99/max",
        np.percentile(C[:, i, 1], [50, 90, 99]),
        C[:, i, 1].max(),
        "iters p50/p99",
        np.percentile(C[:, i, 2], [50, 99]),
    )
