"""Real `python -m service` processes on 127.0.0.1 (a free port each), ready before the
tests run: ``loadtest.service_process`` polls /readyz (bounded, every 0.2 s) instead of
sleeping a fixed time; the first start in a fresh checkout compiles the solver.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from loadtest.service_process import ROOT, ServiceProcess

__all__ = ["ROOT", "Server"]

Server = ServiceProcess  # the name the live tests use: a `python -m service`, `base` its URL


@pytest.fixture(scope="session")
def start_server(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[Callable[..., Server]]:
    servers: list[Server] = []

    def start(**env: str) -> Server:
        log = tmp_path_factory.mktemp("server") / "server.log"
        server = Server(env=env, log_path=log)
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
