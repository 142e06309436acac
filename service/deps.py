"""What handlers share: the per-app ``Services`` (on ``app.state.ik``) and the session
authentication dependency.

Authentication: every call that touches a session needs its token, as
``Authorization: Bearer <token>`` (WebSocket clients that cannot set headers may use
``?token=``). No token -> 401 ``unauthorized``; unknown or expired session -> 404
``not_found``; wrong token -> 403 ``forbidden``.
"""

from __future__ import annotations

import hashlib
import hmac
import time
from dataclasses import dataclass
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import APIKeyHeader, HTTPAuthorizationCredentials, HTTPBearer
from starlette import status
from starlette.requests import HTTPConnection

from .config import Settings
from .errors import ServiceError, not_found
from .metrics import Metrics
from .sessions import Session, SessionStore
from .solving import Runner

T0_KEY = "ik.t0"


@dataclass(slots=True)
class Services:
    """Everything a handler needs, built in the app's lifespan."""

    settings: Settings
    store: SessionStore
    metrics: Metrics
    runner: Runner
    api_keys: tuple[bytes, ...] = ()
    open_websockets: int = 0
    ws_in_flight: int = 0  # WebSocket messages received and not yet answered
    draining: bool = False  # set on SIGTERM (python -m service): answer, then close 1012


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
    svc: Services = conn.app.state.ik
    return svc


def received_at(request: Request) -> float:
    """perf_counter() when the request arrived (set by the timing middleware)."""
    t0 = request.scope.get(T0_KEY)
    return float(t0) if t0 is not None else time.perf_counter()


def unauthorized(
    detail: str = "this call needs the session's token: Authorization: Bearer <token>",
) -> ServiceError:
    return ServiceError("unauthorized", detail, status_code=status.HTTP_401_UNAUTHORIZED)


def forbidden() -> ServiceError:
    return ServiceError(
        "forbidden", "the token does not match this session", status_code=status.HTTP_403_FORBIDDEN
    )


async def authenticate(store: SessionStore, session_id: str, token: str | None) -> Session:
    """The session ``session_id`` if ``token`` opens it.

    Raises:
        ServiceError: unauthorized (no token), not_found, forbidden (wrong token).
    """
    if not token:
        raise unauthorized()
    session = await store.get(session_id)
    if session is None:
        raise not_found()
    if not session.token_ok(token):
        raise forbidden()
    return session


API_KEY_HEADER = "X-API-Key"
_api_key = APIKeyHeader(
    name=API_KEY_HEADER,
    auto_error=False,
    description="Needed for POST /v1/sessions and /v1/solve when the server has IK_API_KEYS",
)


def key_fingerprint(key: bytes) -> str:
    """What a session records about the key that created it (never the key)."""
    return hashlib.sha256(key).hexdigest()[:16]


def check_api_key(keys: tuple[bytes, ...], given: str | None) -> str | None:
    """The fingerprint of ``given`` if it is one of ``keys``; None when keys are off.

    Every configured key is compared (hmac.compare_digest, no early exit), so the time
    taken says nothing about which key or how much of it matched.

    Raises:
        ServiceError: 401 ``unauthorized`` (no key), 403 ``forbidden`` (unknown key).
    """
    if not keys:
        return None
    if not given:
        raise ServiceError(
            "unauthorized",
            f"this server needs an API key: {API_KEY_HEADER}: <key>",
            status_code=status.HTTP_401_UNAUTHORIZED,
        )
    candidate = given.encode("utf-8", "surrogatepass")
    match: bytes | None = None
    for key in keys:
        if hmac.compare_digest(candidate, key):
            match = key
    if match is None:
        raise ServiceError(
            "forbidden", "the API key is not valid", status_code=status.HTTP_403_FORBIDDEN
        )
    return key_fingerprint(match)


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
        raise unauthorized(_NOT_BEARER)  # the header is there, its scheme is not
    token = credentials.credentials if credentials is not None else None
    return await authenticate(services(request).store, session_id, token)


# The commonest first 401: the token sent bare, or as "Token <t>", with no "Bearer ".
_NOT_BEARER = (
    "the Authorization header must be 'Bearer <token>' (the word Bearer, a space, then "
    "the token from POST /v1/sessions)"
)


ServicesDep = Annotated[Services, Depends(services_dep)]
SessionDep = Annotated[Session, Depends(session_auth)]
OwnerDep = Annotated[str | None, Depends(api_key_auth)]
