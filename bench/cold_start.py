"""Cold and warm start of ``python -m service``: seconds to ready and the RSS once ready.

Cold means no compiled solver on disk: every numba cache file under ``solver/`` is
deleted first (what a fresh checkout or image build sees). Warm is the next start,
which loads that cache. Each start is a real ``python -m service`` on 127.0.0.1, polled
on ``/readyz`` every 0.2 s; RSS is read from ``/proc`` (the process and its children)
at every poll (the peak) and when ``/readyz`` first answers 200, and the process is then
stopped with SIGTERM. The 1-minute load average is read at each start and at ready.

    OPENBLAS_NUM_THREADS=1 python -m bench.cold_start [--cold-runs 1] [--warm-runs 3]

Slow on purpose: the cold compile takes 40-270 s on these machines, so run it on idle
cores and quote the figures with the load they ran under.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import time
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
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


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def clear_numba_cache() -> int:
    """Delete every numba cache file under solver/; returns how many."""
    gone = 0
    for pattern in ("*.nbi", "*.nbc"):
        for path in SOLVER.rglob(pattern):
            path.unlink()
            gone += 1
    return gone


def _rss_mb(pid: int) -> float:
    """RSS of ``pid`` and its descendants, from /proc (Linux)."""
    total_kb = 0
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            status = Path(f"/proc/{p}/status").read_text()
        except OSError:
            continue
        for line in status.splitlines():
            if line.startswith("VmRSS:"):
                total_kb += int(line.split()[1])
        # Children of every thread: the service starts its compile processes from one.
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                todo.extend(int(c) for c in (task / "children").read_text().split())
            except OSError:
                pass
    return total_kb / 1024


def start_once(kind: str, timeout_s: float, log_path: Path | None = None) -> Start:
    port = _free_port()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", IK_HOST="127.0.0.1", IK_PORT=str(port))
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "service"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL if log_path is None else log_path.open("wb"),
    )
    progress_seen = False
    last_progress = "-"
    peak = 0.0
    load_at_start = os.getloadavg()[0]
    try:
        while True:
            if time.perf_counter() - t0 > timeout_s:
                raise TimeoutError(f"{kind} start not ready within {timeout_s} s")
            if proc.poll() is not None:
                raise RuntimeError(f"service exited with {proc.returncode}")
            peak = max(peak, _rss_mb(proc.pid))
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/readyz", timeout=2) as r:
                    if r.status == 200:
                        ready_s = time.perf_counter() - t0
                        rss = _rss_mb(proc.pid)
                        load = os.getloadavg()[0]
                        return Start(
                            kind,
                            ready_s,
                            rss,
                            max(peak, rss),
                            progress_seen,
                            last_progress,
                            load_at_start,
                            load,
                        )
            except urllib.error.HTTPError as e:  # 503 while warming: does it say how far?
                body = json.loads(e.read() or b"{}")
                p = body.get("progress")
                if p is not None:
                    progress_seen = True
                    last_progress = (
                        f"{p['phase']} {p['done']}/{p['total']}, {p['compiled']} compiled, "
                        f"{p['elapsed_s']:.0f} s"
                    )
            except (urllib.error.URLError, ConnectionError, TimeoutError):
                pass
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cold-runs", type=int, default=1, help="cold starts (cache deleted)")
    parser.add_argument("--warm-runs", type=int, default=3, help="warm starts after the cold one")
    parser.add_argument("--timeout-s", type=float, default=900.0)
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
        starts.append(start_once("cold", args.timeout_s, log_path(f"cold-{i}")))
        print(starts[-1], file=sys.stderr)
    starts += [
        start_once("warm", args.timeout_s, log_path(f"warm-{i}")) for i in range(args.warm_runs)
    ]
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
