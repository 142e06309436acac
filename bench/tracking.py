"""Tracking benchmark: do streams nobody tuned for pop? (issue #22)

For each chain (panda, ur5, iiwa, Baxter's left arm, PR2's right arm, the humanoid arm,
the 40-DOF tail) and each mode (pose, position), ``--streams`` streams drawn at random
from a seeded generator (bench/tracking_streams.py: joint-space sinusoids, circles,
figure eights, reaches towards the workspace's edge), ``--frames`` frames at 60 Hz,
targets = our FK of a continuous reference joint path. Every solver starts each stream
at the reference's first pose and is warm-started frame by frame from its own previous
answer:

- ours under each continuity policy (``IKSolver.track``, session options
  ``STREAM_DEFAULTS``): ``default`` (what a session gets: ``smooth``, 0.1 rad per
  frame) and ``reach``, main's tracker (the A/B baseline of the per-frame time);
- roboticstoolbox's C++ ``ik_LM`` (bench/peers/rtb_peer.py), seeded with its previous
  answer, its random restarts inside the same time budget.

Per chain, mode and solver: frames within the tolerances (1e-5 m, 1e-4 rad), streams
whose largest joint step is at most twice the reference's, the worst step, the
per-frame wall time (median, p99; the call from Python, both sides). The streams of
the default policy that step more than twice the reference's are listed with what the
reference and the answer looked like before the step.

    python -m bench.tracking                 # 8 streams per chain (a few minutes)
    python -m bench.tracking --streams 100   # the full run

Needs the benchmark extras (example-robot-data, roboticstoolbox-python).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from bench.ik_chains import EXAMPLES, BenchChain, load
from bench.robots import ROBOTS, TRACKING_ARMS, robot
from bench.tracking_streams import (
    KINDS,
    PeerChain,
    PeerSpec,
    Stream,
    make_stream,
    min_singular_value,
)
from solver.ik import STREAM_DEFAULTS, Continuity, IKOptions, IKSolver, Target
from solver.model import EffectorMode
from solver.model.forward import effector_poses
from solver.model.urdf import chain_from_urdf

CHAINS: tuple[str, ...] = ("panda", "ur5", "iiwa", *TRACKING_ARMS, "humanoid_arm", "tail40")
TOLERANCES = {"position_tolerance_m": 1e-5, "rotation_tolerance_rad": 1e-4}
FPS = 60.0


def policies(
    budget_us: float | None = -1.0, polish_steps: int | None = None
) -> dict[str, IKOptions]:
    """The options each of our runs uses (session defaults at the benchmark's
    tolerances): the default (``smooth``, 0.1 rad per frame) and ``reach``, main's
    tracker (its global fallback then sampled an infinite radius, now a full turn).
    ``budget_us``: the per-frame time budget (None: none; negative: the session's);
    ``polish_steps``: ``IKOptions.polish_steps`` (None: the default; 0: no polish,
    the A/B's other side)."""
    base = replace(STREAM_DEFAULTS, **TOLERANCES)
    if polish_steps is not None:
        base = replace(base, polish_steps=polish_steps)
    if budget_us is None or budget_us >= 0.0:
        base = replace(base, time_budget_us=budget_us)
    assert base.continuity is Continuity.SMOOTH
    return {"default": base, "reach": replace(base, continuity=Continuity.REACH)}


def chain(name: str) -> BenchChain:
    if name in ROBOTS or name in EXAMPLES:
        return load(name)
    shipped = robot(name)
    spec = PeerSpec(name, shipped.urdf_path, shipped.base_link, shipped.tip_link)
    text = spec.urdf_text()
    pose, position = (
        chain_from_urdf(text, base_link=spec.base_link, tip_links=[spec.tip_link], mode=m)
        for m in (EffectorMode.POSE, EffectorMode.POSITION)
    )
    perm = np.array([pose.dof_names.index(j) for j in spec.joint_names])
    return BenchChain(name, pose, position, spec, spec.urdf_path.name, True, perm)


@dataclass
class Row:
    """One solver on one chain and mode, over all streams."""

    frames: int = 0
    solved: int = 0
    streams: int = 0
    within_2x: int = 0
    worst_step: float = 0.0
    worst_ratio: float = 0.0
    times_us: list[float] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)  # ours only: load-independent cost
    over_limit: int = 0  # frames whose step is over max_joint_step_rad


@dataclass(frozen=True)
class Outlier:
    chain: str
    mode: str
    solver: str
    stream: int
    kind: str
    step: float
    reference_step: float
    frame: int
    cause: str


def run_ours(
    bc: BenchChain,
    position: bool,
    opts: IKOptions,
    stream: Stream,
    targets: list[list[Target]],
    iterations: list[int],
) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Answers, success flags and per-frame wall times of ``track`` over a stream (each
    frame's optimizer iterations appended to ``iterations``)."""
    solver = IKSolver(bc.position if position else bc.pose, opts)
    solver.set_pose(bc.to_ours(stream.path[0]))
    qs = np.empty((len(targets), bc.pose.n_dof))
    ok = np.zeros(len(targets), dtype=bool)
    times = []
    clock = time.perf_counter
    for k, t in enumerate(targets):
        t0 = clock()
        r = solver.track(t)
        times.append((clock() - t0) * 1e6)
        qs[k] = r.q
        ok[k] = r.success
        iterations.append(r.iterations)
    return qs, ok, times


def run_peer(
    peer: object,
    bc: BenchChain,
    position: bool,
    stream: Stream,
    poses: np.ndarray,
    base: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """ik_LM over a stream, seeded with its previous answer (``base``: our base frame
    in rtb's, see ``PeerChain``)."""
    from bench.peers.rtb_peer import RtbIK

    assert isinstance(peer, RtbIK)
    to_peer = np.linalg.inv(base)
    q = stream.path[0].copy()
    qs = np.empty((len(poses), q.shape[0]))
    ok = np.zeros(len(poses), dtype=bool)
    times = []
    budget = STREAM_DEFAULTS.time_budget_us or 5000.0
    for k, pose in enumerate(poses):
        t0 = time.perf_counter()
        sol = peer.solve(to_peer @ pose, q, position_only=position, timeout_s=budget * 1e-6)
        times.append((time.perf_counter() - t0) * 1e6)
        if sol is not None:
            q = sol
        qs[k] = bc.to_ours(q)
        ok[k] = sol is not None
    return qs, ok, times


def within_tolerance(
    bc: BenchChain, position: bool, qs: np.ndarray, poses: np.ndarray
) -> np.ndarray:
    """Per frame, whether its answer (our FK) is within the tolerances: the same judge
    for all."""
    flags = np.zeros(len(qs), dtype=bool)
    for k, (q, target) in enumerate(zip(qs, poses, strict=True)):
        x = effector_poses(bc.pose, q)[0]
        ok = np.linalg.norm(x[:3, 3] - target[:3, 3]) <= TOLERANCES["position_tolerance_m"]
        if ok and not position:
            r = target[:3, :3].T @ x[:3, :3]
            angle = math.acos(max(-1.0, min(1.0, 0.5 * (np.trace(r) - 1.0))))
            ok = angle <= TOLERANCES["rotation_tolerance_rad"]
        flags[k] = bool(ok)
    return flags


def cause(
    bc: BenchChain, peer_chain: PeerChain, stream: Stream, qs: np.ndarray, k: int, position: bool
) -> str:
    """What the reference and the answer looked like before the largest step."""
    lo = np.where(np.isfinite(bc.pose.lower), bc.pose.lower, -math.pi)
    hi = np.where(np.isfinite(bc.pose.upper), bc.pose.upper, math.pi)
    before = qs[max(k - 1, 0)]
    room = float(np.min(np.minimum(before - lo, hi - before) / (hi - lo)))
    sigma = min_singular_value(peer_chain, stream.path, 3 if position else 6)
    drift = float(np.abs(before - bc.to_ours(stream.path[max(k - 1, 0)])).max())
    label = "limit" if room < 0.03 else "singular path" if sigma < 0.02 else "branch"
    return (
        f"{label}: answer {room:.3f} of a range from a limit, {drift:.2f} rad from the "
        f"reference before the step; reference's smallest singular value {sigma:.3f}"
    )


def largest_steps(start: np.ndarray, qs: np.ndarray) -> np.ndarray:
    return np.abs(np.diff(np.vstack([start, qs]), axis=0)).max(axis=1)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--streams", type=int, default=8, help="streams per chain (full: 100)")
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--seed", type=int, default=0, help="first seed of the generator")
    ap.add_argument("--chains", nargs="*", default=list(CHAINS))
    ap.add_argument("--modes", nargs="*", default=["pose", "position"])
    ap.add_argument("--no-peer", action="store_true", help="skip ik_LM")
    ap.add_argument(
        "--budget-us",
        type=float,
        default=-1.0,
        help="our per-frame time budget (0: none, so that frames within tolerance do not "
        "depend on the machine's load; default: the session's, 5000)",
    )
    ap.add_argument("--misses", action="store_true", help="list our frames outside the tolerances")
    ap.add_argument(
        "--polish-steps",
        type=int,
        default=None,
        help="IKOptions.polish_steps for ours (default: the options' default; 0: no polish)",
    )
    args = ap.parse_args(argv)

    from bench.peers.rtb_peer import RtbIK

    runs = policies(None if args.budget_us == 0.0 else args.budget_us, args.polish_steps)
    solvers = [*runs, "ik_LM"] if not args.no_peer else list(runs)
    rows: dict[tuple[str, str, str], Row] = {}
    outliers: list[Outlier] = []
    started = time.perf_counter()
    for name in args.chains:
        bc = chain(name)
        assert bc.spec is not None
        peer_chain = PeerChain(bc.spec, lambda q, bc=bc: effector_poses(bc.pose, bc.to_ours(q))[0])
        peer = None if args.no_peer else RtbIK(bc.spec)
        streams = [
            make_stream(peer_chain, args.seed, CHAINS.index(name), i, args.frames, FPS)
            for i in range(args.streams)
        ]
        for mode in args.modes:
            position = mode == "position"
            for si, stream in enumerate(streams):
                ours_path = np.array([bc.to_ours(q) for q in stream.path])
                poses = np.array([effector_poses(bc.pose, q)[0] for q in ours_path])
                e = bc.effector
                targets = [
                    [
                        Target(effector=e, position=p[:3, 3].copy())
                        if position
                        else Target(effector=e, position=p[:3, 3].copy(), rotation=p[:3, :3].copy())
                    ]
                    for p in poses
                ]
                ref = stream.largest_step
                for label in solvers:
                    if label == "ik_LM":
                        qs, ok, times = run_peer(peer, bc, position, stream, poses, peer_chain.base)
                        limit = math.inf
                    else:
                        row = rows.setdefault((name, mode, label), Row())
                        qs, ok, times = run_ours(
                            bc, position, runs[label], stream, targets, row.iterations
                        )
                        limit = runs[label].max_joint_step_rad
                    steps = largest_steps(ours_path[0], qs)
                    row = rows.setdefault((name, mode, label), Row())
                    row.frames += len(qs)
                    within = within_tolerance(bc, position, qs, poses)
                    row.solved += int(within.sum())
                    if args.misses and label != "ik_LM":
                        for k in np.flatnonzero(~within):
                            print(
                                f"# miss: {name} {mode} {label} stream {si} ({stream.kind}) "
                                f"frame {k}",
                                file=sys.stderr,
                            )
                    row.streams += 1
                    worst = float(steps.max())
                    row.within_2x += worst <= 2.0 * ref
                    row.worst_step = max(row.worst_step, worst)
                    row.worst_ratio = max(row.worst_ratio, worst / ref)
                    row.times_us += times
                    if label != "ik_LM" and runs[label].continuity is Continuity.SMOOTH:
                        row.over_limit += int(np.sum(steps > limit + 1e-9))
                    if label == "default" and worst > 2.0 * ref:
                        k = int(np.argmax(steps))
                        why = cause(bc, peer_chain, stream, qs, k, position)
                        outliers.append(
                            Outlier(name, mode, label, si, stream.kind, worst, ref, k, why)
                        )
        print(f"# {name} done ({time.perf_counter() - started:.0f} s)", file=sys.stderr)
    report(args, rows, outliers, solvers)
    return 0


def report(
    args: argparse.Namespace,
    rows: dict[tuple[str, str, str], Row],
    outliers: list[Outlier],
    solvers: list[str],
) -> None:
    last = args.seed
    print(
        f"streams per chain: {args.streams} ({', '.join(KINDS)} in turn), {args.frames} frames "
        f"at {FPS:g} Hz; generator seeds [{last}, chain, 0..{args.streams - 1}]; tolerances "
        f"{TOLERANCES['position_tolerance_m']:g} m / {TOLERANCES['rotation_tolerance_rad']:g} rad"
    )
    opts = policies(None if args.budget_us == 0.0 else args.budget_us, args.polish_steps)
    budget = opts["default"].time_budget_us
    print(
        f"default policy: {opts['default'].continuity.value}, max_joint_step_rad "
        f"{opts['default'].max_joint_step_rad:g}; our time budget per frame: "
        f"{'none' if budget is None else f'{budget:g} us'}; polish steps "
        f"{opts['default'].polish_steps}"
    )
    print()
    print(
        "| chain | mode | solver | frames within tol | streams <= 2x ref step | worst step "
        "(x ref) | median us | p99 us | iterations median / p99 / max |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    for (name, mode, label), r in rows.items():
        t = np.array(r.times_us)
        extra = f", {r.over_limit} frames over the limit" if r.over_limit else ""
        its = np.array(r.iterations)
        iters = (
            f"{np.median(its):.0f} / {np.percentile(its, 99):.0f} / {its.max()}"
            if its.size
            else "-"
        )
        print(
            f"| {name} | {mode} | {label} | {100.0 * r.solved / r.frames:.2f}% | "
            f"{r.within_2x}/{r.streams} ({100.0 * r.within_2x / r.streams:.0f}%){extra} | "
            f"{r.worst_step:.3f} ({r.worst_ratio:.1f}x) | {np.median(t):.1f} | "
            f"{np.percentile(t, 99):.0f} | {iters} |"
        )
    print()
    print("Bars:")
    for name in args.chains:
        for mode in args.modes:
            got = {s: rows.get((name, mode, s)) for s in solvers}
            reach, default = got.get("reach"), got.get("default")
            if not (reach and default):
                continue
            t_default = float(np.median(default.times_us))
            t_reach = float(np.median(reach.times_us))
            print(
                f"  {name} {mode}: reach frames {100.0 * reach.solved / reach.frames:.2f}% "
                f"(bar 100%); default streams within 2x "
                f"{100.0 * default.within_2x / default.streams:.0f}% (bar 99%); default (smooth) "
                f"frames over its limit {default.over_limit} (bar 0); median default/reach "
                f"{t_default / t_reach:.2f} (bar 1.2)"
            )
    if outliers:
        print()
        print("Default-policy streams over 2x the reference's largest step:")
        for o in outliers:
            print(
                f"  {o.chain} {o.mode} stream {o.stream} ({o.kind}): {o.step:.3f} rad at frame "
                f"{o.frame}, reference {o.reference_step:.3f}; {o.cause}"
            )


if __name__ == "__main__":
    raise SystemExit(main())
