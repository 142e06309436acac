"""Limits on what a peer controls below the app (issue 23): header size, count and time,
the body's time, connections per address, and the pongs a client that never reads can
make the server buffer.

uvicorn's httptools parser has no header limit (an 8 MiB header was accepted; 20
connections sending 10 MiB of unterminated header held 215 MiB) and no timeout before
the first request (200 slowloris connections and 1,000 idle sockets were all held), and
its websockets-sansio protocol writes every pong whatever its write buffer holds
(75 MiB of pings: +64 MiB RSS). uvicorn's own options cover keep-alive
(``timeout_keep_alive``) and WebSocket pings; the rest is these two protocol
subclasses, passed to ``uvicorn.Config(http=..., ws=...)`` by ``python -m service``.

Sessions created per address per minute (no API keys) are the app's
(``service/session_starts.py``); they see the client a trusted proxy names
(``service/forwarded.py``). The connection count is taken before any header, on the
TCP peer: a trusted proxy is not capped.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import httptools
from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
from uvicorn.protocols.utils import ClientDisconnected
from uvicorn.protocols.websockets.websockets_sansio_impl import WebSocketsSansIOProtocol

from schemas import ErrorCode

from .forwarded import IgnoredForwards, TrustedProxies
from .responses import dumps

if TYPE_CHECKING:
    from uvicorn._types import ASGISendEvent  # uvicorn's own name for the send's argument
    from websockets.frames import Frame

log = logging.getLogger("service")


@dataclass(frozen=True, slots=True)
class PeerLimits:
    max_header_bytes: int
    max_headers: int
    header_timeout_s: float
    body_timeout_s: float
    max_connections_per_address: int
    ws_max_write_buffer_bytes: int
    ws_max_pings_per_s: int
    # Proxies in IK_FORWARDED_ALLOW_IPS: each carries many clients' connections, so
    # the per-address cap does not apply to them (the proxy limits its clients).
    trusted_proxies: TrustedProxies = field(default_factory=TrustedProxies)


@dataclass(slots=True)
class ConnectionCounts:
    """Open connections per client address (HTTP and WebSocket alike)."""

    by_address: dict[str, int] = field(default_factory=dict)

    def add(self, address: str) -> int:
        n = self.by_address.get(address, 0) + 1
        self.by_address[address] = n
        return n

    def remove(self, address: str) -> None:
        n = self.by_address.get(address, 0) - 1
        if n > 0:
            self.by_address[address] = n
        else:
            self.by_address.pop(address, None)


@dataclass(slots=True)
class RefusalLog:
    """Connections refused at accept (over IK_MAX_CONNECTIONS_PER_ADDRESS), logged at
    most once per ``every_s`` with how many there were since the last line."""

    every_s: float = 1.0
    pending: dict[str, int] = field(default_factory=dict)
    last_logged: float = float("-inf")

    def note(self, address: str) -> None:
        self.pending[address] = self.pending.get(address, 0) + 1
        now = time.monotonic()
        if now - self.last_logged >= self.every_s:
            for who, n in self.pending.items():
                log.info("refused %d connection(s) from %s: too many open", n, who)
            self.pending.clear()
            self.last_logged = now


def _address(transport: asyncio.BaseTransport) -> str:
    peer = transport.get_extra_info("peername")
    if isinstance(peer, tuple) and peer:
        return str(peer[0])
    return str(peer)


def _refusal(status: int, reason: bytes, detail: str) -> bytes:
    """A whole HTTP/1.1 response with the service's JSON error body; the connection closes."""
    body = dumps({"detail": detail, "code": ErrorCode.PAYLOAD_TOO_LARGE})
    head = (
        b"HTTP/1.1 %d %s\r\ncontent-type: application/json\r\ncontent-length: %d\r\n"
        b"connection: close\r\n\r\n" % (status, reason, len(body))
    )
    return head + body


class _HeadersTooLarge(Exception):
    pass


def protocols(limits: PeerLimits) -> tuple[type[asyncio.Protocol], type[asyncio.Protocol]]:
    """The HTTP and WebSocket protocol classes for ``uvicorn.Config``, sharing one count
    of connections per address."""
    counts = ConnectionCounts()
    refusals = RefusalLog()
    ignored_forwards = IgnoredForwards()

    class LimitedHttp(HttpToolsProtocol):
        """httptools with a header budget (bytes, count, time) and a body time limit."""

        _address = ""
        _untrusted_forwards = False  # whether an X-Forwarded-For of this peer is ignored
        _refused = False
        _header_bytes = 0
        _header_count = 0
        _in_headers = True
        _timer: asyncio.TimerHandle | None = None
        _upgraded = False

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            self._address = _address(transport)
            trusted = self._address in limits.trusted_proxies
            self._untrusted_forwards = bool(limits.trusted_proxies) and not trusted
            if counts.add(self._address) > limits.max_connections_per_address and not trusted:
                # Refused before uvicorn sets the connection up, and logged once a
                # second: an abuser over the cap reconnecting in a loop made thousands
                # of accepts a second, each a log line and a protocol set-up on the loop.
                self._refused = True
                refusals.note(self._address)
                transport.abort()
                return
            super().connection_made(transport)
            self._expect_headers()

        def connection_lost(self, exc: Exception | None) -> None:
            if self._refused:
                counts.remove(self._address)
                return
            self._cancel_timer()
            if not self._upgraded:
                counts.remove(self._address)
            super().connection_lost(exc)

        def _cancel_timer(self) -> None:
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None

        def _arm(self, seconds: float, why: str) -> None:
            self._cancel_timer()
            self._timer = self.loop.call_later(seconds, self._too_slow, why)

        def _too_slow(self, why: str) -> None:
            self._timer = None
            if not self.transport.is_closing():
                log.info("dropped a connection from %s: %s", self._address, why)
                self.transport.close()

        def _expect_headers(self) -> None:
            self._in_headers = True
            self._header_bytes = 0
            self._header_count = 0
            self._arm(limits.header_timeout_s, "headers not sent within IK_HEADER_TIMEOUT_S")

        def _headers_fit(self, data: bytes) -> bool:
            """Whether the headers stay within IK_MAX_HEADER_BYTES with ``data``: only
            the bytes up to the blank line count (a body may share the read)."""
            end = data.find(b"\r\n\r\n")
            used = len(data) if end == -1 else end + 4
            self._header_bytes += used
            return self._header_bytes <= limits.max_header_bytes

        def data_received(self, data: bytes) -> None:
            # uvicorn's, with the header budget: httptools keeps an unfinished header
            # in memory whatever its size, so the bytes are counted before parsing.
            if self._in_headers and not self._headers_fit(data):
                self._refuse_headers()
                return
            self._unset_keepalive_if_required()
            try:
                self.parser.feed_data(data)
            except httptools.HttpParserUpgrade:
                if self._should_upgrade():
                    self.handle_websocket_upgrade()
                else:
                    self._unsupported_upgrade_warning()
            except httptools.HttpParserError:
                if self._header_count > limits.max_headers:
                    self._refuse_headers()
                    return
                msg = "Invalid HTTP request received."
                self.logger.warning(msg)
                self.send_400_response(msg)

        def _refuse_headers(self) -> None:
            self._cancel_timer()
            detail = (
                f"request headers over {limits.max_header_bytes} bytes or "
                f"{limits.max_headers} fields (IK_MAX_HEADER_BYTES, IK_MAX_HEADERS)"
            )
            if not self.transport.is_closing():
                self.transport.write(_refusal(431, b"Request Header Fields Too Large", detail))
                self.transport.close()

        def on_header(self, name: bytes, value: bytes) -> None:
            self._header_count += 1
            if self._header_count > limits.max_headers:
                raise _HeadersTooLarge  # httptools re-raises it as a parser error
            if self._untrusted_forwards and name.lower() == b"x-forwarded-for":
                ignored_forwards.note(self._address)
            super().on_header(name, value)

        def on_headers_complete(self) -> None:
            self._in_headers = False
            self._arm(limits.body_timeout_s, "body not sent within IK_BODY_TIMEOUT_S")
            super().on_headers_complete()

        def on_message_complete(self) -> None:
            self._cancel_timer()
            super().on_message_complete()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                self._expect_headers()  # the next request on a kept-alive connection

        def handle_websocket_upgrade(self) -> None:
            self._cancel_timer()
            self._upgraded = True  # the WebSocket protocol counts it from now on
            counts.remove(self._address)
            super().handle_websocket_upgrade()

    class LimitedWebSocket(WebSocketsSansIOProtocol):
        """websockets-sansio that drops a client whose unread pongs pass the limit, and
        that lets go of a socket it has closed even when the client never reads.

        uvicorn ends a connection with ``transport.close()``, which waits for the write
        buffer to drain: a client that stopped reading never lets it, so the socket, its
        buffers and its place in the per-address count were held for as long as the
        client kept the connection open. And when uvicorn closes on its own (a keepalive
        ping unanswered) it tells the app nothing: a handler waiting for the next message
        waited for good. Here every close is bounded by uvicorn's ``close_timeout`` (the
        10 s it gives a closing handshake), after which the transport is aborted (the
        app then sees the disconnect), and a send after uvicorn's close is the disconnect
        it is rather than a RuntimeError.
        """

        _address = ""
        _pings = 0
        _pings_since = 0.0
        _abort_timer: asyncio.TimerHandle | None = None

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._address = _address(transport)
            counts.add(self._address)

        def connection_lost(self, exc: Exception | None) -> None:
            if self._abort_timer is not None:
                self._abort_timer.cancel()
                self._abort_timer = None
            counts.remove(self._address)
            super().connection_lost(exc)

        def _abort_if_not_closed_soon(self) -> None:
            """Bound a ``transport.close()`` that waits on a client that does not read."""
            if self._abort_timer is None and not self.disconnected:
                self._abort_timer = self.loop.call_later(self.close_timeout, self._abort)

        def _abort(self) -> None:
            self._abort_timer = None
            if not self.disconnected:
                unsent = self.transport.get_write_buffer_size()
                log.info("aborted a WebSocket from %s: %d bytes unread", self._address, unsent)
                self.transport.abort()

        async def run_asgi(self) -> None:
            await super().run_asgi()
            self._abort_if_not_closed_soon()  # the app is done: the close may wait forever

        def keepalive_timeout(self) -> None:
            super().keepalive_timeout()
            if self.close_sent:
                # uvicorn does not tell the app: without this, a handler waiting for
                # the next message would wait until the transport closed.
                self.queue.put_nowait({"type": "websocket.disconnect", "code": 1011})
                self._abort_if_not_closed_soon()

        def handle_close(self, event: Frame) -> None:
            super().handle_close(event)
            self._abort_if_not_closed_soon()

        async def send(self, message: ASGISendEvent) -> None:
            if self.close_sent and not self.disconnected:
                # uvicorn closed the connection (keepalive, protocol error) under the app:
                # a send meets the disconnect an app expects and a close is done already,
                # rather than uvicorn's RuntimeError ("Unexpected ASGI message").
                if message["type"] == "websocket.send":
                    raise ClientDisconnected()
                if message["type"] == "websocket.close":
                    return
            await super().send(message)

        def handle_ping(self) -> None:
            now = self.loop.time()
            if now - self._pings_since >= 1.0:
                self._pings_since, self._pings = now, 0
            self._pings += 1
            # Each ping is parsed and answered on the loop: a flood of them (thousands
            # per read) held every other client for hundreds of milliseconds.
            flood = self._pings > limits.ws_max_pings_per_s
            if flood or self.transport.get_write_buffer_size() > limits.ws_max_write_buffer_bytes:
                why = "pings too often" if flood else "does not read its pongs"
                log.info("dropped a WebSocket from %s: it %s", self._address, why)
                self.transport.abort()
                return
            super().handle_ping()

    return LimitedHttp, LimitedWebSocket
