"""What handlers share: the per-app ``Services`` (on ``app.state.ik``) and the FastAPI
dependencies that hand it, the caller's API key and the authenticated session to them.

The checks themselves (tokens, keys) are in ``auth.py``.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from starlette.requests import HTTPConnection

from .auth import API_KEY_HEADER, NOT_BEARER, authenticate, check_api_key, unauthorized
from .config import Settings
from .metrics import Metrics
from .session_starts import SessionStarts
from .sessions import Session, SessionStore
from .solving import Runner


@dataclass(slots=True)
class Services:
    """Everything a handler needs, built in the app's lifespan."""

    settings: Settings
    store: SessionStore
    metrics: Metrics
    runner: Runner
    api_keys: tuple[bytes, ...] = ()
    session_starts: SessionStarts | None = None  # per address, when there are no API keys
    open_websockets: int = 0
    ws_in_flight: int = 0  # WebSocket messages received and not yet answered
    draining: bool = False  # set on SIGTERM (python -m service): answer, then close 1012
    # For each WebSocket message still being solved: sends it a shutting_down error
    # (python -m service calls them when IK_GRACEFUL_SHUTDOWN_S is over, before 1012).
    shutdown_replies: set[Callable[[], Awaitable[None]]] = field(default_factory=set)


def services(conn: HTTPConnection) -> Services:
    """The app's ``Services`` (for handlers that hold the connection)."""
    svc: Services = conn.app.state.ik
    return svc


async def services_dep(conn: HTTPConnection) -> Services:
    """Dependency: the app's ``Services``.

    ``async`` on purpose: FastAPI runs a plain ``def`` dependency in its thread pool,
    a hand-off and a wake-up per request that cost more than the whole lookup (py-spy:
    23% of a worker's busy samples under HTTP frames, bench/RESULTS.md).
    """
    return services(conn)


_api_key = APIKeyHeader(
    name=API_KEY_HEADER,
    auto_error=False,
    description="Needed for POST /v1/sessions and /v1/solve when the server has IK_API_KEYS",
)


async def api_key_auth(
    request: Request, key: Annotated[str | None, Depends(_api_key)]
) -> str | None:
    """Dependency: the caller's API key fingerprint (None when keys are off)."""
    return check_api_key(services(request).api_keys, key)


_bearer = HTTPBearer(auto_error=False, description="The session token from POST /v1/sessions")


async def session_auth(
    session_id: str,
    request: Request,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Session:
    """Dependency: the authenticated session of the path's ``session_id``."""
    if credentials is None and "authorization" in request.headers:
        raise unauthorized(NOT_BEARER)  # the header is there, its scheme is not
    token = credentials.credentials if credentials is not None else None
    return await authenticate(services(request).store, session_id, token)


ServicesDep = Annotated[Services, Depends(services_dep)]
SessionDep = Annotated[Session, Depends(session_auth)]
OwnerDep = Annotated[str | None, Depends(api_key_auth)]
