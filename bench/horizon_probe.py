"""What a client can trade for the step bar: latency (receding-horizon planning) or accuracy.

Issue #3 (c) asks that a tracked stream's largest joint step be at most twice the
reference path's; tracked frame by frame, 30 of 40 iiwa streams miss it, and planned as
a whole clip none does (``bench/RESULTS.md``, "iiwa tracking" and "Planned clips"). This
probe asks what lies between: a client that can wait W frames before it needs an
answer. From the pose committed so far, ``IKSolver.plan`` plans the next ``window``
frames, the first ``commit`` of them are kept, and the plan goes on from the last kept
pose, set as the service's ``PUT .../pose`` sets it (W = M: clips planned back to back,
each from the last answer of the one before). A frame is then answered once the frame ``window - 1`` after the start of its
chunk has arrived: a latency of ``window - commit`` to ``window - 1`` frames.

The streams are ``bench/ik.py`` part (c)'s (same generator and seed, so the first three
are the benchmark's), with its tracking options and 5 ms budget; the row ``track`` is
frame-by-frame tracking (``IKSolver.track``) of the same streams. Prints one row per
setting: streams within 2x of the reference's largest step, the worst stream, frames out
of tolerance, and the median over streams of planning time per frame.

``--caps`` adds the other trade: tracking with no frame's joints moving more than C rad
from the previous answer. A frame whose answer would step further is solved again,
locally (no global fallback), inside the box of the previous pose +- C; where that box
holds no answer, the frame is answered with its closest pose and counts as missed. The
extra columns give the longest run of consecutive missed frames and the largest
position error.

    OPENBLAS_NUM_THREADS=1 python -m bench.horizon_probe --chain iiwa --streams 40 \\
        --settings 60:15,120:30,240:60 --caps 0.037,0.1
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import dataclass, replace  # noqa: E402

import numpy as np  # noqa: E402

from solver.ik import IKOptions, IKResult, IKSolver, Target  # noqa: E402
from solver.kinematics import DD_HI, DD_LO  # noqa: E402

from .ik import Config, max_step, ours_options, reference_streams  # noqa: E402
from .ik_chains import CHAINS, load  # noqa: E402

FPS = 60.0


@dataclass(frozen=True)
class Setting:
    """Plan ``window`` frames ahead and keep the first ``commit``; window 0: track,
    each frame's joints moving at most ``cap`` rad (inf: no cap)."""

    window: int
    commit: int
    cap: float = math.inf

    @property
    def label(self) -> str:
        if self.window:
            return f"{self.window}:{self.commit}"
        return "track" if math.isinf(self.cap) else f"track, cap {self.cap:g} rad"

    @property
    def latency_s(self) -> tuple[float, float]:
        if self.window == 0:
            return 0.0, 0.0
        return (self.window - self.commit) / FPS, (self.window - 1) / FPS


@dataclass(frozen=True)
class Row:
    setting: Setting
    ratios: np.ndarray  # per stream: largest step / reference's
    missed: int  # frames out of tolerance, all streams
    longest_miss: int  # consecutive frames out of tolerance, longest run
    worst_error_m: float  # largest position error of any frame
    us_per_frame: float  # median over streams


def parse_settings(text: str) -> list[Setting]:
    out = []
    for item in filter(None, text.split(",")):
        window, _, commit = item.partition(":")
        s = Setting(int(window), int(commit or window))
        if not 1 <= s.commit <= s.window:
            raise ValueError(f"setting {item!r}: need 1 <= commit <= window")
        out.append(s)
    return out


def track_capped(
    solver: IKSolver, targets: Sequence[Target], cap: float, local: IKOptions
) -> IKResult:
    """``solver.track``, then, if any joint stepped more than ``cap``, the frame again
    from the previous pose inside the box of that pose +- cap. The box is the
    bound-constrained core's own bounds (the solver has no public per-frame box, so
    this reaches into its data; it holds for chains whose every effector moves every
    joint, where a frame keeps the bounds it finds)."""
    prev = solver.q.copy()
    r = solver.track(targets)
    if np.abs(r.q - prev).max() <= cap:
        return r
    lower, upper = solver.chain.lower, solver.chain.upper
    solver.q = prev
    solver._dd[DD_LO] = np.maximum(lower, prev - cap)
    solver._dd[DD_HI] = np.minimum(upper, prev + cap)
    try:
        return solver.track(targets, options=local)
    finally:
        solver._dd[DD_LO] = lower
        solver._dd[DD_HI] = upper


def answer_stream(
    solver: IKSolver, targets: Sequence[Sequence[Target]], setting: Setting
) -> tuple[np.ndarray, list[IKResult]]:
    """The stream's answers under ``setting`` from ``solver.q``, and their results."""
    n = len(targets)
    out = np.empty((n, solver.chain.n_dof))
    results: list[IKResult] = []
    if setting.window == 0:
        local = replace(solver.options, global_fallback=False)
        for k in range(n):
            r = track_capped(solver, targets[k], setting.cap, local)
            out[k] = r.q
            results.append(r)
        return out, results
    k = 0
    while k < n:
        plan = solver.plan(targets[k : k + setting.window])
        kept = plan.results[: setting.commit]
        for i, r in enumerate(kept):
            out[k + i] = r.q
        results += kept
        k += len(kept)
        if len(kept) < len(plan.results):
            # Go on from the last kept pose, as a client of the service would: PUT
            # .../pose (set_pose: the pose and the rest pose). Clips back to back need
            # nothing: a plan leaves the pose at its last answer.
            solver.set_pose(out[k - 1])
    return out, results


def longest_run(flags: Sequence[bool]) -> int:
    best = run = 0
    for f in flags:
        run = run + 1 if f else 0
        best = max(best, run)
    return best


def run(chain: str, settings: list[Setting], streams: int, frames: int) -> list[Row]:
    bc = load(chain, peer_urdf=False)
    cfg = Config(1, 0, 0, 0.005, frames, FPS, streams, (), ())
    options = ours_options(1, stream=True, budget_us=cfg.timeout_s * 1e6)
    references = list(reference_streams(cfg, bc))
    rows = []
    for setting in settings:
        solver = IKSolver(bc.pose, options)
        if not solver._every_effector_moves_all:
            raise SystemExit(f"{chain}: the cap's box needs every effector to move every joint")
        ratios, per_frame = [], []
        missed = longest = 0
        worst = 0.0
        for stream in references:
            path, targets = stream.path, stream.targets
            solver.set_pose(path[0])
            t = time.perf_counter()
            out, results = answer_stream(solver, targets, setting)
            per_frame.append((time.perf_counter() - t) / frames * 1e6)
            ratios.append(max_step(np.vstack([path[0], out])) / max_step(path))
            misses = [not r.success for r in results]
            missed += sum(misses)
            longest = max(longest, longest_run(misses))
            worst = max(worst, max(r.max_position_error_m for r in results))
        rows.append(
            Row(setting, np.array(ratios), missed, longest, worst, float(np.median(per_frame)))
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--chain", default="iiwa", choices=CHAINS)
    ap.add_argument("--streams", type=int, default=40)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument(
        "--settings",
        default="60:15,120:30,240:60",
        help="window:commit pairs, comma-separated; 'track' and the whole clip are added",
    )
    ap.add_argument("--caps", default="", help="per-frame joint step caps (rad), comma-separated")
    args = ap.parse_args(argv)
    try:
        settings = parse_settings(args.settings)
        caps = [Setting(0, 0, float(c)) for c in filter(None, args.caps.split(","))]
        if any(not 0.0 < c.cap < math.inf for c in caps):
            raise ValueError("--caps: each cap must be a positive finite angle (rad)")
    except ValueError as e:
        ap.error(str(e))
    settings = [Setting(0, 0), *caps, *settings, Setting(args.frames, args.frames)]
    t = time.perf_counter()
    rows = run(args.chain, settings, args.streams, args.frames)
    print(f"{args.chain}: {args.streams} streams x {args.frames} frames at {FPS:g} Hz")
    print(
        "| setting | latency (s) | within 2x | worst | frames missed | longest miss "
        "| largest error (mm) | us per frame |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        lo, hi = row.setting.latency_s
        print(
            f"| {row.setting.label} | {lo:.2f}-{hi:.2f} | {int((row.ratios <= 2.0).sum())} / "
            f"{len(row.ratios)} | {row.ratios.max():.2f}x | {row.missed} | "
            f"{row.longest_miss} | {row.worst_error_m * 1e3:.2f} | {row.us_per_frame:.0f} |"
        )
    print(f"\n{time.perf_counter() - t:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
