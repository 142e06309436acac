"""The 60-second soak (issue #6 item 6): steady WebSocket and HTTP traffic with session
churn against a real `python -m service`; RSS may not grow more than 10% after the
warm-up, and no session, WebSocket or event-loop task may be left behind.
The long run is `python -m loadtest.soak` (10 minutes by default)."""

from __future__ import annotations

import pytest

from loadtest.soak import run, verdict

pytestmark = [pytest.mark.live, pytest.mark.slow]


def test_soak_60_s_no_growth_nothing_left_behind() -> None:
    out = run(
        duration_s=60.0,
        ws_clients=2,
        http_clients=1,
        rate=40.0,
        churn_s=8.0,
        sample_s=5.0,
        warmup_s=20.0,
        log=lambda *_: None,
    )
    assert out["frames"] > 1000
    assert not out["errors"], out["errors"]
    assert out["sessions_created"] >= 6  # churn happened
    assert verdict(out, max_growth=0.10) == [], {k: v for k, v in out.items() if k != "samples"}
