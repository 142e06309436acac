"""A short run of the hostile-client suite (loadtest/hostile.py): under each abuse the
well-behaved client keeps getting answers, nothing is a 5xx and memory stays bounded.
The latency goals are the suite's printed table (bench/RESULTS.md), not asserted here."""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest

from loadtest import hostile

from .conftest import Server

pytestmark = pytest.mark.live

SECONDS = 2.0
# The bound for 1,000 slowloris / 20 oversized-header connections.
RSS_GROWTH_MB = 50.0


@pytest.fixture(scope="module")
def hostile_server(start_server: Callable[..., Server]) -> Server:
    return start_server(**hostile.SERVER_ENV)


@pytest.mark.parametrize("name", list(hostile.ABUSES))
def test_the_polite_client_is_served_under_each_abuse(hostile_server: Server, name: str) -> None:
    row = asyncio.run(hostile.run_one(hostile_server, name, SECONDS))
    assert row.server_5xx == 0
    assert row.polite_ms and row.polite_errors == 0, row.cells()
    assert row.create_ms, row.cells()
    if "slowloris" in name or "header" in name or "idle" in name or "ping" in name:
        assert row.rss_peak_mb - row.rss_before_mb < RSS_GROWTH_MB, row.cells()
