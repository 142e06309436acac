"""A real `python -m service` on 127.0.0.1 (a free port), ready before the tests run.

Polls /readyz every 0.2 s instead of sleeping a fixed time. The first start in a fresh
checkout compiles the solver: minutes, more on busy cores (266 s measured). So the wait
follows the progress /readyz reports: it gives up when nothing moved for READY_STALL_S
(a single function compiles in well under that), or after READY_LIMIT_S in any case.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest

ROOT = Path(__file__).resolve().parents[2]
READY_STALL_S = 240.0
READY_LIMIT_S = 1200.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Server:
    """A `python -m service` process; ``base`` is its http://127.0.0.1:PORT."""

    def __init__(self, log_path: Path, **env: str) -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.log_path = log_path
        full_env = {
            **os.environ,
            "IK_HOST": "127.0.0.1",
            "IK_PORT": str(self.port),
            "PYTHONUNBUFFERED": "1",
            **env,
        }
        full_env.pop("OPENBLAS_NUM_THREADS", None)  # python -m service sets it itself
        self._log = open(log_path, "wb")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "service"],
            cwd=ROOT,
            env=full_env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
        )

    def wait_ready(self) -> None:
        start = time.monotonic()
        moved_at, seen = start, None
        while (now := time.monotonic()) - moved_at < READY_STALL_S and now - start < READY_LIMIT_S:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited:\n{self.log()}")
            try:
                r = httpx.get(f"{self.base}/readyz", timeout=2.0)
                if r.status_code == 200:
                    return
                progress = r.json().get("progress")
            except (httpx.HTTPError, ValueError):
                progress = None
            if progress is not None:
                where = (progress["phase"], progress["done"], progress["compiled"])
                if where != seen:
                    moved_at, seen = now, where
            time.sleep(0.2)
        raise RuntimeError(
            f"server not ready after {now - start:.0f} s (last progress {seen}, nothing moved "
            f"for {now - moved_at:.0f} s):\n{self.log()}"
        )

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(30.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10.0)
        self._log.close()
        return int(self.proc.returncode)


@pytest.fixture(scope="session")
def start_server(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[Callable[..., Server]]:
    servers: list[Server] = []

    def start(**env: str) -> Server:
        log = tmp_path_factory.mktemp("server") / "server.log"
        server = Server(log, **env)
        servers.append(server)
        server.wait_ready()
        return server

    yield start
    for s in servers:
        s.stop()


@pytest.fixture(scope="session")
def server(start_server: Callable[..., Server]) -> Server:
    """One shared server for the live tests that do not stop it."""
    return start_server()
