"""A bounded run: N clients (in one or more generator processes), then one report.

Every run stops by itself: each client sends for ``duration_s`` and waits at most
``drain_s`` for its last answers; the parent gives each generator process a hard
deadline on top of that and terminates it (its own child, by handle) past it.
"""

from __future__ import annotations

import asyncio
import ipaddress
import multiprocessing as mp
import os
import resource
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import urlsplit

from .clients import ClientSpec, http_client, ws_client
from .paths import DEFAULT_CHAINS, Path, make_path
from .records import ClientResult, Progress

MAX_CLIENTS = 5000
MAX_DURATION_S = 3600.0
MAX_RATE_HZ = 1000.0


@dataclass(frozen=True)
class RunConfig:
    """One load run; the limits keep a typo from turning into an unbounded run."""

    url: str = "http://127.0.0.1:8000"
    transport: str = "ws"  # "ws" or "http"
    clients: int = 20
    rate_hz: float = 60.0
    duration_s: float = 10.0
    warmup_s: float = 1.0  # frames scheduled in each client's first warmup_s are not counted
    drain_s: float = 10.0
    timeout_s: float = 30.0  # connect / request timeout
    chains: tuple[str, ...] = DEFAULT_CHAINS
    processes: int = 1
    options: dict[str, Any] = field(default_factory=dict)  # session options (PATCH fields)
    results: str = "full"  # the service's ?results= view: "full" or "compact"
    deflate: bool = False  # WebSocket clients offer permessage-deflate (as browsers do)
    allow_remote: bool = False

    def check(self) -> None:
        parts = urlsplit(self.url)
        if parts.scheme != "http" or not parts.hostname:
            raise ValueError(f"url must be http://host:port, got {self.url!r}")
        if not self.allow_remote and not _is_loopback(parts.hostname):
            raise ValueError(f"{parts.hostname} is not a loopback address (--allow-remote)")
        if self.transport not in ("ws", "http"):
            raise ValueError("transport must be ws or http")
        if not 1 <= self.clients <= MAX_CLIENTS:
            raise ValueError(f"clients must be in 1..{MAX_CLIENTS}")
        if not 0 < self.rate_hz <= MAX_RATE_HZ:
            raise ValueError(f"rate must be in (0, {MAX_RATE_HZ:g}] Hz")
        if not 0 < self.duration_s <= MAX_DURATION_S:
            raise ValueError(f"duration must be in (0, {MAX_DURATION_S:g}] s")
        if not 0 <= self.warmup_s < self.duration_s:
            raise ValueError("warmup must be shorter than the duration")
        if not 1 <= self.processes <= max(1, self.clients):
            raise ValueError("processes must be in 1..clients")
        if self.results not in ("full", "compact"):
            raise ValueError("results must be full or compact")

    @property
    def hard_deadline_s(self) -> float:
        """Longest a run may take, setup included."""
        return self.timeout_s + self.duration_s + self.drain_s + 2 * self.timeout_s


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass
class RunOutput:
    """Every client's result plus what the generator itself cost."""

    config: RunConfig
    results: list[ClientResult]
    wall_s: float
    generator_cpu_s: float


def _specs(cfg: RunConfig, indices: list[int], paths: dict[str, Path]) -> list[ClientSpec]:
    period = 1.0 / cfg.rate_hz
    return [
        ClientSpec(
            index=i,
            url=cfg.url.rstrip("/"),
            transport=cfg.transport,
            path=paths[cfg.chains[i % len(cfg.chains)]],
            rate_hz=cfg.rate_hz,
            duration_s=cfg.duration_s,
            drain_s=cfg.drain_s,
            timeout_s=cfg.timeout_s,
            # Spread the clients' ticks over one period, so they do not all send at once.
            phase_s=period * i / cfg.clients,
            options=cfg.options,
            results=cfg.results,
            deflate=cfg.deflate,
        )
        for i in indices
    ]


async def _run_clients(
    cfg: RunConfig,
    indices: list[int],
    progress: Progress,
    start_wall: float,
) -> list[ClientResult]:
    paths = {c: make_path(c, cfg.rate_hz) for c in set(cfg.chains)}
    specs = _specs(cfg, indices, paths)
    # A common start on the wall clock, so clients in different processes line up;
    # sessions are opened before it (setup time is not load).
    start = time.perf_counter() + max(0.0, start_wall - time.time())
    run = ws_client if cfg.transport == "ws" else http_client
    return list(await asyncio.gather(*(run(s, start, progress) for s in specs)))


def _child(
    cfg: RunConfig,
    indices: list[int],
    start_wall: float,
    shared: Any,
    slot: int,
    out: Any,
) -> None:
    """A generator process: runs its clients, mirrors progress into shared memory."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    progress = Progress()

    async def main() -> list[ClientResult]:
        async def mirror() -> None:
            while True:
                shared[4 * slot : 4 * slot + 4] = [
                    progress.sent,
                    progress.answered,
                    progress.errors,
                    progress.late,
                ]
                await asyncio.sleep(0.25)

        task = asyncio.create_task(mirror())
        try:
            return await _run_clients(cfg, indices, progress, start_wall)
        finally:
            task.cancel()

    results = asyncio.run(main())
    ru = resource.getrusage(resource.RUSAGE_SELF)
    out.put((slot, results, ru.ru_utime + ru.ru_stime))


def _setup_allowance_s(cfg: RunConfig) -> float:
    # Session creation: chain parsing runs in the server's pool; tails are the slowest.
    return 1.0 + 0.02 * cfg.clients


def run(cfg: RunConfig, on_progress: Callable[[str], None] | None = None) -> RunOutput:
    """Run ``cfg`` to the end and return every client's result."""
    cfg.check()
    t_wall0 = time.perf_counter()
    start_wall = time.time() + _setup_allowance_s(cfg)
    if cfg.processes == 1:
        progress = Progress()
        cpu0 = time.process_time()

        async def main() -> list[ClientResult]:
            task = asyncio.create_task(_report_progress(cfg, [progress], on_progress, start_wall))
            try:
                return await asyncio.wait_for(
                    _run_clients(cfg, list(range(cfg.clients)), progress, start_wall),
                    cfg.hard_deadline_s,
                )
            finally:
                task.cancel()

        results = asyncio.run(main())
        return RunOutput(cfg, results, time.perf_counter() - t_wall0, time.process_time() - cpu0)
    return _run_processes(cfg, on_progress, start_wall, t_wall0)


def _run_processes(
    cfg: RunConfig,
    on_progress: Callable[[str], None] | None,
    start_wall: float,
    t_wall0: float,
) -> RunOutput:
    ctx = mp.get_context("spawn")  # no forked asyncio or numba state
    shared = ctx.Array("q", 4 * cfg.processes, lock=False)
    out = ctx.Queue()
    start_wall += 1.0  # spawned interpreters need a moment to import
    procs = []
    for slot in range(cfg.processes):
        indices = list(range(slot, cfg.clients, cfg.processes))
        p = ctx.Process(target=_child, args=(cfg, indices, start_wall, shared, slot, out))
        p.start()
        procs.append(p)
    deadline = time.monotonic() + cfg.hard_deadline_s + 10.0
    collected: dict[int, tuple[list[ClientResult], float]] = {}
    last = 0.0
    while len(collected) < cfg.processes and time.monotonic() < deadline:
        try:
            slot, results, cpu = out.get(timeout=0.25)
            collected[slot] = (results, cpu)
        except Exception:  # queue.Empty; spawn's Queue re-exports it awkwardly
            pass
        if on_progress is not None and time.monotonic() - last >= 1.0:
            last = time.monotonic()
            progs = [Progress(*shared[4 * s : 4 * s + 4]) for s in range(cfg.processes)]
            on_progress(_progress_line(cfg, progs, start_wall))
    for p in procs:
        p.join(timeout=5.0)
        if p.is_alive():  # past the hard deadline: our own child, stopped by handle
            p.terminate()
            p.join(timeout=5.0)
    if len(collected) < cfg.processes:
        print(
            f"loadtest: {cfg.processes - len(collected)} generator process(es) "
            "gave no result before the deadline",
            file=sys.stderr,
        )
    results = sorted((r for rs, _ in collected.values() for r in rs), key=lambda r: r.index)
    cpu = sum(c for _, c in collected.values())
    return RunOutput(cfg, results, time.perf_counter() - t_wall0, cpu)


def _progress_line(cfg: RunConfig, progs: list[Progress], start_wall: float) -> str:
    el = time.time() - start_wall
    sent = sum(p.sent for p in progs)
    answered = sum(p.answered for p in progs)
    errors = sum(p.errors for p in progs)
    late = sum(p.late for p in progs)
    if el < 0:
        return f"setting up {cfg.clients} sessions ({-el:.1f} s to start)"
    rate = answered / el if el > 0 else 0.0
    return (
        f"{min(el, cfg.duration_s):5.1f}/{cfg.duration_s:g} s  sent {sent}  answered "
        f"{answered} ({rate:,.0f}/s)  late {late}  errors {errors}"
    )


async def _report_progress(
    cfg: RunConfig,
    progs: list[Progress],
    on_progress: Callable[[str], None] | None,
    start_wall: float,
) -> None:
    if on_progress is None:
        return
    while True:
        await asyncio.sleep(1.0)
        on_progress(_progress_line(cfg, progs, start_wall))
