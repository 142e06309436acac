"""Each class of work has threads and bounds of its own (issue 23): a session's pooled
frames cannot hold up chain builds, one request's worst case is capped, and one client
holds at most its share of the pooled frames in flight."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import httpx
import pytest
from starlette.testclient import TestClient

from schemas.chain import EXAMPLE_ARM
from service import solving
from service.config import Settings

from .helpers import create, hand_frame

WAIT_S = 30.0


@pytest.fixture
def stalled_frames(monkeypatch: pytest.MonkeyPatch) -> Iterator[threading.Event]:
    """Pooled frames wait for the event before solving: a long clip, on demand."""
    release = threading.Event()
    started = threading.Semaphore(0)
    real = solving._track_all

    def stalled(*args: Any) -> Any:
        started.release()
        release.wait(WAIT_S)
        return real(*args)

    monkeypatch.setattr(solving, "_track_all", stalled)
    release.started = started  # type: ignore[attr-defined]
    yield release
    release.set()


def _post_frame_in_background(
    pool: ThreadPoolExecutor, client: TestClient, event: threading.Event
) -> Future[httpx.Response]:
    s = create(client)
    fut = pool.submit(
        client.post, f"/v1/sessions/{s.id}/frames", json=hand_frame(1), headers=s.headers
    )
    assert event.started.acquire(timeout=WAIT_S)  # type: ignore[attr-defined]
    return fut


def test_a_session_is_created_while_every_frame_thread_is_busy(
    make_client: Callable[..., TestClient], stalled_frames: threading.Event
) -> None:
    client = make_client(Settings(inline_budget_us=0.0, solver_threads=1))
    with ThreadPoolExecutor(2) as pool:
        busy = _post_frame_in_background(pool, client, stalled_frames)
        created = pool.submit(create, client)
        # The frame still holds the only frame thread; the build does not wait for it.
        assert created.result(timeout=WAIT_S).id
        assert not busy.done()
        stalled_frames.set()
        assert busy.result(timeout=WAIT_S).status_code == 200


def test_one_requests_worst_case_is_capped(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_request_work_s=0.01))
    s = create(client, options={"time_budget_us": 5000})  # 3 frames: 15 ms at worst
    clip = {"frames": [hand_frame(i) for i in range(1, 4)]}
    r = client.post(f"/v1/sessions/{s.id}/frames", json=clip, headers=s.headers)
    assert r.status_code == 422
    assert r.json()["code"] == "invalid_problem" and r.json()["field"] == "frames"
    assert "IK_MAX_REQUEST_WORK_S" in r.json()["detail"]


def test_one_client_holds_at_most_its_share_of_pooled_frames(
    make_client: Callable[..., TestClient], stalled_frames: threading.Event
) -> None:
    # Each frame counts 1 ms (the default budget); the share holds one, not two.
    client = make_client(Settings(inline_budget_us=0.0, max_client_work_s=0.0015))
    with ThreadPoolExecutor(1) as pool:
        busy = _post_frame_in_background(pool, client, stalled_frames)
        other = create(client)  # another session of the same client (address)
        r = client.post(
            f"/v1/sessions/{other.id}/frames", json=hand_frame(1), headers=other.headers
        )
        assert r.status_code == 429 and r.json()["code"] == "too_much_work"
        assert int(r.headers["Retry-After"]) >= 1
        stalled_frames.set()
        assert busy.result(timeout=WAIT_S).status_code == 200
    # Its share given back, the same request is served.
    r = client.post(f"/v1/sessions/{other.id}/frames", json=hand_frame(1), headers=other.headers)
    assert r.status_code == 200


def test_pooled_frames_beyond_the_queue_get_server_busy(
    make_client: Callable[..., TestClient], stalled_frames: threading.Event
) -> None:
    client = make_client(Settings(inline_budget_us=0.0, max_queued_jobs=1))
    with ThreadPoolExecutor(1) as pool:
        busy = _post_frame_in_background(pool, client, stalled_frames)
        other = create(client)
        r = client.post(
            f"/v1/sessions/{other.id}/frames", json=hand_frame(1), headers=other.headers
        )
        assert r.status_code == 503 and r.json()["code"] == "server_busy"
        assert r.headers["Retry-After"] == "1"
        stalled_frames.set()
        assert busy.result(timeout=WAIT_S).status_code == 200


def test_without_api_keys_one_address_creates_a_bounded_number_of_sessions_per_minute(
    make_client: Callable[..., TestClient],
) -> None:
    client = make_client(Settings(sessions_per_address_per_min=3))
    for _ in range(3):
        create(client)
    r = client.post("/v1/sessions", json={"chain": {"format": "example", "name": "panda_arm"}})
    assert r.status_code == 429 and r.json()["code"] == "rate_limited"
    assert 1 <= int(r.headers["Retry-After"]) <= 20  # one session's worth: 20 s at 3/min
    assert "IK_SESSIONS_PER_ADDRESS_PER_MIN" in r.json()["detail"]


def test_with_api_keys_the_per_key_cap_applies_instead(
    make_client: Callable[..., TestClient],
) -> None:
    client = make_client(Settings(sessions_per_address_per_min=1, api_keys="k1"))
    for _ in range(3):
        r = client.post("/v1/sessions", json={"chain": EXAMPLE_ARM}, headers={"X-API-Key": "k1"})
        assert r.status_code == 201, r.text
