"""The per-frame path stays cheap (issue #5): no thread hop per HTTP request, the
WebSocket send limit is one watchdog per connection that only fires on a stuck send,
and frame metrics are plain numbers exported at scrape time."""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute, APIWebSocketRoute
from prometheus_client import CollectorRegistry, Histogram
from starlette.testclient import TestClient
from starlette.websockets import WebSocket, WebSocketDisconnect

from service.config import Settings
from service.metrics import DURATION_BUCKETS_S, Metrics
from service.routes import health, http, ws

from .helpers import create, hand_frame


def _calls(dependant: Dependant) -> Iterator[Any]:
    for d in dependant.dependencies:
        if d.call is not None:
            yield d.call
        yield from _calls(d)


def _is_async(call: Any) -> bool:
    return inspect.iscoroutinefunction(call) or inspect.iscoroutinefunction(
        getattr(call, "__call__", None)  # noqa: B004 (security schemes are callables)
    )


def test_no_route_runs_a_dependency_in_the_thread_pool() -> None:
    """FastAPI runs a plain ``def`` dependency (or endpoint) in its thread pool: a
    hand-off and a wake-up per request."""
    seen = 0
    for route in (*http.router.routes, *ws.router.routes, *health.router.routes):
        assert isinstance(route, APIRoute | APIWebSocketRoute)
        assert _is_async(route.endpoint), route.path
        for call in _calls(route.dependant):
            seen += 1
            assert _is_async(call), (route.path, call)
    assert seen > 10  # the walk did reach the dependencies


def test_ws_slow_sends_under_the_limit_are_not_dropped(
    make_client: Callable[..., TestClient], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each send takes 0.1 s, the limit is 0.25 s: six answers (0.6 s in all) arrive;
    the watchdog measures each send, not the connection's age."""
    client = make_client(Settings(ws_send_timeout_s=0.25))
    s = create(client)
    real_send_text = WebSocket.send_text

    async def slow(self: WebSocket, data: str) -> None:
        await asyncio.sleep(0.1)
        await real_send_text(self, data)

    monkeypatch.setattr(WebSocket, "send_text", slow)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        for i in range(3):
            ws.send_json({"type": "ping", "id": 2 * i})
            assert ws.receive_json() == {"id": 2 * i, "type": "pong"}
            ws.send_json({"type": "frame", "id": 2 * i + 1, **hand_frame(None)})
            assert ws.receive_json()["id"] == 2 * i + 1


def test_ws_stuck_send_after_quiet_time_is_dropped(
    make_client: Callable[..., TestClient], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A send that gets stuck after the connection was idle longer than the limit is
    still dropped within about one limit (the watchdog re-arms from the send's start)."""
    client = make_client(Settings(ws_send_timeout_s=0.2))
    s = create(client)
    real_send_text = WebSocket.send_text
    stuck = False

    async def maybe_blocked(self: WebSocket, data: str) -> None:
        if stuck:
            await asyncio.sleep(3600)
        await real_send_text(self, data)

    monkeypatch.setattr(WebSocket, "send_text", maybe_blocked)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "ping", "id": 1})
        assert ws.receive_json()["type"] == "pong"
        ws.send_json({"type": "ping", "id": 2})  # answered: a fresh send each time
        assert ws.receive_json()["type"] == "pong"
        time.sleep(0.5)  # the connection idles for over twice the limit
        stuck = True
        t0 = time.monotonic()
        ws.send_json({"type": "ping", "id": 3})
        with pytest.raises(WebSocketDisconnect) as info:
            ws.receive_json()
        waited = time.monotonic() - t0
    assert info.value.code == 1008
    assert 0.15 <= waited < 2.0, waited


# -- metrics without a lock per increment ------------------------------------------------
def test_frame_histograms_match_prometheus_client(rng: np.random.Generator) -> None:
    """The hand-kept histograms expose the same buckets, count and sum as
    prometheus_client's Histogram fed the same values (bucket bounds included)."""
    values = [*rng.exponential(1e-3, size=300), *DURATION_BUCKETS_S, 0.0, 10.0]
    reference = CollectorRegistry()
    h = Histogram("ik_solve_duration_seconds", "x", buckets=DURATION_BUCKETS_S, registry=reference)
    ours = Metrics(lambda: 0)
    for v in values:
        h.observe(v)
        ours.series.solve.observe(v)

    def samples(registry: CollectorRegistry) -> dict[tuple[str, str], float]:
        return {
            (s.name, s.labels.get("le", "")): s.value
            for m in registry.collect()
            if m.name == "ik_solve_duration_seconds"
            for s in m.samples
            if not s.name.endswith("_created")
        }

    expected = samples(reference)
    got = samples(ours.registry)
    assert got.keys() == expected.keys()
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, rel=1e-12, abs=0.0), key


def test_pooled_clip_frames_are_counted(make_client: Callable[..., TestClient]) -> None:
    """Frames solved in the pool reach the metrics (handed to the loop's thread)."""
    client = make_client(Settings(inline_budget_us=0))
    s = create(client)
    clip = {"frames": [{"id": i, **hand_frame(None)} for i in range(3)]}
    r = client.post(f"/v1/sessions/{s.id}/frames", json=clip, headers=s.headers)
    assert r.status_code == 200 and len(r.json()["results"]) == 3
    text = client.get("/metrics").text
    assert 'ik_server_duration_seconds_count{transport="http"} 3.0' in text
    assert 'ik_frames_total{success="true",termination="goal_reached"} 3.0' in text
