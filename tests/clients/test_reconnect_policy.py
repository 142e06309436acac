"""ik_client.reconnect without I/O: the deadline, the backoff and its jitter, Retry-After,
and the switches (``Reconnect.OFF``, ``attempts``), on a clock the test moves."""

from __future__ import annotations

import random

import pytest
from ik_client import Reconnect
from ik_client.reconnect import DEFAULT_RECONNECT, Backoff, retry_after_s


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def waits_until_given_up(backoff: Backoff, clock: FakeClock) -> list[float]:
    """Every wait ``backoff`` grants, each slept on the clock, until it gives up."""
    waits = []
    while (wait := backoff.next_wait_s()) is not None:
        waits.append(wait)
        clock.now += wait
        assert len(waits) < 10_000, "never gave up"
    return waits


def test_the_waits_double_up_to_the_cap_and_stop_at_the_deadline() -> None:
    clock = FakeClock()
    policy = Reconnect(deadline_s=10.0, initial_delay_s=0.1, max_delay_s=2.0, jitter=0.0)
    waits = waits_until_given_up(Backoff(policy, clock=clock), clock)
    assert waits[:6] == [0.1, 0.2, 0.4, 0.8, 1.6, 2.0]
    assert set(waits[6:-1]) == {2.0}
    # The last wait is cut to end exactly at the deadline; no try starts after it.
    assert sum(waits) == pytest.approx(10.0, abs=1e-9)
    assert waits[-1] <= 2.0


def test_the_default_budget_outlasts_a_slow_restart_the_old_one_did_not() -> None:
    # The old default: 6 tries, 0.05 s doubling to 2 s, 3.15 s of waits in all.
    old_budget_s = sum(min(0.05 * 2**n, 2.0) for n in range(6))
    assert old_budget_s == pytest.approx(3.15)
    clock = FakeClock()
    backoff = Backoff(DEFAULT_RECONNECT, clock=clock, rng=random.Random(0))
    waits = waits_until_given_up(backoff, clock)
    assert sum(waits) == pytest.approx(DEFAULT_RECONNECT.deadline_s)
    assert DEFAULT_RECONNECT.deadline_s > old_budget_s
    # A server back at any moment is tried again within max_delay_s.
    assert max(waits) <= DEFAULT_RECONNECT.max_delay_s


def test_jitter_takes_up_to_its_share_of_each_wait_and_spreads_the_clients() -> None:
    policy = Reconnect(initial_delay_s=1.0, max_delay_s=1.0, jitter=0.5)
    rng = random.Random(1)
    draws = [policy.delay_s(0, rng=rng) for _ in range(2000)]
    assert min(draws) >= 0.5 and max(draws) <= 1.0
    assert max(draws) - min(draws) > 0.45  # spread over the whole share
    full = Reconnect(initial_delay_s=1.0, max_delay_s=1.0)  # jitter 1: "full jitter"
    draws = [full.delay_s(0, rng=rng) for _ in range(2000)]
    assert min(draws) < 0.05 and max(draws) > 0.95


def test_retry_after_is_honoured_within_the_deadline_and_ends_it_beyond() -> None:
    clock = FakeClock()
    policy = Reconnect(deadline_s=10.0, initial_delay_s=0.1, jitter=0.0)
    backoff = Backoff(policy, clock=clock)
    assert backoff.next_wait_s(retry_after_s=3.0) == 3.0  # longer than max_delay_s: honoured
    clock.now += 3.0
    assert backoff.next_wait_s(retry_after_s=7.5) is None  # past the deadline: give up now


def test_an_answer_gives_the_whole_budget_back() -> None:
    clock = FakeClock()
    backoff = Backoff(Reconnect(deadline_s=5.0, jitter=0.0), clock=clock)
    assert backoff.next_wait_s() == 0.1
    clock.now += 4.0
    assert backoff.recovering
    backoff.answered()
    assert not backoff.recovering
    assert backoff.next_wait_s() == 0.1  # tries counted from 0 again
    clock.now += 4.9
    assert backoff.next_wait_s() == pytest.approx(0.1)
    clock.now += 0.2
    assert backoff.next_wait_s() is None


@pytest.mark.parametrize("policy", [Reconnect.OFF, Reconnect(attempts=0)])
def test_off_never_tries_again(policy: Reconnect) -> None:
    assert not policy.enabled
    assert Backoff(policy, clock=FakeClock()).next_wait_s() is None


def test_attempts_caps_the_tries_too() -> None:
    clock = FakeClock()
    backoff = Backoff(Reconnect(attempts=3, jitter=0.0), clock=clock)
    assert len(waits_until_given_up(backoff, clock)) == 3


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("deadline_s", -1.0),
        ("deadline_s", float("inf")),
        ("initial_delay_s", float("nan")),
        ("max_delay_s", -0.5),
        ("jitter", 1.5),
        ("attempts", -1),
    ],
)
def test_a_bad_policy_is_refused_naming_its_field(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=field):
        Reconnect(**{field: value})


@pytest.mark.parametrize(
    ("header", "seconds"),
    [("1", 1.0), ("2.5", 2.5), (None, None), ("", None), ("soon", None), ("-3", None)],
)
def test_retry_after_header(header: str | None, seconds: float | None) -> None:
    assert retry_after_s(header) == seconds
