"""Many characters per message: clients that each drive ``characters`` sessions of one
chain over one WebSocket, one ``batch`` message per tick (``loadtest.cost --characters``).

Each client creates its sessions over HTTP, opens the socket on the first one and, at
``rate_hz``, sends one batch holding a frame for every session, each session at its own
point of the chain's path; it waits for the answer before the next tick's send is due
(one message in flight). An entry answered with an error counts in ``errors``
(``entry_<code>``), as does an error answer to the whole message (``ws_<code>``) and a
socket closed under the client (``closed_<code>``, which ends that client).

The batches go through ik_client's ``AsyncStream`` (``send_batch``; reconnecting off,
permessage-deflate only with ``--deflate``). The sessions are created with plain httpx:
the floor's bare echo, measured by the same clients, answers session creation with an
id and a token only, and echoes each batch back as it came (an ``UnexpectedAnswer``
whose entries are the frames echoed).
"""

from __future__ import annotations

import asyncio
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import httpx
import orjson
from ik_client import (
    Answer,
    AsyncClient,
    BatchAnswer,
    BatchFrame,
    ServiceError,
    StreamClosed,
    Target,
    UnexpectedAnswer,
)

from .clients import NO_RECONNECT, StickySession
from .paths import make_path


@dataclass
class BatchRun:
    """What the clients saw: messages and entries answered, errors, round trips."""

    server_cpu_s: float = 0.0  # from the moment every client has its sessions
    messages: int = 0
    entries: int = 0
    measured_entries: int = 0  # answered after the warm-up
    errors: Counter[str] = field(default_factory=Counter)
    rtt_ms: list[float] = field(default_factory=list)


async def _client(
    url: str, index: int, characters: int, chain: str, rate_hz: float, duration_s: float,
    warmup_s: float, results: str, deflate: bool, run: BatchRun, ready: asyncio.Barrier,
) -> None:  # fmt: skip
    path = make_path(chain, rate_hz)
    sessions = []
    try:
        async with httpx.AsyncClient(base_url=url, timeout=60.0) as http:
            for _ in range(characters):
                r = await http.post(
                    "/v1/sessions", json={"chain": {"format": "example", "name": chain}}
                )
                if r.status_code != 201:
                    run.errors[f"setup_http_{r.status_code}"] += 1
                    break
                sessions.append(r.json())
    except httpx.HTTPError as e:  # refused, timed out: counted, and still at the barrier
        run.errors[f"setup_{type(e).__name__}"] += 1
    await ready.wait()  # every client has its sessions: the measured window starts
    if len(sessions) < characters:
        # Counted above; it still met the others at the barrier (returning before it
        # left them waiting for ever) and sends nothing.
        return
    refs = [StickySession(x["id"], x["token"]) for x in sessions]
    targets: list[list[Target]] = [orjson.loads(t) for t in path.targets]
    period = 1.0 / rate_hz
    n_path = len(targets)
    async with (
        AsyncClient(url, timeout_s=60.0) as ik,
        ik.stream(
            refs[0],
            compact=results == "compact",
            reconnect=NO_RECONNECT,
            timeout_s=None,
            deflate=deflate,
            ping_interval_s=None,  # no keepalive frames in the measured traffic
        ) as stream,
    ):
        start = time.perf_counter() + index * period / 7
        k = 0
        while (t_sched := start + k * period) - start < duration_s:
            delay = t_sched - time.perf_counter()
            if delay > 0:
                await asyncio.sleep(delay)
            frames: list[BatchFrame] = [
                {"session": s.id, "token": s.token, "id": k,
                 "targets": targets[(k + 37 * j) % n_path]}
                for j, s in enumerate(refs)
            ]  # fmt: skip
            entries = 0
            answer: Answer | UnexpectedAnswer | None
            try:
                await stream.send_batch(frames)
                answer = await stream.receive()
            except UnexpectedAnswer as e:  # the floor's echo
                answer = e
            except ServiceError as e:  # the whole message refused
                run.errors[f"ws_{e.code}"] += 1
                answer = None
            except StreamClosed as e:
                run.errors[f"closed_{e.close_code}"] += 1
                return
            now = time.perf_counter()
            run.messages += 1
            if isinstance(answer, BatchAnswer):
                entries = len(answer.results)
                for r in answer.results:
                    if r.error is not None:
                        run.errors[f"entry_{r.error.code}"] += 1
            elif isinstance(answer, UnexpectedAnswer):  # the floor's echo: the frames sent
                entries = len(answer.envelope.get("frames") or [])
            run.entries += entries
            if now - start >= warmup_s:
                run.measured_entries += entries
                run.rtt_ms.append((now - t_sched) * 1e3)
            k += 1


def run_batches(
    url: str, *, clients: int, characters: int, chain: str, rate_hz: float, duration_s: float,
    warmup_s: float, results: str, cpu_s: Callable[[], float], deflate: bool = False,
) -> BatchRun:  # fmt: skip
    """Run ``clients`` batch clients against ``url`` (in this process) until done;
    ``cpu_s`` reads the server's CPU time, counted once every session is created;
    ``results``: ``full`` or ``compact`` (``?results=``); ``deflate``: the clients offer
    permessage-deflate."""
    run = BatchRun()
    ready = asyncio.Barrier(clients + 1)

    async def main() -> None:
        tasks = [
            asyncio.create_task(
                _client(
                    url,
                    i,
                    characters,
                    chain,
                    rate_hz,
                    duration_s,
                    warmup_s,
                    results,
                    deflate,
                    run,
                    ready,
                )
            )
            for i in range(clients)
        ]
        await ready.wait()
        cpu0 = cpu_s()
        await asyncio.gather(*tasks)
        run.server_cpu_s = cpu_s() - cpu0

    asyncio.run(main())
    return run


def summary(run: BatchRun) -> dict[str, Any]:
    rtt = sorted(run.rtt_ms)
    return {
        "messages": run.messages,
        "entries": run.entries,
        "errors": dict(run.errors),
        "rtt_ms_p50": rtt[len(rtt) // 2] if rtt else None,
        "rtt_ms_p99": rtt[min(len(rtt) - 1, int(0.99 * len(rtt)))] if rtt else None,
    }
