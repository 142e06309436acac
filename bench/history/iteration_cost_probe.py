"""Where an iteration's time goes on the URDF sweep's worst multi-tip chains (issue 26).

Run from the repo root: python bench/history/iteration_cost_probe.py /tmp/pyb/pybullet_data
Solves targets as bench.urdf_sweep does (no budget), then times each piece of an
iteration alone in a compiled loop on a converging point.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

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
from solver.ik.kinematics import ik_objective
from solver.ik.metric import metric_inverse
from solver.model.forward import forward_kinematics, link_poses
from solver.model.urdf import chain_from_urdf
from solver.optim.bfgs import bfgs_update, descent_direction


@njit
def t_obj(q, g, data, reps):  # type: ignore[no-untyped-def]
    f = 0.0
    for _ in range(reps):
        q[0] += 1e-12
        f += ik_objective(q, g, True, data)
    return f


@njit
def t_f(q, g, data, reps):  # type: ignore[no-untyped-def]
    f = 0.0
    for _ in range(reps):
        q[0] += 1e-12
        f += ik_objective(q, g, False, data)
    return f


@njit
def t_fk(q, data, reps):  # type: ignore[no-untyped-def]
    for _ in range(reps):
        q[0] += 1e-12
        forward_kinematics(q, data[0], data[1])


@njit
def t_metric(q, g, lo, hi, data, h, reps):  # type: ignore[no-untyped-def]
    ok = True
    for _ in range(reps):
        q[0] += 1e-12
        ok = metric_inverse(q, g, lo, hi, data, h)
    return ok


@njit
def t_bfgs(h, s, y, hy, g, x, lo, hi, d, gm, reps):  # type: ignore[no-untyped-def]
    for _ in range(reps):
        bfgs_update(h, s, y, hy, 1e-10)
        descent_direction(h, g, x, lo, hi, d, gm)


def per_call(fn, *args, reps=2000):  # type: ignore[no-untyped-def]
    fn(*args, 2)
    best = []
    for _ in range(7):
        t0 = time.perf_counter()
        fn(*args, reps)
        best.append((time.perf_counter() - t0) / reps * 1e6)
    return float(np.median(best))


def main() -> None:
    pyb = Path(sys.argv[1]) if len(sys.argv) > 1 else None
    want = {"g1": None, "tiago.urdf": None}
    for _, path in urdf_files(pyb):
        text = read_text(path)
        tree = tree_of(text)
        if tree is None:
            continue
        if "g1" in path.name and want["g1"] is None and "29" in path.name:
            base, tips = chains_of(tree)
            want["g1"] = (
                path.name,
                chain_from_urdf(text, base_link=base, tip_links=[t[0] for t in tips]),
            )
        if path.name == "tiago.urdf" and want["tiago.urdf"] is None:
            base, _ = chains_of(tree)
            want["tiago.urdf"] = (
                path.name,
                chain_from_urdf(text, base_link=base, tip_links=NAMED_MULTI["tiago.urdf"][0]),
            )
    for key, got in want.items():
        if got is None:
            print(key, "not found")
            continue
        name, chain = got
        chain = with_modes(chain)
        rows = sum(6 if e.mode.value == "pose" else 3 for e in chain.effectors)
        print(
            f"== {name}: {chain.n_dof} variables, {len(chain.effectors)} effectors, {rows} rows, {len(chain.joints)} joints"
        )
        solver = IKSolver(chain, IKOptions(time_budget_us=None))
        rng = np.random.default_rng(1)
        its, fev, us = [], [], []
        last = None
        for _ in range(60):
            frames = link_poses(chain, random_q(chain, rng))
            full = {e.name: e.mode.value == "pose" for e in chain.effectors}
            targets = [
                Target(
                    effector=e.name,
                    position=frames[e.link][:3, 3].copy(),
                    rotation=frames[e.link][:3, :3].copy() if full[e.name] else None,
                )
                for e in chain.effectors
            ]
            r = solver.solve(targets, seed=chain.mid_limits())
            its.append(r.iterations)
            fev.append(r.function_evals)
            us.append(r.solve_us)
            last = targets
        its_a, fev_a, us_a = map(np.array, (its, fev, us))
        print(
            f"  solves: median iterations {np.median(its_a):.0f}, evaluations/iteration {fev_a.sum() / its_a.sum():.2f}, "
            f"us/iteration median {np.median(us_a / np.maximum(its_a, 1)):.1f}, us/evaluation {np.median(us_a / fev_a):.1f}"
        )
        data = solver.load_frame(last, chain.mid_limits())
        q = random_q(chain, rng)
        n = chain.n_dof
        g = np.zeros(n)
        lo = chain.lower.copy()
        hi = chain.upper.copy()
        lo[~np.isfinite(lo)] = -1e9
        hi[~np.isfinite(hi)] = 1e9
        ik_objective(q, g, True, data)
        h = np.eye(n)
        fg = per_call(t_obj, q, g, data)
        f = per_call(t_f, q, g, data)
        fk = per_call(t_fk, q, data)
        m = per_call(t_metric, q, g, lo, hi, data, h, reps=500)
        s = rng.normal(size=n) * 1e-3
        y = s + rng.normal(size=n) * 1e-4
        hb = np.eye(n)
        b = per_call(t_bfgs, hb, s, y, np.zeros(n), g, q, lo, hi, np.zeros(n), np.zeros(n))
        print(
            f"  FK alone {fk:.2f} us; f {f:.2f} us; f+g {fg:.2f} us (g adds {fg - f:.2f}); "
            f"metric (J^T W J + {n}x{n} inverse) {m:.2f} us; BFGS update + direction {b:.2f} us"
        )


if __name__ == "__main__":
    main()
