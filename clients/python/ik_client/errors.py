"""Errors the service reports, as exceptions: one class per kind of reaction.

``ServiceError`` is an HTTP error body ``{"detail", "code", "field"}`` or a WebSocket error
answer ``{"code", "message", "field", "retry_after_s"}``; its subclass says what a caller
can do about it (fix the request, fix the token, make a new session, wait). A WebSocket
the server closes raises a ``StreamClosed`` subclass chosen by the close code, whose
``meaning`` is the server's (service/errors.py, WS_CLOSE_CODES).
"""

from __future__ import annotations

import enum
from typing import Any


class ErrorCode(enum.StrEnum):
    """The service's stable error codes (docs/api.md and docs/websocket.md, Errors)."""

    INVALID_FORMAT = "invalid_format"
    INVALID_PROBLEM = "invalid_problem"
    ID_REUSE = "id_reuse"
    UNAUTHORIZED = "unauthorized"
    FORBIDDEN = "forbidden"
    FORBIDDEN_ORIGIN = "forbidden_origin"
    NOT_FOUND = "not_found"
    METHOD_NOT_ALLOWED = "method_not_allowed"
    HTTP_ERROR = "http_error"
    PAYLOAD_TOO_LARGE = "payload_too_large"
    TOO_MANY_SESSIONS = "too_many_sessions"
    KEY_SESSION_LIMIT = "key_session_limit"
    RATE_LIMITED = "rate_limited"
    NOT_READY = "not_ready"
    WARMUP_FAILED = "warmup_failed"
    PLANS_BUSY = "plans_busy"
    TOO_MANY_PLANS = "too_many_plans"
    SERVER_BUSY = "server_busy"
    TOO_MUCH_WORK = "too_much_work"
    # Reasons of WebSocket closes (a close's reason is its error code).
    TOO_MANY_WEBSOCKETS = "too_many_websockets"
    SLOW_READER = "slow_reader"
    SHUTTING_DOWN = "shutting_down"
    STORE_UNAVAILABLE = "store_unavailable"
    INTERNAL_ERROR = "internal_error"


class CloseCode(enum.IntEnum):
    """The close codes of the service's WebSocket (docs/websocket.md, Close codes)."""

    NORMAL = 1000
    ABNORMAL = 1006  # no close frame: the connection dropped (never sent by the server)
    SLOW_READER = 1008
    MESSAGE_TOO_BIG = 1009
    INTERNAL_ERROR = 1011
    SERVICE_RESTART = 1012
    TRY_AGAIN_LATER = 1013
    UNAUTHORIZED = 4401
    FORBIDDEN = 4403
    NOT_FOUND = 4404


# The server's explanations (service/errors.py, WS_CLOSE_CODES), plus 1006.
CLOSE_CODE_MEANINGS: dict[int, str] = {
    CloseCode.NORMAL: "normal closure",
    CloseCode.ABNORMAL: "the connection dropped without a close frame",
    CloseCode.SLOW_READER: "the client did not read its answers (IK_WS_SEND_TIMEOUT_S), "
    "or the handshake's query was invalid",
    CloseCode.MESSAGE_TOO_BIG: "message larger than IK_WS_MAX_MESSAGE_BYTES",
    CloseCode.INTERNAL_ERROR: "unexpected server error (logged)",
    CloseCode.SERVICE_RESTART: "the server is shutting down; reconnect",
    CloseCode.TRY_AGAIN_LATER: "too many open WebSockets; retry later",
    CloseCode.UNAUTHORIZED: "no token (Authorization: Bearer or ?token=)",
    CloseCode.FORBIDDEN: "wrong token for this session, or a browser Origin not allowed",
    CloseCode.NOT_FOUND: "no such session (never existed, expired or deleted)",
}


class IKClientError(Exception):
    """Base of every error this client raises."""


class ServiceError(IKClientError):
    """An error the service answered with.

    Attributes:
        code: The stable code (an ``ErrorCode``, or the server's string for a code this
            client does not know).
        message: The server's explanation (HTTP ``detail``; for ``invalid_format`` over
            HTTP, the first validation error's ``msg``).
        field: Dotted path of the offending field, when the server names one.
        retry_after_s: When to try again [s] (HTTP ``Retry-After``, WebSocket
            ``retry_after_s``), for the codes that have it.
        status_code: The HTTP status (None for a WebSocket answer).
        id: The WebSocket message id the error answers (None over HTTP).
        detail: The HTTP body's ``detail`` as sent (a list for ``invalid_format``).
    """

    def __init__(
        self,
        code: ErrorCode | str,
        message: str,
        *,
        field: str | None = None,
        retry_after_s: float | None = None,
        status_code: int | None = None,
        id: int | None = None,
        detail: Any = None,
    ) -> None:
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message
        self.field = field
        self.retry_after_s = retry_after_s
        self.status_code = status_code
        self.id = id
        self.detail = detail


class InvalidRequest(ServiceError):
    """invalid_format, invalid_problem, id_reuse, payload_too_large, method_not_allowed,
    http_error: the request is wrong; ``field`` says where."""


class AuthError(ServiceError):
    """unauthorized, forbidden, forbidden_origin: no or wrong token or API key, or a
    browser origin the server does not allow."""


class NotFound(ServiceError):
    """not_found: the session never existed, expired or was deleted."""


class RetryLater(ServiceError):
    """rate_limited, not_ready, plans_busy, too_many_plans, too_many_sessions,
    key_session_limit, warmup_failed, too_many_websockets, shutting_down,
    store_unavailable: try again
    (after ``retry_after_s`` when given)."""


class ServerFault(ServiceError):
    """internal_error, slow_reader, or a code this client does not know."""


_ERROR_CLASSES: dict[str, type[ServiceError]] = {
    ErrorCode.INVALID_FORMAT: InvalidRequest,
    ErrorCode.INVALID_PROBLEM: InvalidRequest,
    ErrorCode.ID_REUSE: InvalidRequest,
    ErrorCode.PAYLOAD_TOO_LARGE: InvalidRequest,
    ErrorCode.METHOD_NOT_ALLOWED: InvalidRequest,
    ErrorCode.HTTP_ERROR: InvalidRequest,
    ErrorCode.UNAUTHORIZED: AuthError,
    ErrorCode.FORBIDDEN: AuthError,
    ErrorCode.FORBIDDEN_ORIGIN: AuthError,
    ErrorCode.NOT_FOUND: NotFound,
    ErrorCode.TOO_MANY_SESSIONS: RetryLater,
    ErrorCode.KEY_SESSION_LIMIT: RetryLater,
    ErrorCode.RATE_LIMITED: RetryLater,
    ErrorCode.NOT_READY: RetryLater,
    ErrorCode.WARMUP_FAILED: RetryLater,
    ErrorCode.PLANS_BUSY: RetryLater,
    ErrorCode.TOO_MANY_PLANS: RetryLater,
    ErrorCode.SERVER_BUSY: RetryLater,
    ErrorCode.TOO_MUCH_WORK: RetryLater,
    ErrorCode.TOO_MANY_WEBSOCKETS: RetryLater,
    ErrorCode.SHUTTING_DOWN: RetryLater,
    ErrorCode.STORE_UNAVAILABLE: RetryLater,
}


def _code(value: Any) -> ErrorCode | str:
    try:
        return ErrorCode(value)
    except ValueError:
        return str(value)


def service_error(code: Any, message: str, **kw: Any) -> ServiceError:
    """The ``ServiceError`` subclass for ``code``."""
    parsed = _code(code)
    return _ERROR_CLASSES.get(parsed, ServerFault)(parsed, message, **kw)


class StreamClosed(IKClientError):
    """The WebSocket closed and the stream cannot go on (a reconnect cannot help, or the
    bounded reconnect attempts ran out).

    Attributes:
        close_code: The WebSocket close code (1006 when the connection dropped).
        reason: The server's close reason, its error code (e.g. ``not_found``); empty
            when none was sent.
        meaning: What the code means, from the server's table.
    """

    def __init__(self, close_code: int, reason: str = "") -> None:
        self.close_code = close_code
        self.reason = reason
        self.meaning = CLOSE_CODE_MEANINGS.get(close_code, "unknown close code")
        super().__init__(
            f"WebSocket closed {close_code} ({self.meaning})" + (f": {reason}" if reason else "")
        )


class StreamAuthError(StreamClosed):
    """4401 / 4403: no token, or the wrong one."""


class SessionGone(StreamClosed):
    """4404: the session does not exist (any more); create a new one."""


class MessageTooBig(StreamClosed):
    """1009: a message was larger than the server accepts."""


class SlowReader(StreamClosed):
    """1008: the client did not read its answers in time (or a bad handshake query)."""


class ServerRestarting(StreamClosed):
    """1012: the server shut down; raised only when reconnecting did not succeed."""


class TooManyWebSockets(StreamClosed):
    """1013: the server holds its maximum of WebSockets; retry later."""


class ConnectionLost(StreamClosed):
    """1006 or 1011: the connection dropped, or the server failed; raised only when
    reconnecting did not succeed."""


_CLOSE_CLASSES: dict[int, type[StreamClosed]] = {
    CloseCode.UNAUTHORIZED: StreamAuthError,
    CloseCode.FORBIDDEN: StreamAuthError,
    CloseCode.NOT_FOUND: SessionGone,
    CloseCode.MESSAGE_TOO_BIG: MessageTooBig,
    CloseCode.SLOW_READER: SlowReader,
    CloseCode.SERVICE_RESTART: ServerRestarting,
    CloseCode.TRY_AGAIN_LATER: TooManyWebSockets,
    CloseCode.ABNORMAL: ConnectionLost,
    CloseCode.INTERNAL_ERROR: ConnectionLost,
}

# Closes after which reconnecting and resending can succeed.
RECONNECTABLE = frozenset(
    {
        CloseCode.ABNORMAL,
        CloseCode.INTERNAL_ERROR,
        CloseCode.SERVICE_RESTART,
        CloseCode.TRY_AGAIN_LATER,
    }
)


def stream_closed(close_code: int, reason: str = "") -> StreamClosed:
    """The ``StreamClosed`` subclass for ``close_code``."""
    return _CLOSE_CLASSES.get(close_code, StreamClosed)(close_code, reason)
