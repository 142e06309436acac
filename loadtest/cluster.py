"""Several ``python -m service`` workers sharing sessions in a real ``redis-server``,
behind a real HAProxy running ``deploy/haproxy.cfg``, all on 127.0.0.1 free ports.

Used by tests/live/test_failover.py and ``python -m loadtest.cost --workers N``. The
balancer runs the shipped configuration; only its ``server-template`` lines (Docker's
DNS) are replaced by one ``server`` line per worker here.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

from .service_process import ROOT, ServiceProcess, StoppedOnExit, free_port

HAPROXY_CFG = ROOT / "deploy" / "haproxy.cfg"
START_LIMIT_S = 10.0


def missing_programs() -> list[str]:
    """Which of redis-server and haproxy this machine lacks (.ci/run installs them)."""
    return [p for p in ("redis-server", "haproxy") if shutil.which(p) is None]


def _wait_port(port: int, limit_s: float = START_LIMIT_S) -> None:
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            s.settimeout(0.2)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {limit_s} s")


class RedisServer:
    """``redis-server`` on a free port: in memory only, or with ``data_dir`` its
    append-only file there (as docker-compose.yml and deploy/k8s run it), so that a
    restart (``restart``) comes back with the sessions."""

    def __init__(
        self, port: int | None = None, *, data_dir: Path | None = None, password: str = ""
    ) -> None:
        self.port = port or free_port()
        auth = f":{password}@" if password else ""
        self.url = f"redis://{auth}127.0.0.1:{self.port}/0"
        self.data_dir = data_dir
        self.password = password  # requirepass: clients without it are refused
        self.proc: subprocess.Popen[bytes] | None = None
        self.start()

    def start(self) -> None:
        args = ["redis-server", "--port", str(self.port), "--bind", "127.0.0.1", "--save", ""]
        if self.data_dir is None:
            args += ["--appendonly", "no"]
        else:  # fsync at every write: a test restarts it right after the last frame
            args += ["--appendonly", "yes", "--appendfsync", "always", "--dir", str(self.data_dir)]
        if self.password:
            args += ["--requirepass", self.password]
        args += ["--loglevel", "warning"]
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
        _wait_port(self.port)

    def restart(self) -> None:
        """Stop (SIGTERM) and start again on the same port."""
        self.stop()
        self.start()

    def pause(self) -> None:
        """SIGSTOP: Redis stops answering (connections stay open: the hard case)."""
        assert self.proc is not None
        self.proc.send_signal(signal.SIGSTOP)

    def resume(self) -> None:
        assert self.proc is not None
        self.proc.send_signal(signal.SIGCONT)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGCONT)
            self.proc.terminate()
            self.proc.wait(10)


def balancer_config(workers: list[int], template: Path = HAPROXY_CFG) -> str:
    """``deploy/haproxy.cfg`` with a ``server`` line per worker port in place of each
    ``server-template`` line, and without the Docker DNS resolvers."""
    out: list[str] = []
    skip_section = False
    for line in template.read_text().splitlines():
        stripped = line.strip()
        if stripped.startswith("resolvers "):
            skip_section = True
            continue
        if skip_section:
            if line.startswith((" ", "\t")) or not stripped:
                continue
            skip_section = False
        if stripped.startswith("server-template "):
            indent = line[: len(line) - len(line.lstrip())]
            out += [f"{indent}server w{i} 127.0.0.1:{p}" for i, p in enumerate(workers)]
            continue
        out.append(line)
    return "\n".join(out) + "\n"


class Balancer:
    """HAProxy on a free port in front of ``workers`` (ports)."""

    def __init__(self, workers: list[int]) -> None:
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self._dir = tempfile.TemporaryDirectory(prefix="ik-haproxy-")
        cfg = Path(self._dir.name) / "haproxy.cfg"
        cfg.write_text(balancer_config(workers))
        env = {**os.environ, "IK_LB_BIND": f"127.0.0.1:{self.port}"}
        self.log_path = Path(self._dir.name) / "haproxy.log"
        self._log = open(self.log_path, "wb")  # noqa: SIM115 (closed in stop)
        self.proc = subprocess.Popen(
            ["haproxy", "-db", "-f", str(cfg)], env=env, stdout=self._log, stderr=subprocess.STDOUT
        )
        _wait_port(self.port)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(10)
        self._log.close()
        self._dir.cleanup()


class Cluster(StoppedOnExit):
    """Redis, ``n`` workers with IK_REDIS_URL, and HAProxy in front; ``base`` is the
    balancer's URL. Workers keep their ports across restarts (the balancer's list)."""

    def __init__(self, n: int, *, log_dir: Path, env: dict[str, str] | None = None) -> None:
        redis_dir = log_dir / "redis"
        redis_dir.mkdir(exist_ok=True)
        self.redis = RedisServer(data_dir=redis_dir)
        # HAProxy connects from 127.0.0.1 and names the client (option forwardfor).
        self.env = {
            "IK_REDIS_URL": self.redis.url,
            "IK_FORWARDED_ALLOW_IPS": "127.0.0.1",
            **(env or {}),
        }
        self.log_dir = log_dir
        self.workers: list[ServiceProcess] = []
        self.balancer: Balancer | None = None
        try:
            self.workers = [self._start_worker(i) for i in range(n)]
            for w in self.workers:
                w.wait_ready()
            self.balancer = Balancer([w.port for w in self.workers])
        except BaseException:
            self.stop()
            raise

    @property
    def base(self) -> str:
        assert self.balancer is not None
        return self.balancer.base

    def _start_worker(self, i: int, port: int | None = None) -> ServiceProcess:
        env = dict(self.env)
        if port is not None:
            env["IK_PORT"] = str(port)
        w = ServiceProcess(env=env, log_path=self.log_dir / f"worker{i}-{time.time_ns()}.log")
        if port is not None:  # ServiceProcess picked a port of its own; the env wins
            w.port, w.base = port, f"http://127.0.0.1:{port}"
        return w

    def kill(self, i: int) -> None:
        """SIGKILL worker ``i`` (no drain, no goodbye: a crash)."""
        w = self.workers[i]
        w.proc.kill()
        w.proc.wait(10)

    def restart(self, i: int) -> None:
        """Start worker ``i`` again on its port (after ``kill``)."""
        old = self.workers[i]
        if old.proc.poll() is None:
            self.kill(i)
        old.stop()  # closes its log
        self.workers[i] = self._start_worker(i, old.port)
        self.workers[i].wait_ready()

    def stop(self) -> None:
        if self.balancer is not None:
            self.balancer.stop()
        for w in self.workers:
            w.stop()
        self.redis.stop()
