"""A real ``python -m service`` on 127.0.0.1, on a free port: start it, wait until
``/readyz`` answers 200, read its memory, stop it.

One place for what the load tools (``loadtest.soak``, ``loadtest.ws_inline_vs_thread``,
the deployments of ``loadtest.capacity``), ``bench/cold_start.py`` and the live tests
(``tests/live/conftest.py``) each need. Readiness is polled (every 0.2 s, bounded), never
slept for: the first start in a fresh checkout compiles the solver, which takes minutes.
Standard library only, so that ``bench.cold_start`` needs no HTTP client.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Mapping
from pathlib import Path
from types import TracebackType
from typing import Self

ROOT = Path(__file__).resolve().parents[1]
# The first start of a fresh checkout compiles the solver: minutes, more on busy cores
# (266 s measured). So the wait follows the progress /readyz reports: it gives up when
# nothing moved for READY_STALL_S (one function compiles in well under that), or after
# READY_LIMIT_S in any case.
READY_STALL_S = 240.0
READY_LIMIT_S = 1200.0
POLL_S = 0.2


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def readyz(base: str, timeout_s: float = 2.0) -> tuple[int, bytes] | None:
    """One GET of ``{base}/readyz``: (status, body), or None when nothing answered."""
    try:
        with urllib.request.urlopen(f"{base}/readyz", timeout=timeout_s) as r:
            return int(r.status), r.read()
    except urllib.error.HTTPError as e:  # 503 while warming up
        # The error holds the response's socket: close it here, not at garbage
        # collection, where the ResourceWarning lands in whichever test runs then.
        with e:
            return e.code, e.read()
    except (urllib.error.URLError, ConnectionError, TimeoutError):
        return None


def _progress_mark(body: bytes) -> tuple[object, ...] | None:
    """What of a 503 /readyz body shows the warm-up moving: (phase, steps, functions)."""
    try:
        progress = json.loads(body).get("progress")
    except (ValueError, AttributeError):
        return None
    if not isinstance(progress, dict):
        return None
    return (progress.get("phase"), progress.get("done"), progress.get("compiled"))


def _status_kb(pid: int, key: str) -> int:
    """A number from /proc/<pid>/status (Linux), e.g. ``VmRSS`` [kB] or ``Threads``."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1])
    return 0


def rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` and its descendants [MiB], from /proc (Linux)."""
    total_kb = 0
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            total_kb += _status_kb(p, "VmRSS")
        except OSError:  # gone in the meantime
            continue
        # Children of every thread: the service starts its compile processes from one.
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                todo.extend(int(c) for c in (task / "children").read_text().split())
            except OSError:
                pass
    return total_kb / 1024


def thread_count(pid: int) -> int:
    """Threads of ``pid``, from /proc (Linux)."""
    return _status_kb(pid, "Threads")


class StoppedOnExit:
    """A process (or a group of them) that ``with`` stops on the way out, whatever
    happened inside: ``stop`` is the subclass's."""

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    def stop(self) -> object:
        raise NotImplementedError


class ServiceProcess(StoppedOnExit):
    """``python -m service`` on 127.0.0.1 and a free port; ``base`` is its URL.

    Args:
        env: Variables added to this process's environment (``IK_*`` settings).
        log_path: File for the server's stdout and stderr; discarded when None.
        root: The checkout to run (another one compares two versions).
        port: The port (a restart on the port of a stopped one); a free one when None.
    """

    def __init__(
        self,
        *,
        env: Mapping[str, str] | None = None,
        log_path: Path | None = None,
        root: Path = ROOT,
        port: int | None = None,
    ) -> None:
        self.port = free_port() if port is None else port
        self.base = f"http://127.0.0.1:{self.port}"
        self.log_path = log_path
        full_env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
        # python -m service sets OPENBLAS_NUM_THREADS=1 itself, before numpy
        full_env |= {
            "IK_HOST": "127.0.0.1",
            "IK_PORT": str(self.port),
            "PYTHONUNBUFFERED": "1",
            # Every load-test client comes from 127.0.0.1: the per-address limits would
            # count them as one client (tests of those limits set them back).
            "IK_MAX_CONNECTIONS_PER_ADDRESS": "0",
            "IK_SESSIONS_PER_ADDRESS_PER_MIN": "0",
            **(env or {}),
        }
        self._log = open(log_path, "wb") if log_path else None  # noqa: SIM115 (closed in stop)
        self.started = time.perf_counter()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service"],
            cwd=root,
            env=full_env,
            stdout=self._log or subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
        )

    def wait_ready(
        self,
        *,
        stall_s: float = READY_STALL_S,
        limit_s: float = READY_LIMIT_S,
        on_not_ready: Callable[[int, bytes], None] | None = None,
    ) -> float:
        """Poll ``/readyz`` until it answers 200; returns the seconds since the start.

        While the solver compiles, /readyz's 503 carries ``progress``; the wait goes on
        as long as that moves, and gives up after ``stall_s`` without a move or after
        ``limit_s`` in all. ``on_not_ready`` sees every other answer (status, body).
        Raises RuntimeError when the server exits, TimeoutError when it gives up.
        """
        moved_at, seen = self.started, None
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}{self._tail()}")
            answer = readyz(self.base)
            now = time.perf_counter()
            if answer is not None and answer[0] == 200:
                return now - self.started
            if answer is not None:
                if on_not_ready is not None:
                    on_not_ready(*answer)
                where = _progress_mark(answer[1])
                if where is not None and where != seen:
                    moved_at, seen = now, where
            if now - moved_at > stall_s or now - self.started > limit_s:
                raise TimeoutError(
                    f"server not ready after {now - self.started:.0f} s (last progress {seen}, "
                    f"nothing moved for {now - moved_at:.0f} s){self._tail()}"
                )
            time.sleep(POLL_S)

    def log(self) -> str:
        """What the server wrote so far ("" without a log file)."""
        if self._log is None or self.log_path is None:
            return ""
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def _tail(self) -> str:
        text = self.log()
        return f":\n{text}" if text else ""

    def stop(self) -> int:
        """SIGTERM (the service drains and exits), SIGKILL after 30 s; the exit status."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(30.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10.0)
        if self._log is not None:
            self._log.close()
        return int(self.proc.returncode)
