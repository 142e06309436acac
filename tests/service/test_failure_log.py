"""The WARNING for requests Redis failed is throttled per cause (an operator trial:
8,516 identical lines in a 7 s outage, one per failed frame)."""

from __future__ import annotations

import logging

import pytest
from redis.exceptions import BusyLoadingError
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeout

from service.redis_commit import FailureLog, redis_cause


def test_a_failed_request_is_logged_once_per_interval_with_the_count_left_out(
    caplog: pytest.LogCaptureFixture,
) -> None:
    now = [0.0]
    failures = FailureLog(every_s=10.0, clock=lambda: now[0])
    caplog.set_level(logging.WARNING, logger="service")
    for k in range(600):  # 60 Hz for 10 s, the same cause
        now[0] = k / 60
        failures.failed(RedisConnectionError("Error 111 connecting to 127.0.0.1:16379."))
    failures.failed(RedisTimeout("Timeout reading from socket"))  # another cause: its own line
    now[0] = 10.5
    failures.failed(RedisConnectionError("Error 111 connecting to 127.0.0.1:16379."))
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 3, lines
    assert lines[0].startswith("a request failed: Redis cannot be reached (ConnectionError")
    assert "127.0.0.1:16379" in lines[0] and "more since" not in lines[0]
    assert lines[1].startswith("a request failed: Redis did not answer within")
    assert lines[2].endswith("; 599 more since the last such line")


def test_redis_loading_its_data_is_said_so_not_unreachable() -> None:
    # An operator trial: Redis loading its append-only file read "cannot be reached".
    cause = redis_cause(BusyLoadingError("Redis is loading the dataset in memory"))
    assert cause.startswith("Redis is loading its data set into memory (BusyLoadingError)")
