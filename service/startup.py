"""Getting the compiled solver into this process at startup, and saying how far it is.

The solver is numba code. The first start of a checkout or image finds no compiled
solver on disk and compiles it (minutes); numba caches the result on disk (the
``__pycache__`` folders under solver/, or NUMBA_CACHE_DIR), so every later start only
loads it (about a second).

``warm_solver`` first tries to load everything from that cache. Where something is
missing, the compile runs in child processes (``python -m service.compile_worker``),
up to ``processes`` of them, each compiling its share of the warm-up's steps into the
cache, and this process then loads the result. Why children: a compile holds ~1.5 GB
(numba's and LLVM's working memory, never given back) while the loaded code needs
~250 MB, and independent shares compile in parallel on separate cores (two at once
peak at ~2.4 GB together, bench/cold_start.py; one compile in-process peaked at
~1.9 GB).

Progress goes to ``report`` (readyz shows the last one) and to the log.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO

from schemas import StartupPhase, StartupProgress
from solver.precompile import STEP_NAMES, NotCached, WarmupProgress, cache_location, warmup

log = logging.getLogger("service")

Report = Callable[[StartupProgress], None]

# How the warm-up's steps are shared out. Measured (numba's compile events of each
# step, on busy cores): the IK core (pose) is ~15% of the compile, the planner's node
# search (plan_nodes) ~53%, its projection and DP (plan_projection) ~30%. With two
# processes the node search gets one to itself, the other compiles the rest. "plan"
# (the planner end to end) then only combines what the two compiled: it runs in the
# loading process (in a child it would compile whichever kernel the other child had
# not yet written to the cache, a second time).
_SHARES: dict[int, tuple[tuple[str, ...], ...]] = {
    1: (STEP_NAMES,),
    2: (("pose", "position", "aim", "no_variables", "plan_projection"), ("plan_nodes",)),
}

# The children import this process's solver: the one under this root, first.
_IMPORT_ROOT = Path(__file__).resolve().parent.parent

# Log a line while compiling at least this often (when something was compiled since).
_LOG_EVERY_S = 15.0


def shares(processes: int, steps: Sequence[str] = STEP_NAMES) -> list[tuple[str, ...]]:
    """``steps`` split over at most ``processes`` compile processes (each step in one
    share at most; see ``_SHARES``)."""
    split = _SHARES[min(max(processes, 1), max(_SHARES))]
    chosen = [tuple(n for n in share if n in steps) for share in split]
    return [share for share in chosen if share]


def warm_solver(report: Report, *, processes: int = 2, steps: Sequence[str] = STEP_NAMES) -> float:
    """Load the compiled solver into this process (the warm-up's ``steps``), compiling
    it first in child processes if the on-disk cache lacks any of it; returns the
    seconds it took."""
    start = time.perf_counter()
    log.info("loading the compiled solver from its on-disk cache (%s)", cache_location())
    try:
        warmup(_relay(report, StartupPhase.LOADING, start), steps=steps, load_only=True)
    except NotCached as missing:
        split = shares(processes, steps)
        log.info(
            "solver: no compiled code on disk for step %r: compiling it now, in %d "
            "process(es). This happens once per checkout or image (the compiled code is "
            "cached on disk); it takes minutes, later starts take about a second",
            missing.step,
            len(split),
        )
        compile_in_children(split, report, start)
        loaded = _load_after_compile(report, start, steps)
        log.info(
            "solver compiled and loaded in %.1f s (loading took %.1f s)",
            time.perf_counter() - start,
            loaded,
        )
    else:
        log.info(
            "solver loaded from its on-disk cache in %.1f s (nothing to compile)",
            time.perf_counter() - start,
        )
    return time.perf_counter() - start


def _relay(report: Report, phase: StartupPhase, start: float) -> Callable[[WarmupProgress], None]:
    def relay(p: WarmupProgress) -> None:
        elapsed = time.perf_counter() - start
        report(_progress(phase, p.done, p.total, elapsed, p.compiled))

    return relay


def _progress(
    phase: StartupPhase, done: int, total: int, elapsed_s: float, compiled: int
) -> StartupProgress:
    return StartupProgress(
        phase=phase, done=done, total=total, elapsed_s=round(elapsed_s, 1), compiled=compiled
    )


def _load_after_compile(report: Report, start: float, steps: Sequence[str]) -> float:
    """Load what the children compiled; whatever the cache still lacks (a child that
    failed) is compiled here, and said so."""
    compiled = 0

    def relay(p: WarmupProgress) -> None:
        nonlocal compiled
        compiled = p.compiled
        report(
            _progress(StartupPhase.LOADING, p.done, p.total, time.perf_counter() - start, compiled)
        )

    seconds = warmup(relay, steps=steps)
    if compiled:
        log.warning(
            "solver: %d functions were missing from the on-disk cache after the compile "
            "processes and were compiled in this process",
            compiled,
        )
    return seconds


class _Tally:
    """The compile processes' progress, summed (their reader threads update it)."""

    def __init__(self, n: int, total: int, report: Report, start: float) -> None:
        self.done = [0] * n
        self.compiled = [0] * n
        self.total = total
        self.report = report
        self.start = start
        self.lock = threading.Lock()
        self.logged_at = start
        self.logged = (0, 0)

    def update(self, i: int, done: int, compiled: int, step: str | None) -> None:
        with self.lock:
            self.done[i], self.compiled[i] = done, compiled
            now = time.perf_counter()
            state = (sum(self.done), sum(self.compiled))
            self.report(
                _progress(StartupPhase.COMPILING, state[0], self.total, now - self.start, state[1])
            )
            step_finished = state[0] > self.logged[0]
            if step_finished or (state != self.logged and now - self.logged_at >= _LOG_EVERY_S):
                self._log(state, step if step_finished else None, now)

    def heartbeat(self) -> None:
        """Log where the compile stands if nothing was logged for a while."""
        with self.lock:
            now = time.perf_counter()
            if now - self.logged_at >= _LOG_EVERY_S:
                self._log((sum(self.done), sum(self.compiled)), None, now)

    def _log(self, state: tuple[int, int], step: str | None, now: float) -> None:
        log.info(
            "compiling the solver: %d/%d steps done%s, %d functions compiled, %.0f s",
            state[0],
            self.total,
            f" ({step})" if step else "",
            state[1],
            now - self.start,
        )
        self.logged, self.logged_at = state, now


def compile_in_children(
    step_shares: Sequence[Sequence[str]], report: Report, start: float | None = None
) -> list[int]:
    """Compile each share of the warm-up's steps in a child process, all at once;
    returns their exit codes. A child that fails is logged (its stderr is this
    process's); the caller's load then compiles what it left out."""
    start = time.perf_counter() if start is None else start
    tally = _Tally(len(step_shares), sum(len(s) for s in step_shares), report, start)
    path = os.pathsep.join(p for p in (str(_IMPORT_ROOT), os.environ.get("PYTHONPATH")) if p)
    env = {**os.environ, "PYTHONPATH": path}
    children = [
        subprocess.Popen(
            [sys.executable, "-m", "service.compile_worker", *share],
            stdin=subprocess.PIPE,  # never written: the child exits when it closes (we die)
            stdout=subprocess.PIPE,
            env=env,
            text=True,
        )
        for share in step_shares
    ]
    readers = [
        threading.Thread(
            target=_read_progress, args=(child.stdout, i, tally), name=f"ik-compile-{i}"
        )
        for i, child in enumerate(children)
    ]
    for reader in readers:
        reader.start()
    # A single function can take a minute to compile: say every so often that it goes on.
    while alive := [reader for reader in readers if reader.is_alive()]:
        alive[0].join(_LOG_EVERY_S / 3)
        tally.heartbeat()
    codes = []
    for child, reader, share in zip(children, readers, step_shares, strict=True):
        reader.join()
        codes.append(child.wait())
        for pipe in (child.stdin, child.stdout):
            if pipe is not None:
                pipe.close()
        if codes[-1] != 0:
            log.error(
                "solver: the compile process for steps %s exited with %d; "
                "compiling what it left out in this process",
                list(share),
                codes[-1],
            )
    return codes


def _read_progress(stream: IO[str] | None, i: int, tally: _Tally) -> None:
    assert stream is not None
    for line in stream:
        try:
            p = json.loads(line)
            tally.update(i, int(p["done"]), int(p["compiled"]), p.get("step"))
        except (ValueError, KeyError, TypeError):
            log.warning("solver compile process %d: unexpected output %r", i, line[:200])
