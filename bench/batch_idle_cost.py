"""What a character of a 50-character batch costs in CPU, back to back and after idling.

Issue 24's bar is the server's CPU per character when 50 characters share one message
(<= 25 us for a 7-DOF arm). A game server sends one such message per tick, so at 60 Hz
the worker idles for most of each 16.7 ms between messages. ``bench.idle_cost`` showed
that on these machines (2 shared virtual cores) work after an idle gap costs more than
back to back; this measures how much for the batch path, without a socket, so that the
transport's share of the server's figure (``loadtest.cost --characters 50``) can be
told from the machine's.

In one process, the service's own handler of a WebSocket ``batch`` (``ws_batch``: read
the entries, ``batch.solve``, render, encode; the app built by ``create_app`` with its
lifespan started), for ``--characters`` sessions of the 7-DOF ``panda_arm`` following
``loadtest.paths``' path (the load tests' targets; each character its own phase), one
message after another, with a sleep of ``--gaps`` ms before each. Each gap has its own
sessions tracking the same targets from the same start, and the gaps take turns
``--block`` messages at a time (the order rotating), so that they do the same work under
the same load. It prints, per gap, the median and p90 over messages of the handler's
CPU time (``time.thread_time``) per character.

    OPENBLAS_NUM_THREADS=1 python -m bench.batch_idle_cost [--messages 200] [--gaps 0,0.5,2,8]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import time
import warnings
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import orjson  # noqa: E402

import schemas as S  # noqa: E402
from loadtest.paths import make_path  # noqa: E402
from service import convert  # noqa: E402
from service.config import Settings  # noqa: E402
from service.main import create_app  # noqa: E402
from service.responses import dumps_message  # noqa: E402
from service.routes.ws_batch import batch_reply, raw_batch  # noqa: E402
from service.session_tokens import SessionTokens  # noqa: E402

with warnings.catch_warnings():  # starlette's advice to install httpx2: not ours
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

CHAIN = "panda_arm"
RATE_HZ = 60.0


@dataclass(frozen=True, slots=True)
class GapRow:
    gap_ms: float
    cpu_us_median: float  # per character, over messages
    cpu_us_p90: float


class _Socket:
    """What ``batch_reply`` needs of a connection (``ws_batch.Connection``)."""

    def __init__(self, svc: Any) -> None:
        self.svc = svc
        self.build = convert.result_builder(S.ResultView.FULL)
        self.backlog = False
        self.tokens = SessionTokens(svc.store)
        self.client = "bench"


def measure(gaps_ms: list[float], characters: int, messages: int, block: int) -> list[GapRow]:
    # No frame-rate limit: the gaps shorter than a 60 Hz tick send faster than a client may.
    app = create_app(Settings(max_frames_per_s=0, sessions_per_address_per_min=0))
    with TestClient(app) as client:
        svc = app.state.ik
        while not svc.runner.warmup.ready.wait(1.0):
            pass
        # The entries must be solved on the loop, where thread_time sees them: a budget
        # over IK_INLINE_BUDGET_US would send them to the frame threads.
        config = svc.settings
        assert config.default_time_budget_us <= config.inline_budget_us, "not solved inline"
        targets = [orjson.loads(t) for t in make_path(CHAIN, RATE_HZ).targets]
        chain = {"chain": {"format": "example", "name": CHAIN}}
        sessions: list[list[dict[str, Any]]] = []
        for _ in gaps_ms:
            made = [client.post("/v1/sessions", json=chain) for _ in range(characters)]
            assert all(r.status_code == 201 for r in made), made[-1].text
            sessions.append([r.json() for r in made])
        sockets = [_Socket(svc) for _ in gaps_ms]

        def message(g: int, k: int) -> bytes:
            frames = [
                {
                    "session": s["id"],
                    "token": s["token"],
                    "id": k,
                    "targets": targets[(k + 37 * j) % len(targets)],
                }
                for j, s in enumerate(sessions[g])
            ]
            return orjson.dumps({"type": "batch", "id": k, "frames": frames})

        async def handle(g: int, k: int, pause_s: float) -> float:
            text = message(g, k)
            if pause_s > 0:
                await asyncio.sleep(pause_s)
            t0 = time.thread_time()
            reply = await batch_reply(
                raw_batch(orjson.loads(text)), False, time.perf_counter(), sockets[g]
            )
            dumps_message(reply)
            return (time.thread_time() - t0) * 1e6 / characters

        async def run() -> list[list[float]]:
            cpu: list[list[float]] = [[] for _ in gaps_ms]
            for g in range(len(gaps_ms)):  # warm: compiled entries resolved, streams under way
                for k in range(block):
                    await handle(g, k, 0.0)
            for b, first in enumerate(range(block, block + messages, block)):
                order = list(range(len(gaps_ms)))
                order = order[b % len(order) :] + order[: b % len(order)]
                for g in order:
                    for k in range(first, min(first + block, block + messages)):
                        cpu[g].append(await handle(g, k, gaps_ms[g] * 1e-3))
            return cpu

        cpu = client.portal.call(run)
    rows = []
    for g, gap_ms in enumerate(gaps_ms):
        ordered = sorted(cpu[g])
        rows.append(GapRow(gap_ms, statistics.median(ordered), ordered[int(0.9 * len(ordered))]))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--messages", type=int, default=200, help="batch messages per gap")
    ap.add_argument("--characters", type=int, default=50, help="sessions per batch message")
    ap.add_argument("--block", type=int, default=20, help="messages per turn of a gap")
    ap.add_argument(
        "--gaps", default="0,0.5,2,8", help="idle ms before each message, comma-separated"
    )
    args = ap.parse_args()
    gaps = [float(g) for g in args.gaps.split(",")]
    rows = measure(gaps, args.characters, args.messages, args.block)
    base = rows[0].cpu_us_median
    print(
        f"ws_batch handler in process, {args.characters} x {CHAIN} per message, "
        f"{args.messages} messages per gap"
    )
    print("| idle before each message | CPU per character median | p90 | / back to back |")
    print("|---|---|---|---|")
    for r in rows:
        print(
            f"| {r.gap_ms:g} ms | {r.cpu_us_median:.1f} us | {r.cpu_us_p90:.1f} us | "
            f"{r.cpu_us_median / base:.2f} |"
        )


if __name__ == "__main__":
    main()
