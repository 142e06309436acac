"""Who may do what: session tokens, API keys and the WebSocket's Origin.

Every call that touches a session needs its token, as ``Authorization: Bearer <token>``
(WebSocket clients that cannot set headers may send it as an ``ik.token.<token>``
subprotocol or ``?token=``). When the server has API keys (IK_API_KEYS), creating a
session or a one-shot solve needs ``X-API-Key``.

Codes owned here: ``unauthorized`` (401 / close 4401: no token or key), ``forbidden``
(403 / close 4403: wrong token or key, or an Origin not in IK_CORS_ORIGINS),
``not_found`` (404 / close 4404: no such session).

The FastAPI dependencies that call these are in ``dependencies.py``.
"""

from __future__ import annotations

import hashlib
import hmac
from urllib.parse import urlsplit

from starlette import status
from starlette.websockets import WebSocket

from schemas import ErrorCode

from .errors import ServiceError, not_found
from .sessions import Session, SessionStore

API_KEY_HEADER = "X-API-Key"
SUBPROTOCOL = "ik.v1"
TOKEN_SUBPROTOCOL_PREFIX = "ik.token."

# The commonest first 401: the token sent bare, or as "Token <t>", with no "Bearer ".
NOT_BEARER = (
    "the Authorization header must be 'Bearer <token>' (the word Bearer, a space, then "
    "the token from POST /v1/sessions)"
)


def unauthorized(
    detail: str = "this call needs the session's token: Authorization: Bearer <token>",
) -> ServiceError:
    return ServiceError(ErrorCode.UNAUTHORIZED, detail, status_code=status.HTTP_401_UNAUTHORIZED)


def forbidden(detail: str = "the token does not match this session") -> ServiceError:
    return ServiceError(ErrorCode.FORBIDDEN, detail, status_code=status.HTTP_403_FORBIDDEN)


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
        raise unauthorized(f"this server needs an API key: {API_KEY_HEADER}: <key>")
    candidate = given.encode("utf-8", "surrogatepass")
    match: bytes | None = None
    for key in keys:
        if hmac.compare_digest(candidate, key):
            match = key
    if match is None:
        raise forbidden("the API key is not valid")
    return key_fingerprint(match)


def websocket_token(ws: WebSocket) -> str | None:
    """The session token of a WebSocket handshake: ``Authorization: Bearer``, else a
    ``ik.token.<token>`` subprotocol (browsers can set subprotocols, not headers), else
    ``?token=``."""
    auth = ws.headers.get("authorization")
    if auth is not None:
        scheme, _, value = auth.partition(" ")
        if scheme.lower() == "bearer" and value.strip():
            return value.strip()
    for proto in ws.scope.get("subprotocols", ()):
        if proto.startswith(TOKEN_SUBPROTOCOL_PREFIX) and len(proto) > len(
            TOKEN_SUBPROTOCOL_PREFIX
        ):
            return str(proto[len(TOKEN_SUBPROTOCOL_PREFIX) :])
    return ws.query_params.get("token")


def websocket_subprotocol(ws: WebSocket) -> str | None:
    """Echo ``ik.v1`` when offered (browsers fail a handshake that offered subprotocols
    and got none back); never echo the token."""
    return SUBPROTOCOL if SUBPROTOCOL in ws.scope.get("subprotocols", ()) else None


def origin_allowed(ws: WebSocket, allowed: list[str]) -> bool:
    """Browsers send Origin; other clients usually do not. A browser may open a WebSocket
    from a configured origin (IK_CORS_ORIGINS) or from a page of the service itself
    (/demo): its Origin names the host the socket connects to. That adds nothing a
    same-origin page could not already do over HTTP; a page of another site has its own
    host in Origin and is refused."""
    origin = ws.headers.get("origin")
    if origin is None or origin in allowed or "*" in allowed:
        return True
    parts = urlsplit(origin)
    return parts.scheme in ("http", "https") and parts.netloc == ws.headers.get("host")
