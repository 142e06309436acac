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
from typing import Any

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware

import schemas as S
from solver.ik import IKOptions, IKSolver

from . import convert
from .auth import API_KEY_HEADER
from .config import Settings, get_settings
from .dependencies import Services
from .errors import install_handlers
from .metrics import Metrics
from .middleware import TimingAndLimits
from .responses import ORJSONResponse
from .routes import health, http, ws
from .routes.demo import add_demo
from .routes.docs import add_docs
from .session_starts import SessionStarts
from .sessions import InMemorySessionStore, SessionStore
from .solving import Runner, Warmup, WarmupFn, default_warmup, make_solver
from .work import WorkClass

log = logging.getLogger("service")

DESCRIPTION = """\
Inverse kinematics over HTTP and WebSocket: create a **session** for a chain (a glTF or
BVH character's skeleton, URDF text as robots ship it, joints as JSON, or a built-in
example), then send **frames** of targets (a position, an orientation and/or an aim per
effector, with optional blend weights and pole targets); each frame is warm-started from
the previous answer, and can answer with bone rotations to apply. `POST /v1/solve` is a
stateless one-shot; `POST /v1/batch` carries one frame each for several sessions.

Conventions: metres, radians, microseconds (`_us`), in the chain's own axes (Z up for
URDF and JSON chains, Y up for glTF and BVH) unless the session names its engine's
(`conventions`: Unity, Unreal, Godot, glTF, three.js, ROS, or up axis, handedness and
centimetres: target positions and directions in, bone rotations and positions out).
Joint values, tolerances and errors (`position_error_m`) stay in the chain's own units
and frame under any `conventions`. Quaternions are objects `{w, x, y, z}`; finite
numbers only; unknown fields are rejected. Errors are `{"detail", "code"}`. Session
calls need `Authorization: Bearer <token>` (the token comes back from `POST
/v1/sessions`; a batch entry carries its session's). When the server has API keys, `POST
/v1/sessions` and `POST /v1/solve` need `X-API-Key: <key>`. The WebSocket protocol
(`/v1/sessions/{id}/ws`) is described as AsyncAPI 3 at `/asyncapi.json`, and in
docs/websocket.md in the repository. A live demo is at `/demo`.
"""


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
        # The store is built after the runner (a shared one builds models on its threads).
        metrics = Metrics(lambda: len(app.state.ik.store))
        warm = Warmup(warmup or default_warmup(settings.compile_processes))
        runner = Runner(settings, metrics=metrics, warmup=warm)
        sessions = store
        if sessions is None:  # (not `store or ...`: an empty store is falsy)
            sessions = default_store(settings, runner, metrics)
        app.state.ik = Services(
            settings=settings,
            store=sessions,
            metrics=metrics,
            runner=runner,
            api_keys=settings.api_key_list(),
            session_starts=SessionStarts(settings.sessions_per_address_per_min, time.monotonic),
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
            await sessions.close()

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
    add_demo(app)
    install_handlers(app)
    app.include_router(http.router)
    app.include_router(ws.router)
    app.include_router(health.router)
    # Added before CORS, so CORS wraps it: a 413 it answers early carries the CORS
    # headers too (a browser shows a CORS failure instead of a 413 otherwise).
    app.add_middleware(TimingAndLimits, max_body_bytes=settings.max_body_bytes)
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


def default_store(settings: Settings, runner: Runner, metrics: Metrics) -> SessionStore:
    """Redis when IK_REDIS_URL is set (sessions shared by every worker), else memory."""
    url = settings.redis_url.get_secret_value()
    if not url:
        # Said at every start: behind a balancer, a worker that keeps its sessions in
        # its own memory breaks routing (an operator checks this line).
        log.info("sessions in this process's memory (IK_REDIS_URL is not set)")
        return InMemorySessionStore(
            max_sessions=settings.max_sessions,
            ttl_s=settings.session_ttl_s,
            max_per_owner=settings.max_sessions_per_key,
        )

    async def build_view(definition: bytes) -> convert.ChainView:
        spec = S.SessionCreate.model_validate_json(definition)
        return await runner.run(
            WorkClass.BUILD,
            convert.chain_from_spec,
            spec.chain,
            settings,
            spec.conventions,
            spec.bones,
        )

    async def build_solver(view: convert.ChainView, options: IKOptions) -> IKSolver:
        return await runner.run(WorkClass.BUILD, make_solver, view, options)

    def load_options(stored: dict[str, Any]) -> IKOptions:
        patch = S.OptionsPatch.model_validate(stored)
        return convert.apply_options(patch, convert.session_defaults(settings), settings)

    # Imported here: redis-py is the optional extra `redis`, needed only with a URL.
    from .redis_commit import connect, where
    from .redis_store import RedisSessionStore

    client = connect(url, settings.redis_timeout_s)
    # Where, and which database (never the URL: it may hold a password): workers behind
    # one balancer must all say the same.
    db = client.connection_pool.connection_kwargs.get("db", 0)
    log.info("sessions in Redis at %s, database %s (IK_REDIS_URL)", where(client), db)
    return RedisSessionStore(
        client,
        max_sessions=settings.max_sessions,
        ttl_s=settings.session_ttl_s,
        max_per_owner=settings.max_sessions_per_key,
        build_view=build_view,
        build_solver=build_solver,
        load_options=load_options,
        dump_options=convert.options_dict,
        write_behind_s=settings.redis_write_behind_ms / 1000,
        observe_commit=metrics.watch_commits(),
    )


async def _sweep(store: SessionStore, metrics: Metrics, interval_s: float) -> None:
    """Expire idle sessions every ``interval_s``."""
    while True:
        await asyncio.sleep(interval_s)
        gone = await store.expire()
        if gone:
            metrics.sessions_expired.inc(len(gone))
            log.info("expired %d idle session(s)", len(gone))
