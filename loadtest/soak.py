"""Soak: steady WebSocket and HTTP traffic with session churn against a real
`python -m service` on 127.0.0.1, for a bounded time; reports the server's memory
(RSS), round-trip p99 over time, and what is left behind (sessions, WebSockets,
event-loop tasks, threads).

    python -m loadtest.soak [--duration 600] [--ws-clients 3] [--http-clients 1]
                         [--rate 50] [--churn 10] [--append]

Each WebSocket client creates a session, opens a socket, streams panda frames at
``--rate`` per second, and every ``--churn`` seconds closes the socket, deletes the
session and starts over; each HTTP client does the same with POST frames (a 5-frame
clip every tenth request). After the run every client has deleted its session, so
sessions, WebSockets and event-loop tasks must be back to where they started.
Exit status 1 when RSS grew more than ``--max-growth`` after warm-up or anything was
left behind (the CI test, tests/live/test_soak.py, runs it for 60 s).
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import re
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import httpx
from ik_client import Chain, Client, Frame, ServiceError, Session, Target

from .service_process import ROOT, ServiceProcess, rss_mb, thread_count

RESULTS = ROOT / "bench" / "RESULTS.md"
PANDA: Chain = {"format": "example", "name": "panda_arm"}


def _target(t: float) -> Target:
    return {
        "effector": "tool",
        "position": {"x": 0.4, "y": 0.1 + 0.05 * math.sin(t), "z": 0.5},
        "orientation": {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0},
    }


@dataclass
class Shared:
    """What the clients record; one lock (the rates are low)."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    rtts: list[tuple[float, float]] = field(default_factory=list)  # (time, seconds)
    errors: dict[str, int] = field(default_factory=dict)
    frames: int = 0
    sessions: int = 0
    stop: threading.Event = field(default_factory=threading.Event)

    def rtt(self, t: float, s: float) -> None:
        with self.lock:
            self.rtts.append((t, s))
            self.frames += 1

    def error(self, what: str) -> None:
        with self.lock:
            self.errors[what] = self.errors.get(what, 0) + 1


def _churn(base: str, shared: Shared, use: Callable[[Client, Session], None]) -> None:
    """Sessions one after the other until the soak stops: each created (and counted),
    used, deleted; any error is counted and the client starts over."""
    with Client(base, timeout_s=30.0) as client:
        while not shared.stop.is_set():
            try:
                session = client.create_session(PANDA)
                with shared.lock:
                    shared.sessions += 1
                use(client, session)
                client.delete_session(session)
            except Exception as e:  # counted, and the client starts over
                shared.error(type(e).__name__)
                time.sleep(0.1)


def _paced(shared: Shared, rate: float, churn_s: float, send: Callable[[int], int]) -> None:
    """``send(i)`` at ``rate`` calls a second for ``churn_s`` (``i``: the frames sent so
    far; ``send`` returns how many it sent), each call's round trip recorded."""
    period = 1.0 / rate
    until = time.monotonic() + churn_s
    i = 0
    while time.monotonic() < until and not shared.stop.is_set():
        t0 = time.perf_counter()
        i += send(i)
        shared.rtt(time.monotonic(), time.perf_counter() - t0)
        time.sleep(max(0.0, period - (time.perf_counter() - t0)))


def ws_client(base: str, shared: Shared, rate: float, churn_s: float) -> None:
    """A game client through ``ik_client``: a session, its WebSocket stream at ``rate``,
    and every ``churn_s`` the socket closed, the session deleted, and over again."""

    def use(client: Client, session: Session) -> None:
        with client.stream(session, timeout_s=30.0) as stream:

            def send(i: int) -> int:
                try:
                    stream.frame([_target(i * 0.05)])
                except ServiceError as e:
                    shared.error(str(e.code))
                return 1

            _paced(shared, rate, churn_s, send)

    _churn(base, shared, use)


def http_client(base: str, shared: Shared, rate: float, churn_s: float) -> None:
    """The same over HTTP: one frame per request, a 5-frame clip every tenth."""

    def use(client: Client, session: Session) -> None:
        def send(i: int) -> int:
            n = 5 if i % 10 == 9 else 1
            try:
                if n == 1:
                    client.frame(session, [_target(i * 0.05)], id=i)
                else:
                    frames: list[Frame] = [
                        {"id": i + k, "targets": [_target((i + k) * 0.05)]} for k in range(n)
                    ]
                    client.clip(session, frames)
            except ServiceError as e:
                shared.error(f"http_{e.status_code}")
            return n

        _paced(shared, rate, churn_s, send)

    _churn(base, shared, use)


def _metric(text: str, name: str) -> float:
    m = re.search(rf"^{name} ([0-9.e+-]+)$", text, re.M)
    return float(m.group(1)) if m else float("nan")


@dataclass
class Sample:
    t_s: float
    rss_mb: float
    p99_ms: float
    frames: int
    sessions: float
    websockets: float
    tasks: float
    threads: int


def run(
    *,
    duration_s: float = 600.0,
    ws_clients: int = 3,
    http_clients: int = 1,
    rate: float = 50.0,
    churn_s: float = 10.0,
    sample_s: float = 5.0,
    warmup_s: float | None = None,
    log: Any = print,
) -> dict[str, Any]:
    """Run a soak; returns the samples and the verdict figures."""
    server = ServiceProcess(env={"IK_LOG_LEVEL": "warning", "IK_GRACEFUL_SHUTDOWN_S": "2"})
    try:
        server.wait_ready()
        base, pid = server.base, server.proc.pid

        def scrape() -> str:
            return httpx.get(f"{base}/metrics", timeout=10.0).text

        before = scrape()
        tasks0 = _metric(before, "ik_event_loop_tasks")
        threads0 = thread_count(pid)
        shared = Shared()
        clients = [
            threading.Thread(target=ws_client, args=(base, shared, rate, churn_s), daemon=True)
            for _ in range(ws_clients)
        ] + [
            threading.Thread(target=http_client, args=(base, shared, rate, churn_s), daemon=True)
            for _ in range(http_clients)
        ]
        t_start = time.monotonic()
        for c in clients:
            c.start()
        samples: list[Sample] = []
        seen = 0
        while (now := time.monotonic()) - t_start < duration_s:
            time.sleep(min(sample_s, max(0.0, duration_s - (now - t_start))))
            text = scrape()
            with shared.lock:
                window = [s for _, s in shared.rtts[seen:]]
                seen = len(shared.rtts)
                frames = shared.frames
            window.sort()
            p99 = window[min(len(window) - 1, int(0.99 * len(window)))] * 1e3 if window else 0.0
            sample = Sample(
                t_s=time.monotonic() - t_start,
                rss_mb=rss_mb(pid),
                p99_ms=p99,
                frames=frames,
                sessions=_metric(text, "ik_active_sessions"),
                websockets=_metric(text, "ik_websockets"),
                tasks=_metric(text, "ik_event_loop_tasks"),
                threads=thread_count(pid),
            )
            samples.append(sample)
            log(
                f"t={sample.t_s:6.0f} s  rss={sample.rss_mb:7.1f} MB  p99={p99:6.2f} ms  "
                f"frames={frames:7d}  sessions={sample.sessions:.0f}  "
                f"ws={sample.websockets:.0f}  tasks={sample.tasks:.0f}  threads={sample.threads}"
            )
        shared.stop.set()
        for c in clients:
            c.join(60.0)
        # Let the server see the last closes and deletes (bounded).
        settle = time.monotonic() + 10.0
        while True:
            after = scrape()
            left = (
                _metric(after, "ik_active_sessions"),
                _metric(after, "ik_websockets"),
                _metric(after, "ik_event_loop_tasks") - tasks0,
            )
            if left == (0.0, 0.0, 0.0) or time.monotonic() > settle:
                break
            time.sleep(0.2)
        warm = warmup_s if warmup_s is not None else max(sample_s, 0.25 * duration_s)
        after_warm = [s for s in samples if s.t_s >= warm] or samples
        rss_warm = after_warm[0].rss_mb
        rss_end = samples[-1].rss_mb
        return {
            "samples": samples,
            "rss_after_warmup_mb": rss_warm,
            "rss_end_mb": rss_end,
            "rss_growth": (rss_end - rss_warm) / rss_warm,
            "sessions_left": left[0],
            "websockets_left": left[1],
            "tasks_left": left[2],
            "threads_start": threads0,
            "threads_end": thread_count(pid),
            "frames": shared.frames,
            "sessions_created": shared.sessions,
            "errors": dict(shared.errors),
            "duration_s": duration_s,
            "clients": f"{ws_clients} WebSocket + {http_clients} HTTP at {rate:g} frames/s each",
            "churn_s": churn_s,
        }
    finally:
        server.stop()


def verdict(out: dict[str, Any], max_growth: float) -> list[str]:
    problems = []
    if out["rss_growth"] > max_growth:
        problems.append(f"RSS grew {out['rss_growth']:.1%} after warm-up (> {max_growth:.0%})")
    for what in ("sessions_left", "websockets_left", "tasks_left"):
        if out[what] != 0:
            problems.append(f"{what}: {out[what]:g}")
    return problems


def _markdown(out: dict[str, Any], cmd: str, problems: list[str]) -> str:
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    rows = "\n".join(
        f"| {s.t_s:.0f} | {s.rss_mb:.1f} | {s.p99_ms:.2f} | {s.frames} | {s.sessions:.0f} | "
        f"{s.websockets:.0f} | {s.tasks:.0f} | {s.threads} |"
        for s in out["samples"]
    )
    return (
        f"\nCommand: `{cmd}` (run {when}, 2 shared cores; client and server on the same "
        f"machine). Traffic: {out['clients']}, session churn every {out['churn_s']:g} s.\n\n"
        f"| t [s] | server RSS [MB] | round-trip p99 [ms] | frames so far | sessions | "
        f"WebSockets | loop tasks | threads |\n|---|---|---|---|---|---|---|---|\n{rows}\n\n"
        f"- frames {out['frames']}, sessions created {out['sessions_created']}, client-side "
        f"errors {out['errors'] or 'none'}\n"
        f"- RSS after warm-up {out['rss_after_warmup_mb']:.1f} MB, at the end "
        f"{out['rss_end_mb']:.1f} MB: growth {out['rss_growth']:+.1%}\n"
        f"- left behind after the clients stopped: sessions {out['sessions_left']:g}, "
        f"WebSockets {out['websockets_left']:g}, event-loop tasks {out['tasks_left']:+g}; "
        f"threads {out['threads_start']} at the start, {out['threads_end']} at the end\n"
        f"- verdict: {'PASS' if not problems else 'FAIL: ' + '; '.join(problems)}\n"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--duration", dest="duration_s", type=float, default=600.0, help="seconds (default 600)"
    )
    ap.add_argument("--ws-clients", type=int, default=3)
    ap.add_argument("--http-clients", type=int, default=1)
    ap.add_argument("--rate", type=float, default=50.0, help="frames/s per client")
    ap.add_argument("--churn", dest="churn_s", type=float, default=10.0, help="seconds per session")
    ap.add_argument(
        "--sample", dest="sample_s", type=float, default=10.0, help="seconds between samples"
    )
    ap.add_argument("--max-growth", type=float, default=0.10)
    ap.add_argument("--append", action="store_true", help="append to bench/RESULTS.md")
    args = ap.parse_args()
    # The options named as run()'s parameters (dest=), passed through.
    passed = ("duration_s", "ws_clients", "http_clients", "rate", "churn_s", "sample_s")
    out = run(**{name: getattr(args, name) for name in passed})
    problems = verdict(out, args.max_growth)
    cmd = "python -m loadtest.soak " + " ".join(sys.argv[1:])
    text = _markdown(out, cmd.strip(), problems)
    print(text)
    if args.append:
        body = RESULTS.read_text()
        if "\n## Soak\n" not in body:
            body += "\n## Soak\n"
        RESULTS.write_text(body + text)
    return 1 if problems else 0


if __name__ == "__main__":
    raise SystemExit(main())
