"""Cold and warm start of ``python -m service``: seconds to ready and the RSS once ready.

Cold means no compiled solver on disk: every numba cache file under ``solver/`` is
deleted first (what a fresh checkout or image build sees). Warm is the next start,
which loads that cache. Each start is a real ``python -m service`` on 127.0.0.1
(``loadtest.service_process``), polled on ``/readyz`` every 0.2 s; RSS is read from
``/proc`` (the process and its children) when ``/readyz`` first answers 200, and the
process is then stopped with SIGTERM.

    OPENBLAS_NUM_THREADS=1 python -m bench.cold_start [--warm-runs 3]

Slow on purpose: the cold compile takes 40-270 s on these machines, so run it on idle
cores and quote the figures with the load they ran under.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass

from loadtest.service_process import ROOT, ServiceProcess, rss_mb

SOLVER = ROOT / "solver"


@dataclass(frozen=True, slots=True)
class Start:
    kind: str
    ready_s: float
    rss_mb: float
    readyz_progress_seen: bool


def clear_numba_cache() -> int:
    """Delete every numba cache file under solver/; returns how many."""
    gone = 0
    for pattern in ("*.nbi", "*.nbc"):
        for path in SOLVER.rglob(pattern):
            path.unlink()
            gone += 1
    return gone


def start_once(kind: str, timeout_s: float) -> Start:
    progress_seen = False

    def warming(_status: int, body: bytes) -> None:  # 503 while warming: does it say how far?
        nonlocal progress_seen
        progress_seen = progress_seen or "progress" in json.loads(body or b"{}")

    with ServiceProcess() as server:
        ready_s = server.wait_ready(timeout_s, on_not_ready=warming)
        return Start(kind, ready_s, rss_mb(server.proc.pid), progress_seen)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--warm-runs", type=int, default=3, help="warm starts after the cold one")
    parser.add_argument("--timeout-s", type=float, default=900.0)
    args = parser.parse_args()
    cleared = clear_numba_cache()
    print(f"deleted {cleared} numba cache files under solver/", file=sys.stderr)
    starts = [start_once("cold", args.timeout_s)]
    starts += [start_once("warm", args.timeout_s) for _ in range(args.warm_runs)]
    print("| start | seconds to ready | RSS when ready (MB) | /readyz showed progress |")
    print("|---|---|---|---|")
    for s in starts:
        seen = "yes" if s.readyz_progress_seen else "no"
        print(f"| {s.kind} | {s.ready_s:.1f} | {s.rss_mb:.0f} | {seen} |")


if __name__ == "__main__":
    main()
