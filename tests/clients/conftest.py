"""The clients' tests run against a real `python -m service` (tests/live's Server)."""

from collections.abc import Callable

import pytest

from tests.live.conftest import Server, start_server

__all__ = ["Server", "server", "start_server"]


@pytest.fixture(scope="session")
def server(start_server: Callable[..., Server]) -> Server:
    """The clients' own server: its frames get 100 ms instead of the default 1 ms, since
    these tests check what the clients send and read, not the server's speed on a loaded
    machine (in CI, a one-shot solve once ended `deadline` after one iteration)."""
    return start_server(IK_DEFAULT_TIME_BUDGET_US="100000")
