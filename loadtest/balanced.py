"""Frames per second through HAProxy with 1, 2, 4 ... workers sharing sessions in Redis.

Starts ``loadtest.cluster.Cluster`` (redis-server, the workers, HAProxy running
deploy/haproxy.cfg) for each worker count, opens ``--clients`` WebSocket streams through
the balancer (one session each, spread by connection), each sending its next frame as
soon as the previous one is answered, for ``--duration`` seconds; prints the answered
frames per second.

    OPENBLAS_NUM_THREADS=1 python -m loadtest.balanced --workers 1,2,4 --clients 32
"""

from __future__ import annotations

import argparse
import asyncio
import math
import tempfile
import time
from pathlib import Path

import httpx
import orjson
from websockets.asyncio.client import connect

from .cluster import Cluster

DOWN = {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0}


def _frame(i: int, k: int) -> bytes:
    a = 2 * math.pi * (k + i) / 200
    position = {"x": 0.45 + 0.08 * math.cos(a), "y": 0.08 * math.sin(a), "z": 0.45}
    targets = [{"effector": "tool", "position": position, "orientation": DOWN}]
    return orjson.dumps({"type": "frame", "id": k, "targets": targets})


async def _client(base: str, i: int, ready: asyncio.Barrier, stop_at: list[float]) -> int:
    """One stream: its session and socket first, then (once every client has them)
    frames back to back until ``stop_at[0]``; the frames answered in that window."""
    async with httpx.AsyncClient(base_url=base, timeout=60) as http:
        chain = {"format": "example", "name": "panda_arm"}
        r = await http.post("/v1/sessions", json={"chain": chain})
        r.raise_for_status()
        s = r.json()
    ws_url = base.replace("http", "ws", 1) + f"/v1/sessions/{s['id']}/ws"
    n = 0
    headers = {"Authorization": f"Bearer {s['token']}"}
    async with connect(ws_url, additional_headers=headers) as ws:
        await ready.wait()
        while time.perf_counter() < stop_at[0]:
            await ws.send(_frame(i, n).decode())
            answer = orjson.loads(await ws.recv())
            if answer.get("type") == "result":
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
