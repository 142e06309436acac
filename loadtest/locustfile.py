"""Locust scenarios for the IK service: game clients over HTTP and over WebSocket.

Each simulated user opens a session on one of the shipped example chains (in turn:
panda_arm, humanoid_arm, tail) and sends one frame of a smooth path per tick at 60 Hz
(``constant_pacing``), waiting for each answer before the next (one frame in flight).

    pip install -e '.[loadtest]'
    locust -f loadtest/locustfile.py --host http://127.0.0.1:8000 \\
        --headless --users 20 --spawn-rate 10 --run-time 30s [HttpGameClient|WebSocketGameClient]

Locust rounds response times to whole milliseconds in its tables and its FastHttpUser
saturates one core near 10k requests/s, so use it for scenarios (mixes, ramps, its web
UI); the capacity figures in bench/RESULTS.md come from ``python -m loadtest``.
WebSocket frames are reported as request type ``WS``; an ``error`` answer, an answer to
another frame or a closed socket counts as a failure.
"""

from __future__ import annotations

import itertools
import time
from typing import Any
from urllib.parse import urlsplit

import orjson
import websocket  # websocket-client: a dependency of locust, cooperative under gevent
from locust import FastHttpUser, User, constant_pacing, task

from loadtest.clients import create_session_sticky
from loadtest.paths import DEFAULT_CHAINS, Path, make_path

RATE_HZ = 60.0
_next_user = itertools.count()
_paths: dict[str, Path] = {}


def _path_for(n: int) -> Path:
    chain = DEFAULT_CHAINS[n % len(DEFAULT_CHAINS)]
    if chain not in _paths:
        _paths[chain] = make_path(chain, RATE_HZ)
    return _paths[chain]


class HttpGameClient(FastHttpUser):
    """POST /v1/sessions/{id}/frames, one frame per tick."""

    wait_time = constant_pacing(1.0 / RATE_HZ)

    def on_start(self) -> None:
        n = next(_next_user)
        self.path = _path_for(n)
        self.k = n * 37  # users start at different points of the path
        body = {"chain": {"format": "example", "name": self.path.chain}}
        with self.client.post("/v1/sessions", json=body, catch_response=True) as r:
            if r.status_code != 201:
                r.failure(f"create session: HTTP {r.status_code}")
                self.stop()
                return
            created = r.json()
        self.frames_url = f"/v1/sessions/{created['id']}/frames"
        self.headers = {
            "Authorization": f"Bearer {created['token']}",
            "content-type": "application/json",
        }
        self.session_url = f"/v1/sessions/{created['id']}"

    @task
    def frame(self) -> None:
        targets = self.path.targets[self.k % len(self.path.targets)]
        body = f'{{"id":{self.k},"targets":{targets.decode()}}}'
        with self.client.post(
            self.frames_url,
            data=body,
            headers=self.headers,
            name="/v1/sessions/[id]/frames",
            catch_response=True,
        ) as r:
            if r.status_code != 200:
                r.failure(f"HTTP {r.status_code}")
            elif r.json()["results"][0]["id"] != self.k:
                r.failure("answer to another frame")
        self.k += 1

    def on_stop(self) -> None:
        if hasattr(self, "session_url"):
            self.client.delete(self.session_url, headers=self.headers, name="/v1/sessions/[id]")


class WebSocketGameClient(User):
    """Frames over /v1/sessions/{id}/ws, one per tick, each answer awaited."""

    wait_time = constant_pacing(1.0 / RATE_HZ)

    def on_start(self) -> None:
        n = next(_next_user)
        self.path = _path_for(n)
        self.k = n * 37
        parts = urlsplit(self.host or "http://127.0.0.1:8000")
        host, port = parts.hostname or "127.0.0.1", parts.port or 80
        body = orjson.dumps({"chain": {"format": "example", "name": self.path.chain}})
        t = time.perf_counter()
        try:
            # The socket that created the session carries the WebSocket, so both reach the
            # same worker process (see loadtest.serve).
            sock, created, _ = create_session_sticky(host, port, body, 30.0)
            self.ws = websocket.create_connection(
                f"ws://{host}:{port}/v1/sessions/{created['id']}/ws",
                header=[f"Authorization: Bearer {created['token']}"],
                socket=sock,
                timeout=30.0,
                suppress_origin=True,  # not a browser; the service refuses unknown origins
            )
        except Exception as e:
            self._fire("connect", t, 0, e)
            self.stop()
            return
        self._fire("connect", t, 0, None)

    def _fire(self, name: str, t0: float, length: int, exc: BaseException | None) -> None:
        self.environment.events.request.fire(
            request_type="WS",
            name=name,
            response_time=(time.perf_counter() - t0) * 1e3,
            response_length=length,
            exception=exc,
            context={},
        )

    @task
    def frame(self) -> None:
        targets = self.path.targets[self.k % len(self.path.targets)].decode()
        msg = f'{{"type":"frame","id":{self.k},"targets":{targets}}}'
        t = time.perf_counter()
        exc: BaseException | None = None
        length = 0
        try:
            self.ws.send(msg)
            raw = self.ws.recv()
            length = len(raw)
            reply: dict[str, Any] = orjson.loads(raw)
            if "error" in reply:
                exc = RuntimeError(f"error answer: {reply['error'].get('code')}")
            elif reply.get("id") != self.k:
                exc = RuntimeError("answer to another frame")
        except Exception as e:  # a closed socket ends this user
            exc = e
            self._fire("frame", t, length, exc)
            self.stop()
            return
        self._fire("frame", t, length, exc)
        self.k += 1

    def on_stop(self) -> None:
        ws = getattr(self, "ws", None)
        if ws is not None:
            ws.close()
