"""The clients' tests run against a real `python -m service` (tests/live's Server)."""

from tests.live.conftest import Server, server, start_server

__all__ = ["Server", "server", "start_server"]
