"""Cold and warm start of ``python -m service``: seconds to ready and the RSS once ready.

Cold means no compiled solver on disk: every numba cache file under ``solver/`` is
deleted first (what a fresh checkout or image build sees). Warm is the next start,
which loads that cache. Each start is a real ``python -m service`` on 127.0.0.1
(``loadtest.service_process``), polled on ``/readyz`` every 0.2 s; RSS is read from
``/proc`` (the process and its children) at every poll (the peak) and when ``/readyz``
first answers 200, and the process is then stopped with SIGTERM. The 1-minute load average is read at each start and at ready.

    OPENBLAS_NUM_THREADS=1 python -m bench.cold_start [--cold-runs 1] [--warm-runs 3]

Slow on purpose: the cold compile takes 40-270 s on these machines, so run it on idle
cores and quote the figures with the load they ran under.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

from loadtest.service_process import ROOT, ServiceProcess, rss_mb

SOLVER = ROOT / "solver"


@dataclass(frozen=True, slots=True)
class Start:
    kind: str
    ready_s: float
    rss_mb: float
    peak_rss_mb: float
    readyz_progress_seen: bool
    last_progress: str  # the last progress /readyz showed before 200
    load_at_start: float
    load_at_ready: float


def clear_numba_cache() -> int:
    """Delete every numba cache file under solver/; returns how many."""
    gone = 0
    for pattern in ("*.nbi", "*.nbc"):
        for path in SOLVER.rglob(pattern):
            path.unlink()
            gone += 1
    return gone


def start_once(kind: str, log_path: Path | None = None) -> Start:
    progress_seen = False
    last_progress = "-"
    peak = 0.0
    load_at_start = os.getloadavg()[0]
    with ServiceProcess(env={"OPENBLAS_NUM_THREADS": "1"}, log_path=log_path) as server:

        def warming(_status: int, body: bytes) -> None:  # 503 while warming: how far?
            nonlocal progress_seen, last_progress, peak
            peak = max(peak, rss_mb(server.proc.pid))
            p = json.loads(body or b"{}").get("progress")
            if p is not None:
                progress_seen = True
                last_progress = (
                    f"{p['phase']} {p['done']}/{p['total']}, {p['compiled']} compiled, "
                    f"{p['elapsed_s']:.0f} s"
                )

        ready_s = server.wait_ready(on_not_ready=warming)
        rss = rss_mb(server.proc.pid)
        return Start(
            kind,
            ready_s,
            rss,
            max(peak, rss),
            progress_seen,
            last_progress,
            load_at_start,
            os.getloadavg()[0],
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cold-runs", type=int, default=1, help="cold starts (cache deleted)")
    parser.add_argument("--warm-runs", type=int, default=3, help="warm starts after the cold one")
    parser.add_argument("--log-dir", type=Path, help="keep each start's service log here")
    args = parser.parse_args()

    def log_path(name: str) -> Path | None:
        if args.log_dir is None:
            return None
        args.log_dir.mkdir(parents=True, exist_ok=True)
        return args.log_dir / f"{name}.log"

    starts = []
    for i in range(args.cold_runs):
        cleared = clear_numba_cache()
        print(f"deleted {cleared} numba cache files under solver/", file=sys.stderr)
        starts.append(start_once("cold", log_path(f"cold-{i}")))
        print(starts[-1], file=sys.stderr)
    starts += [start_once("warm", log_path(f"warm-{i}")) for i in range(args.warm_runs)]
    print(
        "| start | seconds to ready | RSS when ready (MB) | peak RSS, all processes (MB) "
        "| load avg at start / ready | last /readyz progress |"
    )
    print("|---|---|---|---|---|---|")
    for s in starts:
        print(
            f"| {s.kind} | {s.ready_s:.1f} | {s.rss_mb:.0f} | {s.peak_rss_mb:.0f} "
            f"| {s.load_at_start:.2f} / {s.load_at_ready:.2f} | {s.last_progress} |"
        )
    for kind in ("cold", "warm"):
        of_kind = [s for s in starts if s.kind == kind]
        if len(of_kind) > 1:
            print(
                f"| {kind}, median of {len(of_kind)} "
                f"| {statistics.median(s.ready_s for s in of_kind):.1f} "
                f"| {statistics.median(s.rss_mb for s in of_kind):.0f} "
                f"| {statistics.median(s.peak_rss_mb for s in of_kind):.0f} | | |"
            )


if __name__ == "__main__":
    main()
