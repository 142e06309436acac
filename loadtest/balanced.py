"""Frames per second through HAProxy with 1, 2, 4 ... workers sharing sessions in Redis.

Starts ``loadtest.cluster.Cluster`` (redis-server, the workers, HAProxy running
deploy/haproxy.cfg) for each worker count, opens ``--clients`` WebSocket streams through
the balancer (one session each, spread by connection), each sending its next frame as
soon as the previous one is answered, for ``--duration`` seconds; prints the answered
frames per second. The clients are ik_client's (``AsyncClient``, ``AsyncStream``), with
reconnecting off: a stream that drops fails the run rather than being mended.

    OPENBLAS_NUM_THREADS=1 python -m loadtest.balanced --workers 1,2,4 --clients 32
"""

from __future__ import annotations

import argparse
import asyncio
import math
import tempfile
import time
from pathlib import Path

from ik_client import AsyncClient, FrameAnswer, Quaternion, ServiceError, Target

from .clients import NO_RECONNECT
from .cluster import Cluster

DOWN: Quaternion = {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0}
PANDA = {"format": "example", "name": "panda_arm"}


def _targets(i: int, k: int) -> list[Target]:
    a = 2 * math.pi * (k + i) / 200
    position = {"x": 0.45 + 0.08 * math.cos(a), "y": 0.08 * math.sin(a), "z": 0.45}
    return [{"effector": "tool", "position": position, "orientation": DOWN}]


async def _client(base: str, i: int, ready: asyncio.Barrier, stop_at: list[float]) -> int:
    """One stream: its session and socket first, then (once every client has them)
    frames back to back until ``stop_at[0]``; the frames answered in that window."""
    async with AsyncClient(base, timeout_s=60.0) as ik:
        session = await ik.create_session(PANDA)
        n = 0
        async with ik.stream(
            session, reconnect=NO_RECONNECT, timeout_s=60.0, ping_interval_s=None
        ) as stream:
            await ready.wait()
            while time.perf_counter() < stop_at[0]:
                await stream.send_frame(_targets(i, n))
                try:
                    answer = await stream.receive()
                except ServiceError:
                    continue  # answered, but with an error: not counted
                if isinstance(answer, FrameAnswer):
                    n += 1
    return n


async def _load(base: str, clients: int, duration_s: float) -> float:
    """Answered frames per second over ``duration_s``, all clients streaming."""
    stop_at = [math.inf]
    ready = asyncio.Barrier(clients + 1)
    tasks = [asyncio.create_task(_client(base, i, ready, stop_at)) for i in range(clients)]
    await ready.wait()  # every session created and every socket open
    stop_at[0] = time.perf_counter() + duration_s
    counts = await asyncio.gather(*tasks)
    return sum(counts) / duration_s


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser("python -m loadtest.balanced", description=__doc__)
    ap.add_argument("--workers", default="1,2,4", help="comma-separated worker counts")
    ap.add_argument("--clients", type=int, default=32)
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--repeat", type=int, default=1, help="runs per worker count")
    args = ap.parse_args(argv)
    env = {"IK_MAX_FRAMES_PER_S": "0"}
    for n in (int(x) for x in args.workers.split(",") if x):
        with tempfile.TemporaryDirectory() as tmp, Cluster(n, log_dir=Path(tmp), env=env) as c:
            rates = [
                asyncio.run(_load(c.base, args.clients, args.duration)) for _ in range(args.repeat)
            ]
            shown = ", ".join(f"{r:.0f}" for r in rates)
            print(f"{n} worker(s), {args.clients} clients: {shown} frames/s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
