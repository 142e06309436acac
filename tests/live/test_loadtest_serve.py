"""``python -m loadtest.serve`` runs the service as ``python -m service`` does, in its
uvicorn settings too: the proxy headers believed from IK_FORWARDED_ALLOW_IPS only, and
the service's log lines (UTC time, pid), from every worker process it starts.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest

from loadtest.service_process import ROOT, free_port, readyz

from .test_server import TIMEOUT_S

pytestmark = pytest.mark.live

READY_LIMIT_S = 300.0  # a warm checkout loads the solver in seconds; a cold one compiles
STAMP = re.compile(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z \[(\d+)\] INFO: ")


class Serve:
    """``python -m loadtest.serve`` on a free port, its output in ``log_path``."""

    def __init__(self, log_path: Path, *args: str, **env: str) -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.log_path = log_path
        full_env = {k: v for k, v in os.environ.items() if not k.startswith("IK_")}
        full_env |= {"IK_LOG_LEVEL": "info", "PYTHONUNBUFFERED": "1", **env}
        self._log = open(log_path, "wb")  # noqa: SIM115 (closed in stop)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "loadtest.serve", "--port", str(self.port), *args],
            cwd=ROOT,
            env=full_env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its workers in its group: stop() ends them all
        )

    def wait_ready(self, workers: int) -> None:
        """Ready when 4 x ``workers`` fresh connections in a row answer 200."""
        deadline, streak = time.monotonic() + READY_LIMIT_S, 0
        while streak < 4 * workers:
            assert self.proc.poll() is None, f"loadtest.serve exited:\n{self.log()}"
            assert time.monotonic() < deadline, f"not ready:\n{self.log()}"
            answer = readyz(self.base)
            streak = streak + 1 if answer is not None and answer[0] == 200 else 0
            time.sleep(0.05 if streak else 0.2)

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self._log.close()


@pytest.fixture
def serve(tmp_path: Path) -> Iterator[Callable[..., Serve]]:
    started: list[Serve] = []

    def start(*args: str, **env: str) -> Serve:
        s = Serve(tmp_path / f"serve-{len(started)}.log", *args, **env)
        started.append(s)
        return s

    yield start
    for s in started:
        s.stop()


def _access_lines(s: Serve, path: str, n: int) -> list[str]:
    """The access-log lines of ``path``, once there are ``n`` (within 5 s: a pipe)."""
    deadline = time.monotonic() + 5
    while len(lines := [ln for ln in s.log().splitlines() if f'"GET {path} ' in ln]) < n:
        assert time.monotonic() < deadline, f"{len(lines)} of {n} logged:\n{s.log()}"
        time.sleep(0.05)
    return lines


@pytest.mark.parametrize(("allow", "client"), [(None, "127.0.0.1"), ("127.0.0.1", "198.51.100.9")])
def test_forwarded_for_is_believed_from_the_listed_proxies_only(
    serve: Callable[..., Serve], allow: str | None, client: str
) -> None:
    """As ``python -m service``: IK_FORWARDED_ALLOW_IPS unset, not even 127.0.0.1's
    header is believed (uvicorn's own default believes it); listed, it is."""
    s = serve("--workers", "1", **({} if allow is None else {"IK_FORWARDED_ALLOW_IPS": allow}))
    s.wait_ready(1)
    r = httpx.get(
        f"{s.base}/no-such-page", headers={"X-Forwarded-For": "198.51.100.9"}, timeout=TIMEOUT_S
    )
    assert r.status_code == 404
    (line,) = _access_lines(s, "/no-such-page", 1)
    assert f"{client}:" in line, line


def test_shared_workers_log_their_lines_with_time_and_pid(serve: Callable[..., Serve]) -> None:
    """``--balance shared``: uvicorn starts the workers, which never run main(); each
    still logs, in the service's format: its access lines under its own pid (the one
    its ``x-worker`` header names) and the service's own lines."""
    s = serve("--workers", "2", "--balance", "shared")
    s.wait_ready(2)
    pids = set()
    for _ in range(12):  # fresh connections: a shared socket hands them to either
        r = httpx.get(f"{s.base}/no-such-page", timeout=TIMEOUT_S)
        assert r.status_code == 404
        pids.add(int(r.headers["x-worker"]))
    lines = _access_lines(s, "/no-such-page", 12)
    stamped = [STAMP.match(ln) for ln in lines]
    assert all(stamped), lines
    assert {int(m.group(1)) for m in stamped if m} == pids
    assert len(_access_lines(s, "/no-such-page", 12)) == 12  # each once
    for pid in pids:  # the service's own lines (the solver's warm-up), each worker's
        own = [ln for ln in s.log().splitlines() if f"[{pid}] INFO: " in ln and "solver" in ln]
        assert own, s.log()
