"""Run the service (or the floors) in 1..N worker processes on one port, for load runs.

Deployments (``--balance``):

- ``reuseport`` (default): N independent processes, each with its own listening socket
  bound with SO_REUSEPORT; the kernel hashes each new connection to one of them, which
  splits connections close to evenly.
- ``shared``: ``uvicorn --workers N``: one listening socket inherited by N processes;
  whichever process wakes first accepts, so a burst of connections often lands mostly
  on one worker.

A session lives in the memory of the worker that created it, and a WebSocket stays on
the worker that accepted it; ``python -m loadtest`` opens each WebSocket on the
connection that created its session so both reach the same worker. Every HTTP response
carries ``x-worker: <pid>`` so the generator can count sessions per worker.

    python -m loadtest.serve --app service --workers 2 --port 8000

Settings come from the same ``IK_*`` variables as ``python -m service`` (``IK_PORT`` and
``IK_HOST`` are overridden by ``--port`` / ``--host`` when given).
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy (service imports it)

import uvicorn  # noqa: E402

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


class WorkerHeader:
    """ASGI wrapper adding ``x-worker: <pid>`` to every HTTP response."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self.value = str(os.getpid()).encode()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_header(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), (b"x-worker", self.value)]
            await send(message)

        await self.app(scope, receive, send_with_header)


def service_app() -> WorkerHeader:
    """The service as ``python -m service`` builds it, plus the worker header."""
    from service.config import get_settings
    from service.main import create_app

    return WorkerHeader(create_app(get_settings()))


def floors_app() -> WorkerHeader:
    """The bare echo / endpoint app, plus the worker header."""
    from .floors import create_floor_app

    return WorkerHeader(create_floor_app())


APPS = {"service": service_app, "floors": floors_app}


def _uvicorn_kwargs() -> dict[str, Any]:
    """The uvicorn settings ``python -m service`` uses, from the same IK_* variables;
    its logging too, which uvicorn applies in each process it runs (``--balance
    shared``'s workers never run ``main``)."""
    from service.config import get_settings
    from service.log_format import log_config

    s = get_settings()
    proxies = s.trusted_proxies()
    return {
        "ws": "websockets-sansio",
        # X-Forwarded-For believed from IK_FORWARDED_ALLOW_IPS only (service/forwarded.py):
        # uvicorn's default believes 127.0.0.1's, which every load client here is.
        "proxy_headers": bool(proxies),
        "forwarded_allow_ips": proxies.as_list(),
        "ws_max_size": s.ws_max_message_bytes,
        "ws_per_message_deflate": s.ws_compression,
        "timeout_graceful_shutdown": s.graceful_shutdown_s,
        "log_level": s.log_level,
        "log_config": log_config(s.log_level),
    }


def _reuseport_socket(host: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    sock.bind((host, port))
    return sock


def run_child(app: str, host: str, port: int) -> None:
    """One worker: its own SO_REUSEPORT socket, one uvicorn server."""
    sock = _reuseport_socket(host, port)
    # The app is built by uvicorn (factory), after it has set up the logging.
    config = uvicorn.Config(APPS[app], factory=True, **_uvicorn_kwargs())
    uvicorn.Server(config).run(sockets=[sock])


def run_reuseport(app: str, host: str, port: int, workers: int) -> int:
    """N child processes; SIGTERM / SIGINT are passed on to them and we wait for all."""
    cmd = [
        sys.executable,
        "-m",
        "loadtest.serve",
        "--child",
        "--app",
        app,
        "--host",
        host,
        "--port",
        str(port),
    ]
    children = [subprocess.Popen(cmd) for _ in range(workers)]

    def forward(signum: int, _frame: object) -> None:
        for c in children:
            if c.poll() is None:
                c.send_signal(signum)

    signal.signal(signal.SIGTERM, forward)
    signal.signal(signal.SIGINT, forward)
    codes = [c.wait() for c in children]
    return max((abs(c) for c in codes), default=0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m loadtest.serve",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("--app", choices=sorted(APPS), default="service")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--balance", choices=("reuseport", "shared"), default="reuseport")
    ap.add_argument("--host", default=None)
    ap.add_argument("--port", type=int, default=None)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    host = a.host or os.environ.get("IK_HOST", "127.0.0.1")
    port = a.port if a.port is not None else int(os.environ.get("IK_PORT", "8000"))
    os.environ["IK_HOST"], os.environ["IK_PORT"] = host, str(port)
    if a.child:
        run_child(a.app, host, port)
        return 0
    if not 1 <= a.workers <= 64:
        ap.error("--workers must be in 1..64")
    if a.balance == "shared":
        uvicorn.run(
            f"loadtest.serve:{a.app}_app",
            factory=True,
            host=host,
            port=port,
            workers=a.workers,
            **_uvicorn_kwargs(),
        )
        return 0
    return run_reuseport(a.app, host, port, a.workers)


if __name__ == "__main__":
    sys.exit(main())
