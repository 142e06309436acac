"""The per-frame path stays cheap (issue #5): no thread hop per HTTP request, and the
WebSocket send limit is one watchdog per connection that only fires on a stuck send."""

from __future__ import annotations

import asyncio
import inspect
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute, APIWebSocketRoute
from starlette.testclient import TestClient
from starlette.websockets import WebSocket, WebSocketDisconnect

from service.config import Settings
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
