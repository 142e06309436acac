"""Pure ASGI middleware: stamps each request's arrival time and refuses bodies over
IK_MAX_BODY_BYTES with 413 ``payload_too_large`` before the app reads them.

Pure ASGI rather than ``BaseHTTPMiddleware`` (starlette's docs): it adds no task or
stream per request and does not buffer the body.
"""

from __future__ import annotations

import asyncio
import time

from starlette import status
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from schemas import ErrorCode

from .responses import dumps

# The scope key holding perf_counter() at arrival (``received_at``).
T0_KEY = "ik.t0"


def received_at(request: Request) -> float:
    """perf_counter() when the request arrived (set by ``TimingAndLimits``)."""
    t0 = request.scope.get(T0_KEY)
    return float(t0) if t0 is not None else time.perf_counter()


class TimingAndLimits:
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
        refused = False

        async def limited_receive() -> Message:
            nonlocal seen, refused
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    # A chunked body (no Content-Length) is over the limit only once
                    # read: answer 413 here. The app turns the exception below into a
                    # 422 of its own ("error parsing the body"), which is dropped.
                    if not started and not refused:
                        refused = True
                        await _too_large(send, limit)
                    raise _BodyTooLarge
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if refused:
                return
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except _BodyTooLarge:
            if not started and not refused:
                await _too_large(send, limit)
        except asyncio.CancelledError:
            # uvicorn cancels what is still running when IK_GRACEFUL_SHUTDOWN_S is over,
            # and answers a cancelled request with a plain-text 500 of its own: answer
            # first, with what a client can act on (another replica, or a retry).
            if not started and not refused:
                await _error(
                    send,
                    status.HTTP_503_SERVICE_UNAVAILABLE,
                    ErrorCode.SHUTTING_DOWN,
                    "the server is shutting down; retry (another replica, or this one "
                    "once restarted)",
                    [(b"retry-after", b"1")],
                )
            raise


class _BodyTooLarge(Exception):
    pass


async def _too_large(send: Send, limit: int) -> None:
    detail = f"body larger than {limit} bytes (IK_MAX_BODY_BYTES)"
    await _error(send, status.HTTP_413_CONTENT_TOO_LARGE, ErrorCode.PAYLOAD_TOO_LARGE, detail)


async def _error(
    send: Send,
    status_code: int,
    code: ErrorCode,
    detail: str,
    headers: list[tuple[bytes, bytes]] | None = None,
) -> None:
    """A whole JSON error response, as ``errors.ServiceError`` renders one."""
    body = dumps({"detail": detail, "code": code})
    await send(
        {
            "type": "http.response.start",
            "status": status_code,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                *(headers or []),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})
