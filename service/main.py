"""``create_app(settings) -> FastAPI``: the app factory; stores live on ``app.state``.

``uvicorn --factory service.main:create_app`` and ``python -m service`` use it; nothing
is built at import time.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware
from starlette import status
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from .config import Settings, get_settings
from .deps import API_KEY_HEADER, T0_KEY, Services
from .errors import install_handlers
from .metrics import Metrics
from .responses import ORJSONResponse, dumps
from .routes import health, http, ws
from .routes.docs import add_docs
from .sessions import InMemorySessionStore, SessionStore
from .solving import Runner, Warmup, WarmupFn, default_warmup

log = logging.getLogger("service")

DESCRIPTION = """\
Inverse kinematics over HTTP and WebSocket: create a **session** for a chain (joints as
JSON, URDF text, or a built-in example), then send **frames** of targets; each frame is
warm-started from the previous answer. `POST /v1/solve` is a stateless one-shot.

Conventions: metres, radians, microseconds (`_us`); quaternions are objects
`{w, x, y, z}`; finite numbers only; unknown fields are rejected. Errors are
`{"detail", "code"}`. Session calls need `Authorization: Bearer <token>` (the token
comes back from `POST /v1/sessions`). When the server has API keys, `POST /v1/sessions`
and `POST /v1/solve` need `X-API-Key: <key>`. The WebSocket protocol
(`/v1/sessions/{id}/ws`) is described in docs/websocket.md in the repository.
"""


class _TimingAndLimits:
    """Pure ASGI middleware: stamps arrival time; rejects HTTP bodies over the limit (413)."""

    def __init__(self, app: ASGIApp, max_body_bytes: int) -> None:
        self.app = app
        self.max_body_bytes = max_body_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        scope[T0_KEY] = time.perf_counter()
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.max_body_bytes
        for name, value in scope["headers"]:
            if name == b"content-length":
                try:
                    too_big = int(value) > limit
                except ValueError:
                    too_big = False
                if too_big:
                    await _too_large(send, limit)
                    return
        seen = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise _BodyTooLarge
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except _BodyTooLarge:
            if not started:
                await _too_large(send, limit)


class _BodyTooLarge(Exception):
    pass


async def _too_large(send: Send, limit: int) -> None:
    body = dumps(
        {
            "detail": f"body larger than {limit} bytes (IK_MAX_BODY_BYTES)",
            "code": "payload_too_large",
        }
    )
    await send(
        {
            "type": "http.response.start",
            "status": status.HTTP_413_CONTENT_TOO_LARGE,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


def create_app(
    settings: Settings | None = None,
    *,
    warmup: WarmupFn | None = None,
    store: SessionStore | None = None,
) -> FastAPI:
    """Build the app.

    Args:
        settings: Configuration; default ``get_settings()`` (the environment).
        warmup: Loads the compiled solver, passing its progress to the callable it
            gets (/readyz shows it); /readyz is 503 until it returns. Default:
            ``default_warmup(settings.compile_processes)``.
        store: Session store; default an ``InMemorySessionStore`` from the settings.
    """
    settings = settings or get_settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        sessions = store
        if sessions is None:  # (not `store or ...`: an empty store is falsy)
            sessions = InMemorySessionStore(
                max_sessions=settings.max_sessions,
                ttl_s=settings.session_ttl_s,
                max_per_owner=settings.max_sessions_per_key,
            )
        metrics = Metrics(lambda: len(sessions))
        warm = Warmup(warmup or default_warmup(settings.compile_processes))
        runner = Runner(
            inline_budget_us=settings.inline_budget_us,
            threads=settings.solver_threads,
            metrics=metrics,
            warmup=warm,
            max_frames_per_s=settings.max_frames_per_s,
            max_frames_per_request=settings.max_frames_per_request,
            max_queued_plans=settings.max_queued_plans,
        )
        app.state.ik = Services(
            settings=settings,
            store=sessions,
            metrics=metrics,
            runner=runner,
            api_keys=settings.api_key_list(),
        )
        warm.start()
        sweeper = asyncio.create_task(_sweep(sessions, metrics, settings.sweep_interval_s))
        try:
            yield
        finally:
            sweeper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sweeper
            runner.shutdown()

    app = FastAPI(
        title="IK service",
        version="0.1.0",
        description=DESCRIPTION,
        lifespan=lifespan,
        default_response_class=ORJSONResponse,
        # FastAPI's own pages load their assets from CDNs; add_docs serves them locally.
        docs_url=None,
        redoc_url=None,
    )
    add_docs(app)
    install_handlers(app)
    app.include_router(http.router)
    app.include_router(ws.router)
    app.include_router(health.router)
    # Added before CORS, so CORS wraps it: a 413 it answers early carries the CORS
    # headers too (a browser shows a CORS failure instead of a 413 otherwise).
    app.add_middleware(_TimingAndLimits, max_body_bytes=settings.max_body_bytes)
    origins = settings.cors_origin_list()
    if origins:  # closed by default: no CORS headers at all
        app.add_middleware(
            CORSMiddleware,
            allow_origins=origins,
            allow_methods=["GET", "POST", "PUT", "PATCH", "DELETE"],
            allow_headers=["Authorization", "Content-Type", API_KEY_HEADER],
            expose_headers=["Location", "Retry-After"],
            max_age=600,
        )
    return app


async def _sweep(store: SessionStore, metrics: Metrics, interval_s: float) -> None:
    """Expire idle sessions every ``interval_s``."""
    while True:
        await asyncio.sleep(interval_s)
        gone = await store.expire()
        if gone:
            metrics.sessions_expired.inc(len(gone))
            log.info("expired %d idle session(s)", len(gone))
