"""What a stream does after a failure, without I/O: which failures a reconnect can
mend (a close 1006, 1011, 1012, 1013; an answer ``shutting_down``, or ``not_ready``
while recovering; a refused handshake that waiting can mend), the wait before each
attempt under the ``Reconnect`` policy (reconnect.py), and the error raised when the
budget is spent or the failure cannot be mended.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

from ..errors import (
    RECONNECTABLE,
    CloseCode,
    ConnectionLost,
    ErrorCode,
    StreamClosed,
    stream_closed,
)
from ..reconnect import Backoff, Reconnect, retry_after_s

# What ends one reconnect attempt and lets the next one start (``Retries.attempt_failed``).
ATTEMPT_FAILURES = (ConnectionClosed, OSError, InvalidHandshake, TimeoutError)
# Handshake refusals a reconnect waits out: a timeout, too many requests, and a server
# or balancer that cannot serve now (502-504: no worker up). Any other status (401, 403,
# 404 from a proxy in front) is the same on every try.
_RETRIED_STATUSES = frozenset({408, 425, 429, 500, 502, 503, 504})


class NotServing(Exception):
    """An error answer that says the server cannot serve the message now, where a new
    connection, after a wait, can: the stream reconnects and sends it again. ``close``
    is what the stream raises if its reconnect budget runs out."""

    def __init__(self, close: StreamClosed, retry_after_s: float | None) -> None:
        super().__init__(str(close))
        self.close = close
        self.retry_after_s = retry_after_s

    @classmethod
    def of(cls, error: dict[str, Any]) -> NotServing:
        """The error answer ``error`` (one of ``_OUTAGE_CODES``) as the close it stands for."""
        code = str(error.get("code"))
        close = (
            CloseCode.SERVICE_RESTART
            if code == ErrorCode.SHUTTING_DOWN
            else CloseCode.TRY_AGAIN_LATER
        )
        wait = error.get("retry_after_s")
        return cls(
            stream_closed(close, code), float(wait) if isinstance(wait, int | float) else None
        )


# Error answers that are part of an outage, not about the message (when reconnecting is
# on): ``shutting_down`` (the message was being solved when the server began to stop; it
# closes 1012 next) always, and ``not_ready`` while recovering from a lost connection (a
# restarted worker listens before its solver is loaded; a stream opened on a warming
# server gets ``not_ready`` as before, as its opening fails at once).
_OUTAGE_CODES = frozenset({ErrorCode.SHUTTING_DOWN.value})
_RECOVERY_CODES = frozenset({ErrorCode.SHUTTING_DOWN.value, ErrorCode.NOT_READY.value})


def open_failed(url: str, exc: Exception) -> ConnectionLost:
    """The first connection could not be opened (nothing listens, the handshake was
    refused, e.g. a balancer's 502, or no answer in ``OPEN_TIMEOUT_S``): a
    ``ConnectionLost`` (1006), so that a caller catches every stream failure as an
    ``IKClientError``; the transport's error is its cause. Not retried: a reconnect
    resends what a connection that was open left unanswered, and nothing was sent yet."""
    lost = ConnectionLost(CloseCode.ABNORMAL)
    lost.args = (f"could not open the WebSocket {url} ({type(exc).__name__}: {exc})",)
    return lost


def _close_of(exc: ConnectionClosed) -> tuple[int, str]:
    """The close code and reason the server sent; 1006 when none came."""
    if exc.rcvd is not None:
        return exc.rcvd.code, exc.rcvd.reason
    return 1006, ""


class Retries:
    """A stream's reconnect budget, without I/O: which closes a reconnect can mend, the
    wait before each attempt (``Backoff`` under the ``Reconnect`` policy: a deadline from
    the first failure since the last answer), and the error raised when none is left."""

    def __init__(self, policy: Reconnect) -> None:
        self.backoff = Backoff(policy)
        self._last: StreamClosed | None = None  # raised when the budget is spent
        self._cause: BaseException | None = None
        self._retry_after_s: float | None = None  # the server's wait before the next try

    @property
    def outage(self) -> frozenset[str]:
        """The error answers that are part of an outage now (none when reconnecting is
        off: the caller sees them as they are)."""
        if not self.backoff.policy.enabled:
            return frozenset()
        return _RECOVERY_CODES if self.backoff.recovering else _OUTAGE_CODES

    def answered(self) -> None:
        self.backoff.answered()

    def closed(self, exc: ConnectionClosed) -> None:
        """Note a close; raise it as a ``StreamClosed`` when reconnecting cannot mend it."""
        code, reason = _close_of(exc)
        if code not in RECONNECTABLE:
            raise stream_closed(code, reason) from exc
        self._lost(stream_closed(code, reason), exc)

    def not_serving(self, exc: NotServing) -> None:
        """Note an answer that the server cannot serve now (``NotServing``)."""
        self._lost(exc.close, exc)
        self._retry_after_s = exc.retry_after_s

    def attempt_failed(self, exc: Exception) -> None:
        """Note a reconnect attempt that failed (one of ``ATTEMPT_FAILURES``): a close is
        noted as by ``closed``; an unreachable server, or a handshake refused with a
        status that waiting can mend (``_RETRIED_STATUSES``: a balancer's 503 while no
        worker is ready), is tried again, no sooner than the refusal's ``Retry-After``;
        any other refusal (a proxy's 401, 403 or 404) ends the stream at once."""
        if isinstance(exc, ConnectionClosed):
            self.closed(exc)
        elif isinstance(exc, InvalidStatus):
            if exc.response.status_code not in _RETRIED_STATUSES:
                assert self._last is not None, "a failure is noted before any attempt"
                raise self._last from exc
            self._retry_after_s = retry_after_s(exc.response.headers.get("Retry-After"))

    def delays(self) -> Iterator[float]:
        """The wait before each reconnect attempt left [s]; then the last close, raised.
        An attempt counts when it starts (a server that accepts and closes again uses
        the budget up)."""
        while (wait := self.backoff.next_wait_s(self._retry_after_s)) is not None:
            self._retry_after_s = None
            yield wait
        assert self._last is not None, "a failure is noted before any attempt"
        raise self._last from self._cause

    def _lost(self, close: StreamClosed, cause: BaseException) -> None:
        self.backoff.failed()
        self._last, self._cause = close, cause
