"""Running the parts: build the solvers for a chain, warm them, then time them
interleaved target by target, (a)/(b) solves and (c) tracking streams."""

from __future__ import annotations

import gc
import time

import numpy as np

from bench.ik_chains import BenchChain
from bench.peers import PeerSolver

from .adapters import Adapter, Ours, OursPlanned, Peer, ours_options, peer_key
from .config import RTB, Config, progress
from .judging import Row, judge
from .scipy_lbfgsb import ScipyLBFGSB
from .streams import chain_rng, fk_poses, max_step, reference_streams, targets_for, uniform_q


def make_solvers(
    cfg: Config,
    bc: BenchChain,
    peers: list[PeerSolver],
    position_only: bool,
    *,
    tracking: bool,
) -> list[tuple[str, Adapter, int]]:
    """(key, adapter, N) for each solver that runs on this chain; skipped ones are
    returned by the caller as rows with a reason."""
    budget_us = cfg.timeout_s * 1e6
    n_all = cfg.frames * cfg.streams if tracking else cfg.n
    n_slow = n_all if tracking else min(cfg.n, cfg.peer_n)

    def ours(metric_every: int, label: str, carry: bool = False) -> Ours:
        opts = ours_options(metric_every, stream=tracking, carry=carry, budget_us=budget_us)
        return Ours(bc, position_only, opts, label, track=tracking)

    # The order is the tables' order, and the interleaving permutes this list.
    out: list[tuple[str, Adapter, int]] = []
    if "ours" in cfg.solvers:
        label = "ours (IKSolver.track)" if tracking else "ours (IKSolver.solve)"
        out.append(("ours", ours(1, label), n_all))
    if "ours-plan" in cfg.solvers and tracking and not position_only:
        opts = ours_options(1, stream=True, budget_us=budget_us)
        label = "ours, planned (IKSolver.plan: the whole stream known)"
        out.append(("ours-plan", OursPlanned(bc, opts, label), n_all))
    if "ours" in cfg.solvers and tracking:
        out.append(("ours+carryH", ours(1, "ours, carry_hessian=True", carry=True), n_all))
    if "ours-bfgs" in cfg.solvers:
        out.append(("ours-bfgs", ours(0, "ours, metric_every=0 (article's BFGS)"), n_all))
        if tracking:
            label = "ours, metric_every=0, carry_hessian=True"
            out.append(("ours-bfgs+carryH", ours(0, label, carry=True), n_all))
    if "scipy" in cfg.solvers:
        out.append(
            (
                "scipy",
                ScipyLBFGSB(bc, position_only, ours_options(1, budget_us=budget_us), cfg.timeout_s),
                n_slow,
            )
        )
    for p in peers:
        key = peer_key(p)
        if key in cfg.solvers:
            a = Peer(bc, p, position_only, cfg.timeout_s)
            a.track = tracking
            out.append((key, a, n_all if key == RTB or tracking else n_slow))
    return out


def warm(
    cfg: Config, bc: BenchChain, solvers: list[tuple[str, Adapter, int]], position_only: bool
) -> None:
    """A few untimed solves per adapter (numba compiles on the first; peers build caches)."""
    rng = chain_rng(cfg, bc.name, "warm")
    qs = uniform_q(rng, bc, 3)
    poses = fk_poses(bc, qs)
    targets = targets_for(bc, poses, position_only)
    mid = bc.pose.mid_limits()
    for key, a, _ in solvers:
        t = time.perf_counter()
        a.load(poses if isinstance(a, Peer) else targets)
        a.reset(mid)
        for k in range(3):
            a.solve(k, mid)
        if time.perf_counter() - t > 2.0:
            progress(f"  warm-up {key} on {bc.name}: {time.perf_counter() - t:.1f} s (compilation)")


def run_solves(
    cfg: Config,
    bc: BenchChain,
    peers: list[PeerSolver],
    position_only: bool,
    skipped: dict[str, str],
    part: str,
) -> list[Row]:
    rng = chain_rng(cfg, bc.name, "targets")
    qs = uniform_q(rng, bc, cfg.n)  # the same targets for (a) and (b) and every solver
    poses = fk_poses(bc, qs)
    targets = targets_for(bc, poses, position_only)
    mid = bc.pose.mid_limits()
    solvers = make_solvers(cfg, bc, peers, position_only, tracking=False)
    warm(cfg, bc, solvers, position_only)
    for _, a, _ in solvers:
        a.load(poses if isinstance(a, Peer) else targets)
    rows = [Row(bc.name, key, a.name, a.settings, n, cap=n) for key, a, n in solvers]
    m = len(solvers)
    gc.collect()
    gc.freeze()  # peers' start-up objects (sympy, rtb) out of the collector's way
    t_part = time.perf_counter()
    next_report = time.perf_counter() + 30.0
    order_rng = chain_rng(cfg, bc.name, "order")
    for k in range(cfg.n):
        # a fresh random order per target: no solver always runs first, or always right
        # after the same (cache-flushing) neighbour
        for idx in order_rng.permutation(m):
            key, a, n = solvers[idx]
            if k >= n:
                continue
            t = time.perf_counter()
            q, core, flag = a.solve(k, mid)
            wall = time.perf_counter() - t
            row = rows[idx]
            v = judge(bc, q, poses[k], position_only, wall, cfg.timeout_s)
            row.record(wall, core, v, k)
            if key.startswith("ours") and flag is not None and flag != (v.ok or v.reason == "late"):
                row.flag_mismatch.append(k)
        if time.perf_counter() > next_report:
            next_report += 30.0
            progress(f"  {part} {bc.name}: {k + 1}/{cfg.n} targets")
    progress(f"  {part} {bc.name}: done in {time.perf_counter() - t_part:.1f} s")
    rows += skipped_rows(cfg, bc, peers, skipped)
    return rows


def skipped_rows(
    cfg: Config, bc: BenchChain, peers: list[PeerSolver], skipped: dict[str, str]
) -> list[Row]:
    have = {peer_key(p) for p in peers}
    return [
        Row(bc.name, key, key, "", skipped=skipped.get(key, "not available"))
        for key in ("rtb", "ikpy", "clik")
        if key in cfg.solvers and key not in have
    ]


def run_tracking(
    cfg: Config, bc: BenchChain, peers: list[PeerSolver], skipped: dict[str, str]
) -> list[Row]:
    order_rng = chain_rng(cfg, bc.name, "order")
    solvers = make_solvers(cfg, bc, peers, False, tracking=True)
    warm(cfg, bc, solvers, False)
    rows = [
        Row(bc.name, key, a.name, a.settings, 0, cap=cfg.frames * cfg.streams)
        for key, a, n in solvers
    ]
    m = len(solvers)
    gc.collect()
    gc.freeze()
    t_part = time.perf_counter()
    for s, stream in enumerate(reference_streams(cfg, bc)):
        path, poses, targets = stream.path, stream.poses, stream.targets
        ref = max_step(path)
        held = [path[0].copy() for _ in solvers]  # each solver's output pose stream
        outs = [np.empty_like(path) for _ in solvers]
        answered_all = [True] * m  # a held pose does not move: no step to judge
        for _, a, _ in solvers:
            a.load(poses if isinstance(a, Peer) else targets)
            a.reset(path[0])  # the stream starts at the path's true first pose
        for k in range(cfg.frames):
            for idx in order_rng.permutation(m):
                key, a, _ = solvers[idx]
                if isinstance(a, OursPlanned):
                    continue  # planned below, the whole stream at once
                t = time.perf_counter()
                q, core, flag = a.solve(k, held[idx])
                wall = time.perf_counter() - t
                row = rows[idx]
                v = judge(bc, q, poses[k], False, wall, cfg.timeout_s)
                row.record(wall, core, v, k)
                if (
                    key.startswith("ours")
                    and flag is not None
                    and flag != (v.ok or v.reason == "late")
                ):
                    row.flag_mismatch.append(s * cfg.frames + k)
                if q is not None:  # no answer: the output holds the last pose
                    held[idx] = q
                else:
                    answered_all[idx] = False
                outs[idx][k] = held[idx]
        for idx, (_, a, _) in enumerate(solvers):
            if not isinstance(a, OursPlanned):
                continue
            t = time.perf_counter()
            planned = a.plan()
            per_frame = (time.perf_counter() - t) / cfg.frames
            for k, r in enumerate(planned.results):
                v = judge(bc, r.q, poses[k], False, per_frame, cfg.timeout_s)
                rows[idx].record(per_frame, planned.plan_us / cfg.frames, v, k)
                if r.success != (v.ok or v.reason == "late"):
                    rows[idx].flag_mismatch.append(s * cfg.frames + k)
                outs[idx][k] = r.q
        for idx, row in enumerate(rows):
            row.n += cfg.frames
            st = max_step(outs[idx])
            row.max_step = max(row.max_step, st)
            row.ref_step = max(row.ref_step, ref)
            row.step_ratio = max(row.step_ratio, st / ref)
            row.streams += 1
            row.streams_within_2x += answered_all[idx] and st <= 2.0 * ref
        progress(f"  (c) {bc.name}: stream {s + 1}/{cfg.streams}, reference max step {ref:.4f} rad")
    progress(f"  (c) {bc.name}: done in {time.perf_counter() - t_part:.1f} s")
    rows += skipped_rows(cfg, bc, peers, skipped)
    return rows
