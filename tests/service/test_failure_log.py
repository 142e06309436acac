"""The WARNING for requests Redis failed is throttled per cause (an operator trial:
8,516 identical lines in a 7 s outage, one per failed frame)."""

from __future__ import annotations

import logging

import pytest
from redis.exceptions import (
    AuthenticationError,
    BusyLoadingError,
    OutOfMemoryError,
    ReadOnlyError,
    ResponseError,
)
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


@pytest.mark.parametrize(
    "error",
    [
        OutOfMemoryError("command not allowed when used memory > 'maxmemory'."),
        ReadOnlyError("You can't write against a read only replica."),
        ResponseError("MISCONF Redis is configured to save RDB snapshots, but it is ..."),
    ],
)
def test_redis_refusing_writes_is_not_said_to_be_the_worker_s_credentials(
    error: ResponseError,
) -> None:
    # The refusals Redis answers a commit with for its own state: the hint of a wrong
    # password or database number (an AuthenticationError's) sent operators astray.
    cause = redis_cause(error)
    assert cause.startswith(f"Redis refuses writes ({type(error).__name__}: {error})"), cause
    assert "IK_REDIS_URL" not in cause
    wrong = redis_cause(AuthenticationError("invalid username-password pair"))
    assert "IK_REDIS_URL" in wrong


def test_the_end_of_an_outage_is_one_line_with_the_failures_left_out(
    caplog: pytest.LogCaptureFixture,
) -> None:
    now = [0.0]
    failures = FailureLog(every_s=10.0, clock=lambda: now[0])
    caplog.set_level(logging.INFO, logger="service")
    failures.answered()  # nothing failed: nothing to say
    refused = RedisConnectionError("Error 111 connecting to 127.0.0.1:16379.")
    for k in range(12 * 60):  # 12 s at 60 Hz: a warning at 0 s and at 10 s
        now[0] = 2.0 + k / 60
        failures.failed(refused)
    now[0] = 14.5
    failures.answered()
    failures.answered()  # Redis answering on: said once
    now[0] = 16.0  # a new outage within 10 s of the last warning: said at once
    failures.failed(RedisTimeout("Timeout reading from socket"))
    failures.failed(refused)
    lines = [(r.levelno, r.getMessage()) for r in caplog.records]
    assert [level for level, _ in lines] == [logging.WARNING] * 2 + [logging.INFO] + [
        logging.WARNING
    ] * 2, lines
    # 720 failures: the first (2 s) logged, the 601st (12 s, 10 s on) logged with the
    # 599 between; the 119 after it are the ones the end's line counts.
    assert lines[1][1].endswith("; 599 more since the last such line")
    assert lines[2][1] == (
        "Redis answers again (requests failed for 12.5 s); 119 failed request(s) not "
        "logged since the last warning"
    )
    assert lines[3][1].startswith("a request failed: Redis did not answer within")
    assert lines[4][1].startswith("a request failed: Redis cannot be reached")
    assert "more since" not in lines[4][1]


@pytest.mark.parametrize(
    "error",
    [
        OutOfMemoryError(
            "command not allowed when used memory > 'maxmemory'. script: bf03..., on "
            "@user_script:22."
        ),
        ResponseError("DB index is out of range"),
    ],
)
def test_redis_s_message_is_said_once_per_line(
    caplog: pytest.LogCaptureFixture, error: ResponseError
) -> None:
    # An operator trial at maxmemory: the cause quotes Redis's message, and the line
    # then repeated it in parentheses.
    caplog.set_level(logging.WARNING, logger="service")
    FailureLog().failed(error)
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.count(str(error)) == 1, line
    assert line == f"a request failed: {redis_cause(error)}"
