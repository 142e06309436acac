"""Inline vs thread-pool solves on the WebSocket path, against a real `python -m service`.

Starts the server twice on 127.0.0.1 (IK_INLINE_BUDGET_US=1e12: every frame inline;
=0: every frame in the solver pool) and runs, against each:

  stream  C clients, each streaming N panda_arm pose frames along a smooth path
          (typical solves: tens of microseconds) as fast as answers come back:
          throughput and round-trip p50 / p99.
  stall   one client sending frames the arm cannot reach (each burns its whole
          time budget B us) while another client pings: the ping round trip shows
          how long the event loop is held by someone else's solve.

The clients are ik_client's (``AsyncClient``, ``AsyncStream``; reconnecting off): what
is compared is the server's solving, not the wire.

Usage (from the repository root; bounded: a few thousand frames, < 1 min):

    OPENBLAS_NUM_THREADS=1 python -m loadtest.ws_inline_vs_thread [--clients 4] [--frames 2000]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import time

import numpy as np
from ik_client import AsyncClient, AsyncStream, SolverOptionsPatch, Target

from solver.model import matrix_to_quaternion
from solver.model.examples import panda_arm
from solver.model.forward import effector_poses

from .clients import NO_RECONNECT
from .service_process import ServiceProcess

PANDA = {"format": "example", "name": "panda_arm"}


def start_server(inline_budget_us: float, budget_us: float) -> ServiceProcess:
    server = ServiceProcess(
        env={
            "IK_LOG_LEVEL": "warning",
            "IK_INLINE_BUDGET_US": str(inline_budget_us),
            "IK_MAX_TIME_BUDGET_US": str(max(budget_us, 50_000.0)),
        }
    )
    try:
        server.wait_ready()
    except BaseException:
        server.stop()
        raise
    return server


def panda_path(n: int) -> list[Target]:
    chain = panda_arm()
    mid = chain.mid_limits()
    out: list[Target] = []
    for k in range(n):
        q = np.clip(mid + 0.3 * np.sin(0.01 * k + np.arange(7)), chain.lower, chain.upper)
        pose = effector_poses(chain, q)[0]
        w, x, y, z = (float(v) for v in matrix_to_quaternion(pose[:3, :3]))
        px, py, pz = (float(v) for v in pose[:3, 3])
        out.append(
            {
                "effector": "tool",
                "position": {"x": px, "y": py, "z": pz},
                "orientation": {"w": w, "x": x, "y": y, "z": z},
            }
        )
    return out


async def stream_of(ik: AsyncClient, options: SolverOptionsPatch) -> AsyncStream:
    """A new panda_arm session with ``options`` and its WebSocket (to open with ``async
    with``), not reconnecting."""
    session = await ik.create_session(PANDA, options=options)
    return ik.stream(session, reconnect=NO_RECONNECT, ping_interval_s=None)


async def stream_client(
    base: str, path: list[Target]
) -> tuple[list[float], list[float], list[float]]:
    rtts, solve, server = [], [], []
    async with AsyncClient(base) as ik, await stream_of(ik, {}) as stream:
        for target in path:
            t = time.perf_counter()
            result = await stream.frame([target])
            rtts.append(time.perf_counter() - t)
            solve.append(result.solve_us * 1e-6)
            server.append(result.server_us * 1e-6)
    return rtts, solve, server


async def heavy_client(base: str, budget_us: float, stop: asyncio.Event) -> int:
    far: Target = {
        "effector": "tool",
        "position": {"x": 3.0, "y": 0.0, "z": 0.5},
        "orientation": {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0},
    }
    n = 0
    options: SolverOptionsPatch = {"time_budget_us": budget_us, "max_iter": 100_000}
    async with AsyncClient(base) as ik, await stream_of(ik, options) as stream:
        while not stop.is_set() and n < 2000:
            await stream.frame([far])  # not reachable: a result with success False
            n += 1
    return n


async def ping_client(base: str, count: int) -> list[float]:
    rtts = []
    async with AsyncClient(base) as ik, await stream_of(ik, {}) as stream:
        for _ in range(count):
            t = time.perf_counter()
            await stream.ping()
            rtts.append(time.perf_counter() - t)
            await asyncio.sleep(0.002)
    return rtts


def pct(xs: list[float], p: float) -> float:
    return float(np.percentile(np.asarray(xs) * 1e6, p))


async def run(port: int, clients: int, frames: int, budget_us: float) -> dict[str, float]:
    base = f"http://127.0.0.1:{port}"
    path = panda_path(frames)
    await stream_client(base, path[:50])  # warm connections and caches
    t = time.perf_counter()
    results = await asyncio.gather(*(stream_client(base, path) for _ in range(clients)))
    wall = time.perf_counter() - t
    rtts = [x for r in results for x in r[0]]
    solve = [x for r in results for x in r[1]]
    server = [x for r in results for x in r[2]]
    stop = asyncio.Event()
    heavy = asyncio.create_task(heavy_client(base, budget_us, stop))
    await asyncio.sleep(0.2)
    pings = await ping_client(base, 300)
    stop.set()
    heavy_frames = await heavy
    return {
        "frames_per_s": len(rtts) / wall,
        "rtt_p50_us": pct(rtts, 50),
        "rtt_p99_us": pct(rtts, 99),
        "solve_p50_us": pct(solve, 50),
        "solve_p99_us": pct(solve, 99),
        "server_p50_us": pct(server, 50),
        "server_p99_us": pct(server, 99),
        "ping_p50_us": pct(pings, 50),
        "ping_p99_us": pct(pings, 99),
        "ping_max_us": max(pings) * 1e6,
        "heavy_frames": float(heavy_frames),
    }


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--clients", type=int, default=4)
    ap.add_argument("--frames", type=int, default=2000, help="frames per stream client")
    ap.add_argument("--budget-us", type=float, default=5000.0, help="heavy client's time budget")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args()
    rows: dict[str, list[dict[str, float]]] = {"inline": [], "pool": []}
    for _ in range(args.repeats):
        for mode, inline_budget in (("inline", 1e12), ("pool", 0.0)):
            with start_server(inline_budget, args.budget_us) as server:
                result = asyncio.run(run(server.port, args.clients, args.frames, args.budget_us))
            rows[mode].append(result)
    keys = list(rows["inline"][0])
    print(
        f"clients={args.clients} frames/client={args.frames} heavy budget={args.budget_us:g} us "
        f"repeats={args.repeats} (median over repeats)"
    )
    print("| metric | inline | pool |")
    print("|---|---|---|")
    for k in keys:
        a = statistics.median(r[k] for r in rows["inline"])
        b = statistics.median(r[k] for r in rows["pool"])
        print(f"| {k} | {a:,.0f} | {b:,.0f} |")


if __name__ == "__main__":
    main()
