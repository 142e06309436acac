"""Steering a 7-DOF arm's self-motion ahead of a singularity: what moves the iiwa step bar.

Issue #3 (c) asks that the largest joint step of a tracked stream be at most twice the
reference path's. One iiwa stream misses it (``bench/RESULTS.md``, "iiwa tracking"): the
reference crosses the shoulder pole (joint 2 through 0) and later the wrist's (joint 6
through 0), while our warm-started answer, on another point of the arm's one-dimensional
self-motion, passes *near* the pole, where joints 1 and 3 (or 5 and 7) must turn by about
pi in a few frames. This probe runs the benchmark's own streams (same generator, seed and
options as ``bench/ik.py`` part (c); one solver per strategy, warmed and reused across the
streams as the benchmark does, so ``none`` reproduces its figures) with a steering strategy
applied before each frame, and prints, per stream, the largest step over the reference's,
the frames above 2x, the first of them and the frames out of tolerance. It measures what
each strategy can do, not what it costs: the strategies are Python with finite-difference
Jacobians. ``--streams 40`` looks beyond the benchmark's three streams (the same generator
continues), and ``--tolerance-scale`` multiplies the tolerances of every strategy's
solver, the oracle's look-ahead included (the missed column then counts against the
scaled tolerances). The largest step of a failing stream is mostly where the global fallback's
random restart lands; compare the frames above 2x and the first of them.

Strategies (``--strategy``, several allowed); all but ``none`` run with the rest-pose
pull set to ``--rest-pull`` (default 0: the steering alone):
  none      STREAM_DEFAULTS as the benchmark runs them.
  nopull    no steering (the baseline of the strategies below).
  attract   when an alignment joint (``--align``, 0-based; default: the two joints whose
            zero aligns the axes of their neighbours) is within ``--theta`` of 0, step
            along the self-motion towards the point where that joint is smallest (Newton
            on q_j^2), at most ``--cap`` rad per joint per frame: a stream that sits at
            that point when the pole passes crosses it as the reference does.
  velocity  step along the self-motion down the gradient of |J^+ xdot| (the joint speed
            the coming frame's target motion needs).
  repel     while an alignment joint is within ``--theta`` of 0, step along the
            self-motion away from 0 (down the gradient of -log q_j^2) at ``--cap``.
  hold      while an alignment joint j is within ``--theta`` of 0, solve the frame and
            walk along the self-motion until joint j-1 is back where it was: a
            straight line through the pole in the upper arm's direction.
  flip      solve the frame; if a joint stepped more than 0.05 rad, also solve it from
            the answer with each combination of the chain's flip groups applied (three
            joints i, i+1, i+2 where turning i and i+2 by pi and negating i+1 keeps the
            pose, found numerically) and keep the smallest step.
  oracle    every ``--every`` frames, run a local tracker (3 restarts, no global fallback,
            no rest pull) over the next ``--horizon`` frames of the TRUE future targets
            from the current pose and from points +-D (``--spans``) along the
            self-motion; score each by the sum of squared step excesses over 0.02 rad
            plus 0.01 per frame out of tolerance, and steer towards the best at ``--cap``
            per frame. A tracker never has the future; this asks what look-ahead
            steering could buy.

    OPENBLAS_NUM_THREADS=1 python -m bench.steer_probe --chain iiwa \
        --strategy none,attract,velocity,oracle
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402

import numpy as np  # noqa: E402

from solver.chain import Chain  # noqa: E402
from solver.fk import effector_poses  # noqa: E402
from solver.ik import IKOptions, IKSolver, Target  # noqa: E402

from .ik import (  # noqa: E402
    Config,
    Ours,
    max_step,
    ours_options,
    reference_streams,
    warm,
)
from .ik_chains import CHAINS, load  # noqa: E402
from .stream_probe import jacobian  # noqa: E402

STRATEGIES = ("none", "nopull", "flip", "attract", "repel", "hold", "velocity", "oracle")
# Joints (0-based) whose zero makes the axes of their two neighbours collinear.
ALIGNMENT_JOINTS = {"iiwa": (1, 5), "panda": (1, 5)}
EXCESS_RAD = 0.02  # oracle: steps above this count against a candidate


@dataclass
class Stream:
    """One stream's state as a strategy sees it before frame k is solved."""

    targets: list[list[Target]]
    direction: np.ndarray | None = None  # the self-motion direction, oriented as last frame
    steer: float = 0.0  # oracle: the side chosen at its last look-ahead (-1, 0, +1)
    sim: IKSolver | None = None  # oracle: this stream's look-ahead solver


Strategy = Callable[[IKSolver, int, Stream], None]


def self_motion(chain: Chain, q: np.ndarray, like: np.ndarray | None) -> np.ndarray:
    """Unit direction of the self-motion at q (a 7-DOF arm's one null direction of its
    6-D Jacobian), signed to agree with ``like`` (SVD picks the sign at random)."""
    n: np.ndarray = np.linalg.svd(jacobian(chain, q))[2][-1]
    return -n if like is not None and float(n @ like) < 0.0 else n


def _move(solver: IKSolver, step: np.ndarray, cap: float) -> None:
    """Move the stream's pose by ``step`` scaled to at most ``cap`` per joint; the
    frame's solve then takes it back onto the target (second-order error only)."""
    big = float(np.abs(step).max())
    if big > cap:
        step = step * (cap / big)
    solver.q = np.clip(solver.q + step, solver.chain.lower, solver.chain.upper)


def attract(joints: Sequence[int], theta: float, cap: float, eps: float = 1e-4) -> Strategy:
    def before(solver: IKSolver, k: int, s: Stream) -> None:
        q = solver.q
        near = [j for j in joints if abs(q[j]) < theta]
        if not near:
            return
        j = min(near, key=lambda i: abs(q[i]))
        n = self_motion(solver.chain, q, s.direction)
        s.direction = n
        dn = (self_motion(solver.chain, q + eps * n, n)[j] - n[j]) / eps
        slope = 2.0 * q[j] * n[j]  # d(q_j^2)/da along n
        curvature = 2.0 * (n[j] ** 2 + q[j] * dn)
        a = -slope / curvature if curvature > 0.0 else -math.copysign(1e9, slope)
        _move(solver, a * n, cap)

    return before


def flip_groups(chain: Chain, trials: int = 4, tol: float = 1e-2) -> list[tuple[int, int, int]]:
    """Triples (i, i+1, i+2) of joints for which turning i and i+2 by pi and negating
    i+1 leaves every effector's pose unchanged (a spherical group: shoulder or wrist),
    found numerically on random joint vectors; ``tol`` (m, and rad of the rotation
    matrix's entries) admits nearly spherical groups, whose flipped pose the frame's
    solver then refines. Groups whose outer joints cannot turn by pi within their
    limits are left out (they could never flip)."""
    rng = np.random.default_rng(0)
    n = chain.n_dof
    span = chain.upper - chain.lower
    out = []
    for i in range(n - 2):
        if span[i] < math.pi or span[i + 2] < math.pi:
            continue
        ok = True
        for _ in range(trials):
            q = rng.uniform(-math.pi, math.pi, n)
            f = q.copy()
            f[i] += math.pi
            f[i + 1] = -f[i + 1]
            f[i + 2] += math.pi
            a, b = effector_poses(chain, q), effector_poses(chain, f)
            if any(float(np.abs(x - y).max()) > tol for x, y in zip(a, b, strict=True)):
                ok = False
                break
        if ok:
            out.append((i, i + 1, i + 2))
    return out


def _nearest_turn(value: float, prev: float, lo: float, hi: float) -> float | None:
    """value + 2 pi m for the integer m that brings it nearest to prev within [lo, hi]."""
    best = None
    for m in (-2, -1, 0, 1, 2):
        v = value + 2.0 * math.pi * m
        if lo <= v <= hi and (best is None or abs(v - prev) < abs(best - prev)):
            best = v
    return best


def flip(chain: Chain, trigger: float = 0.05) -> Strategy:
    """Solve the frame; if a joint stepped more than ``trigger``, also solve it from
    the answer turned by each combination of the chain's flip groups and take the
    answer whose largest joint step from the last frame is smallest."""
    groups = flip_groups(chain)
    lo, hi = chain.lower, chain.upper

    def before(solver: IKSolver, k: int, s: Stream) -> None:
        if k < 1 or not groups:
            return
        prev = solver.q.copy()
        q = solver.track(s.targets[k]).q.copy()
        best, best_step = q, float(np.abs(q - prev).max())
        if best_step <= trigger:
            solver.q = q
            return
        for mask in range(1, 1 << len(groups)):
            # Sum the turns and signs per joint first: overlapping groups (the iiwa's
            # shoulder and elbow share joint 3) turn a shared joint twice.
            turns = np.zeros_like(q)
            signs = np.ones_like(q)
            for g, (i, j, m) in enumerate(groups):
                if mask >> g & 1:
                    turns[i] += math.pi
                    turns[m] += math.pi
                    signs[j] = -signs[j]
            c = signs * q
            ok = bool(np.all((lo <= c) | (turns != 0)) and np.all((c <= hi) | (turns != 0)))
            for t in np.flatnonzero(turns):
                v = _nearest_turn(c[t] + turns[t], prev[t], lo[t], hi[t])
                if v is None:
                    ok = False
                    break
                c[t] = v
            if not ok or float(np.abs(c - prev).max()) >= best_step:
                continue
            solver.q = c
            r = solver.track(s.targets[k])
            if r.success and (step := float(np.abs(r.q - prev).max())) < best_step:
                best, best_step = r.q.copy(), step
        solver.q = best

    return before


def repel(joints: Sequence[int], theta: float, cap: float) -> Strategy:
    """While an alignment joint is within ``theta`` of 0, step along the self-motion in
    the direction that moves it away from 0, at ``cap`` rad per frame."""

    def before(solver: IKSolver, k: int, s: Stream) -> None:
        q = solver.q
        near = [j for j in joints if abs(q[j]) < theta]
        if not near:
            return
        n = self_motion(solver.chain, q, s.direction)
        s.direction = n
        # the gradient of sum_j -log(q_j^2) along n, so the nearer pole dominates
        slope = sum(-2.0 * n[j] / q[j] if q[j] != 0.0 else 0.0 for j in near)
        _move(solver, -math.copysign(1.0, slope) * n * 1e3, cap)

    return before


def hold(joints: Sequence[int], theta: float, iterations: int = 8) -> Strategy:
    """Near an alignment pole (|q_j| < theta), solve the frame, then walk along the
    self-motion until joint j-1 is back where it was: the arm crosses the pole with that
    joint still, as a 6-DOF arm would, instead of sweeping it round the pole."""

    def before(solver: IKSolver, k: int, s: Stream) -> None:
        if k < 1:
            return
        prev = solver.q.copy()
        # The joint before the pole's (the one after, for a pole at joint 0).
        held = [j - 1 if j else j + 1 for j in joints if abs(prev[j]) < theta]
        if not held:
            return
        q = solver.track(s.targets[k]).q.copy()
        for _ in range(iterations):
            err = q[held] - prev[held]
            if float(np.abs(err).max()) < 1e-7:
                break
            n = self_motion(solver.chain, q, s.direction)
            s.direction = n
            a = -float(n[held] @ err) / max(float(n[held] @ n[held]), 1e-12)
            a = max(-0.2, min(0.2, a))
            solver.q = np.clip(q + a * n, solver.chain.lower, solver.chain.upper)
            q = solver.track(s.targets[k]).q.copy()
        solver.q = q

    return before


def _rotation_vector(r: np.ndarray) -> np.ndarray:
    angle = math.acos(max(-1.0, min(1.0, (np.trace(r) - 1.0) / 2.0)))
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return w * (0.5 if angle < 1e-8 else angle / (2.0 * math.sin(angle)))


def velocity(cap: float, eps: float = 1e-3) -> Strategy:
    def speed(chain: Chain, q: np.ndarray, xdot: np.ndarray) -> float:
        return float(np.linalg.norm(np.linalg.lstsq(jacobian(chain, q), xdot, rcond=None)[0]))

    def before(solver: IKSolver, k: int, s: Stream) -> None:
        if k < 1:
            return
        a, b = s.targets[k - 1][0], s.targets[k][0]
        assert a.position is not None and b.position is not None
        assert a.rotation is not None and b.rotation is not None
        xdot = np.concatenate(
            [b.position - a.position, _rotation_vector(b.rotation @ a.rotation.T)]
        )
        q = solver.q
        n = self_motion(solver.chain, q, s.direction)
        s.direction = n
        slope = (
            speed(solver.chain, q + eps * n, xdot) - speed(solver.chain, q - eps * n, xdot)
        ) / (2 * eps)
        _move(solver, -slope * n, cap)

    return before


def oracle(
    options: IKOptions, horizon: int, every: int, spans: Sequence[float], cap: float
) -> Strategy:
    local = replace(options, global_fallback=False, null_space_step_rad=0.0, max_restarts=3)

    def simulate(sim: IKSolver, q0: np.ndarray, future: Sequence[list[Target]]) -> float:
        sim.q = q0.copy()
        prev, score = q0, 0.0
        for t in future:
            r = sim.track(t, options=local)
            step = float(np.abs(r.q - prev).max())
            prev = r.q.copy()
            score += max(0.0, step - EXCESS_RAD) ** 2 + (0.0 if r.success else 0.01)
        return score

    def walk(
        sim: IKSolver, q: np.ndarray, target: list[Target], span: float, n0: np.ndarray
    ) -> np.ndarray | None:
        """Follow the self-motion for ``span`` rad (largest joint), re-solving every 0.05."""
        parts = max(1, int(abs(span) / 0.05))
        n = n0
        for _ in range(parts):
            n = self_motion(sim.chain, q, n)
            sim.q = np.clip(
                q + (span / parts) * n / np.abs(n).max(), sim.chain.lower, sim.chain.upper
            )
            r = sim.track(target, options=local)
            if not r.success:
                return None
            q = r.q.copy()
        return q

    def before(solver: IKSolver, k: int, s: Stream) -> None:
        q = solver.q.copy()
        n = self_motion(solver.chain, q, s.direction)
        s.direction = n
        if k >= 1 and k % every == 0:
            if s.sim is None:
                s.sim = IKSolver(solver.chain, options)
            sim = s.sim
            future = s.targets[k : k + horizon]
            best, best_score = 0.0, simulate(sim, q, future)
            for span in spans:
                for side in (-1.0, 1.0):
                    start = walk(sim, q, s.targets[k - 1], side * span, n)
                    if start is not None and (score := simulate(sim, start, future)) < best_score:
                        best, best_score = side, score
            s.steer = best
        if s.steer:
            _move(solver, s.steer * n, cap)

    return before


@dataclass(frozen=True)
class Outcome:
    stream: int
    ratio: float  # largest step / the reference's
    worst_frame: int
    above: int  # frames whose step exceeds twice the reference's
    first_above: int  # the first of them (-1: none)
    missed: int  # frames out of tolerance


def run(
    chain: str,
    strategy: Strategy | None,
    streams: int,
    frames: int,
    rest_pull: float | None,
    tolerance_scale: float = 1.0,
) -> list[Outcome]:
    """The benchmark's streams, tracked as ``bench.ik.run_tracking`` tracks them (one
    solver, warmed by ``bench.ik.warm`` and reused across the streams: the global
    fallback's restarts draw from its generator, so this is what makes ``none`` give
    the benchmark's figures); ``rest_pull`` (not None) replaces STREAM_DEFAULTS'."""
    bc = load(chain, peer_urdf=False)
    cfg = Config(1, 0, 0, 0.005, frames, 60.0, streams, (), ())
    options = ours_options(1, stream=True, budget_us=cfg.timeout_s * 1e6)
    if rest_pull is not None:
        options = replace(options, null_space_step_rad=rest_pull)
    options = replace(
        options,
        position_tolerance_m=options.position_tolerance_m * tolerance_scale,
        rotation_tolerance_rad=options.rotation_tolerance_rad * tolerance_scale,
    )
    ours_adapter = Ours(bc, False, options, "steer_probe", track=True)
    warm(cfg, bc, [("ours", ours_adapter, 0)], False)
    solver = ours_adapter.solver
    out = []
    for index, reference in enumerate(reference_streams(cfg, bc)):
        path = reference.path
        stream = Stream(reference.targets)
        solver.set_pose(path[0])
        ours = np.empty_like(path)
        missed = 0
        for k in range(frames):
            if strategy is not None:
                strategy(solver, k, stream)
            r = solver.track(stream.targets[k])
            ours[k] = r.q
            missed += not r.success
        steps = np.abs(np.diff(ours, axis=0)).max(axis=1)
        ref = max_step(path)
        out.append(
            Outcome(
                index,
                float(steps.max() / ref),
                int(np.argmax(steps)) + 1,
                int((steps > 2 * ref).sum()),
                int(np.argmax(steps > 2 * ref)) + 1 if (steps > 2 * ref).any() else -1,
                missed,
            )
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--chain", default="iiwa", choices=CHAINS)
    ap.add_argument("--strategy", default=",".join(STRATEGIES))
    ap.add_argument("--streams", type=int, default=3)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--align", default=None, help="alignment joints, 0-based (attract)")
    ap.add_argument("--theta", type=float, default=0.3, help="attract when |q_j| < theta (rad)")
    ap.add_argument("--cap", type=float, default=0.01, help="steering per frame, rad per joint")
    ap.add_argument("--tolerance-scale", type=float, default=1.0, help="multiplies the tolerances")
    ap.add_argument("--horizon", type=int, default=120, help="oracle: frames looked ahead")
    ap.add_argument("--every", type=int, default=5, help="oracle: frames between look-aheads")
    ap.add_argument("--spans", default="0.3,0.6", help="oracle: candidate distances (rad)")
    ap.add_argument(
        "--rest-pull",
        type=float,
        default=0.0,
        help="null_space_step_rad of every strategy but none (STREAM_DEFAULTS: 0.005)",
    )
    args = ap.parse_args(argv)

    names = [s for s in args.strategy.split(",") if s]
    unknown = set(names) - set(STRATEGIES)
    if unknown:
        ap.error(f"unknown strategy {sorted(unknown)}; choose from {STRATEGIES}")
    align = (
        tuple(int(x) for x in args.align.split(","))
        if args.align
        else ALIGNMENT_JOINTS.get(args.chain, ())
    )
    if {"attract", "repel", "hold"} & set(names) and not align:
        ap.error(
            f"attract, repel and hold need --align for {args.chain} (no default alignment joints)"
        )
    base = ours_options(1, stream=True, budget_us=5000.0)
    options = replace(
        base,
        position_tolerance_m=base.position_tolerance_m * args.tolerance_scale,
        rotation_tolerance_rad=base.rotation_tolerance_rad * args.tolerance_scale,
    )
    spans = tuple(float(x) for x in args.spans.split(","))
    build: dict[str, Callable[[], Strategy | None]] = {
        "none": lambda: None,
        "nopull": lambda: None,
        "attract": lambda: attract(align, args.theta, args.cap),
        "hold": lambda: hold(align, args.theta),
        "flip": lambda: flip(load(args.chain, peer_urdf=False).pose),
        "repel": lambda: repel(align, args.theta, args.cap),
        "velocity": lambda: velocity(args.cap),
        "oracle": lambda: oracle(options, args.horizon, args.every, spans, args.cap),
    }
    print(
        f"{args.chain}: cap {args.cap} rad/frame, rest pull {args.rest_pull} but in none, "
        f"tolerances x {args.tolerance_scale:g}, {args.streams} x {args.frames} frames"
    )
    print(
        "| strategy | stream | largest step / reference's | at frame | frames above 2x | first | missed | s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    summaries: list[str] = []
    for name in names:
        t = time.perf_counter()
        rest_pull = None if name == "none" else args.rest_pull
        outcomes = run(
            args.chain, build[name](), args.streams, args.frames, rest_pull, args.tolerance_scale
        )
        took = time.perf_counter() - t
        summaries.append(
            f"{name}: {sum(o.ratio > 2.0 for o in outcomes)} of {len(outcomes)} streams above "
            f"2x, worst {max(o.ratio for o in outcomes):.1f}x, "
            f"{sum(o.missed for o in outcomes)} frames missed"
        )
        for o in outcomes:
            print(
                f"| {name} | {o.stream} | {o.ratio:.2f} | {o.worst_frame} | {o.above} "
                f"| {o.first_above} | {o.missed} | {took:.0f} |"
            )
    print()
    print("\n".join(summaries))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
