"""Errors the service reports, as exceptions: one class per kind of reaction.

``ServiceError`` is an HTTP error body ``{"detail", "code", "field"}`` or a WebSocket error
answer ``{"code", "message", "field", "retry_after_s"}``; its subclass says what a caller
can do about it (fix the request, fix the token, make a new session, wait). A WebSocket
the server closes raises a ``StreamClosed`` subclass chosen by the close code, whose
``meaning`` is the server's (service/errors.py, WS_CLOSE_CODES).
"""

from __future__ import annotations

import enum
from dataclasses import KW_ONLY, dataclass
from typing import Any, ClassVar

from .codes import ErrorCode as ErrorCode  # re-exported: ik_client.errors.ErrorCode

_ERROR_CODES = frozenset(ErrorCode)


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
    CloseCode.TRY_AGAIN_LATER: "too many open WebSockets, or the session store did not answer; "
    "retry later",
    CloseCode.UNAUTHORIZED: "no token (Authorization: Bearer or ?token=)",
    CloseCode.FORBIDDEN: "wrong token for this session, or a browser Origin not allowed",
    CloseCode.NOT_FOUND: "no such session (never existed, expired or deleted)",
}


class IKClientError(Exception):
    """Base of every error this client raises."""


class EncodeError(IKClientError, ValueError, TypeError):
    """A stream message this client cannot write, raised before anything is sent or
    counted: a NaN or infinity (``field`` names it, e.g. ``targets[0].position.x``; the
    server refuses them and JSON cannot carry them), or a value the encoding cannot write
    (a dataclass, a datetime, a cycle, an int beyond 64 bits; ``field`` None, the
    encoder's error as ``__cause__``). A ``ValueError`` and a ``TypeError`` too, as the
    encoders' errors it replaces were, so that ``except ValueError`` (or ``TypeError``)
    still catches it.

    Attributes:
        field: Where the non-finite number is; None for a value that cannot be written.
    """

    def __init__(self, message: str, *, field: str | None = None) -> None:
        super().__init__(message)
        self.field = field


class NoAnswer(IKClientError):
    """An HTTP call that got no answer: the connection failed or dropped (after the
    resends ``Reconnect`` allows, for a call that is safe to send again), or the client's
    timeout passed (not sent again: the server may still be working on it). The
    transport's error (httpx's) is the ``__cause__``.

    Attributes:
        timed_out: The timeout passed (the server may have acted on the call).
    """

    def __init__(self, message: str, *, timed_out: bool) -> None:
        super().__init__(message)
        self.timed_out = timed_out


class MessageDropped(IKClientError):
    """A stream message dropped before it went out (the TypeScript client's
    ``MessageDropped``): it was sent while the stream was reconnecting, more than
    ``max_queued`` such messages waited for the new connection, and it was the oldest of
    them. The server never saw it; ``receive`` raises this in its turn, in the order sent.

    Attributes:
        id: The id ``send_*`` returned for it.
        max_queued: The stream's limit.
    """

    def __init__(self, id: int, max_queued: float) -> None:
        super().__init__(
            f"message {id} was dropped unsent: more than {max_queued} messages waited for "
            "the stream to reconnect, and it was the oldest"
        )
        self.id = id
        self.max_queued = max_queued


class UnexpectedAnswer(IKClientError):
    """A stream's answer that this client cannot read: an answer to an id that waits
    for none (``id`` None: nothing was taken off the stream's in-flight messages), or an
    answer of a type it does not know (``id``: the message it answers, which counts as
    answered), or an answer that does not decode to an object (not JSON, not
    MessagePack, an array: ``id`` None, ``envelope`` empty, ``data`` the answer as
    received). The stream goes on; ``envelope`` is the message as decoded.

    Attributes:
        id: The caller's id of the message answered; None when no message waited for it.
        envelope: The decoded message (JSON or MessagePack).
        data: The answer as received when it could not be decoded to an object, else None.
    """

    def __init__(
        self,
        message: str,
        *,
        id: int | None,
        envelope: dict[str, Any],
        data: str | bytes | None = None,
    ) -> None:
        super().__init__(message)
        self.id = id
        self.envelope = envelope
        self.data = data


@dataclass(eq=False)  # an exception equals only itself
class ServiceError(IKClientError):
    """An error the service answered with; its subclass says what a caller can do about
    it, and lists the ``codes`` it stands for.

    Attributes:
        code: The stable code (an ``ErrorCode``, or the server's string for a code this
            client does not know).
        message: The server's explanation (HTTP ``detail``; for ``invalid_format`` over
            HTTP, the first validation error's ``msg``).
        field: Path of the offending field, when the server names one: keys dotted,
            list indices in brackets (``frame.targets[0].position.x``).
        retry_after_s: When to try again [s] (HTTP ``Retry-After``, WebSocket
            ``retry_after_s``), for the codes that have it.
        status_code: The HTTP status (None for a WebSocket answer).
        id: The WebSocket message id the error answers (None over HTTP).
        detail: The HTTP body's ``detail`` as sent (a list for ``invalid_format``).
    """

    codes: ClassVar[frozenset[ErrorCode]] = frozenset()

    code: ErrorCode | str
    message: str
    _: KW_ONLY
    field: str | None = None
    retry_after_s: float | None = None
    status_code: int | None = None
    id: int | None = None
    detail: Any = None

    def __post_init__(self) -> None:
        super().__init__(f"{self.code}: {self.message}")


class InvalidRequest(ServiceError):
    """The request is wrong; ``field`` says where."""

    codes = frozenset(
        {
            ErrorCode.INVALID_FORMAT,
            ErrorCode.INVALID_PROBLEM,
            ErrorCode.ID_REUSE,
            ErrorCode.PAYLOAD_TOO_LARGE,
            ErrorCode.METHOD_NOT_ALLOWED,
            ErrorCode.HTTP_ERROR,
        }
    )


class AuthError(ServiceError):
    """No or wrong token or API key, or a browser origin the server does not allow."""

    codes = frozenset({ErrorCode.UNAUTHORIZED, ErrorCode.FORBIDDEN, ErrorCode.FORBIDDEN_ORIGIN})


class NotFound(ServiceError):
    """The session never existed, expired or was deleted."""

    codes = frozenset({ErrorCode.NOT_FOUND})


class RetryLater(ServiceError):
    """Try again (after ``retry_after_s`` when given)."""

    codes = frozenset(
        {
            ErrorCode.TOO_MANY_SESSIONS,
            ErrorCode.KEY_SESSION_LIMIT,
            ErrorCode.RATE_LIMITED,
            ErrorCode.NOT_READY,
            ErrorCode.WARMUP_FAILED,
            ErrorCode.PLANS_BUSY,
            ErrorCode.TOO_MANY_PLANS,
            ErrorCode.SERVER_BUSY,
            ErrorCode.TOO_MUCH_WORK,
            ErrorCode.TOO_MANY_WEBSOCKETS,
            ErrorCode.SHUTTING_DOWN,
            ErrorCode.STORE_UNAVAILABLE,
        }
    )


class ServerFault(ServiceError):
    """The server failed, or it sent a code this client does not know."""

    codes = frozenset({ErrorCode.INTERNAL_ERROR, ErrorCode.SLOW_READER})


_SERVICE_ERRORS = (InvalidRequest, AuthError, NotFound, RetryLater, ServerFault)
_ERROR_CLASSES: dict[str, type[ServiceError]] = {
    code: kind for kind in _SERVICE_ERRORS for code in kind.codes
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

    Its subclasses list the ``close_codes`` they stand for.

    Attributes:
        close_code: The WebSocket close code (1006 when the connection dropped).
        reason: The server's close reason, its error code (e.g. ``not_found``); empty
            when none was sent.
        meaning: What the code means, from the server's table.
        code: The reason as an ``ErrorCode`` when it is one (``SessionGone``:
            ``not_found``, as ``NotFound.code`` over HTTP); None for a close without
            one (1000, 1006, or the WebSocket library's own text).
    """

    close_codes: ClassVar[frozenset[CloseCode]] = frozenset()

    def __init__(self, close_code: int, reason: str = "") -> None:
        self.close_code = close_code
        self.reason = reason
        self.code = ErrorCode(reason) if reason in _ERROR_CODES else None
        self.meaning = CLOSE_CODE_MEANINGS.get(close_code, "unknown close code")
        super().__init__(
            f"WebSocket closed {close_code} ({self.meaning})" + (f": {reason}" if reason else "")
        )


class StreamAuthError(StreamClosed):
    """No token, or the wrong one."""

    close_codes = frozenset({CloseCode.UNAUTHORIZED, CloseCode.FORBIDDEN})


class SessionGone(StreamClosed):
    """The session does not exist (any more); create a new one."""

    close_codes = frozenset({CloseCode.NOT_FOUND})


class MessageTooBig(StreamClosed):
    """A message was larger than the server accepts."""

    close_codes = frozenset({CloseCode.MESSAGE_TOO_BIG})


class SlowReader(StreamClosed):
    """The client did not read its answers in time (or a bad handshake query)."""

    close_codes = frozenset({CloseCode.SLOW_READER})


class ServerRestarting(StreamClosed):
    """The server shut down; raised only when reconnecting did not succeed."""

    close_codes = frozenset({CloseCode.SERVICE_RESTART})


class TooManyWebSockets(StreamClosed):
    """The server holds its maximum of WebSockets; retry later."""

    close_codes = frozenset({CloseCode.TRY_AGAIN_LATER})


class ConnectionLost(StreamClosed):
    """The connection dropped, or the server failed; raised only when reconnecting did
    not succeed. Also what opening a stream raises when no connection can be made (a
    server down or restarting, a refused handshake), the transport's error its cause."""

    close_codes = frozenset({CloseCode.ABNORMAL, CloseCode.INTERNAL_ERROR})


_CLOSE_CLASSES: dict[int, type[StreamClosed]] = {
    code: kind
    for kind in (
        StreamAuthError,
        SessionGone,
        MessageTooBig,
        SlowReader,
        ServerRestarting,
        TooManyWebSockets,
        ConnectionLost,
    )
    for code in kind.close_codes
}

# Closes after which reconnecting and resending can succeed.
RECONNECTABLE: frozenset[int] = frozenset().union(
    *(kind.close_codes for kind in (ServerRestarting, TooManyWebSockets, ConnectionLost))
)


def stream_closed(close_code: int, reason: str = "") -> StreamClosed:
    """The ``StreamClosed`` subclass for ``close_code``."""
    return _CLOSE_CLASSES.get(close_code, StreamClosed)(close_code, reason)
