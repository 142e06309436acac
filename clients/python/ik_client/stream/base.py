"""What both streams hold (``BaseStream``): the URL and token, the pipeline, the
reconnect budget, the current websockets connection and its options.
"""

from __future__ import annotations

import socket
from typing import Any, Generic, TypeVar

from websockets.asyncio.client import ClientConnection as AsyncConnection
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection as SyncConnection

from ..errors import IKClientError
from ..queued import DEFAULT_MAX_QUEUED, SendQueue, max_queued_option
from ..reconnect import Reconnect
from ..types import Answer, Encoding
from .pipeline import Pipeline
from .recovery import NotServing, Retries

# Answers of long clips of big chains can be large; the server bounds what it sends.
MAX_ANSWER_BYTES = 64 * 2**20
OPEN_TIMEOUT_S = 30.0
# websockets' own keepalive defaults: a ping every 20 s, the connection dropped (1011)
# when its pong takes longer than 20 s.
PING_INTERVAL_S = 20.0
PING_TIMEOUT_S = 20.0


Connection = TypeVar("Connection", SyncConnection, AsyncConnection)


class BaseStream(Generic[Connection]):
    """What both streams hold: the URL and token, the pipeline, the reconnect budget and
    the current websockets connection (``Connection``, threading or asyncio).

    ``deflate`` offers permessage-deflate (websockets' default); frames of a few hundred
    bytes gain little from it and it costs CPU at both ends. ``sock``, an open TCP
    connection to the server, carries the first connection's handshake (e.g. the
    keep-alive connection that created the session, so that the WebSocket reaches the
    worker process holding it); a reconnect opens a new connection. ``ping_interval_s``
    and ``ping_timeout_s`` are websockets' keepalive (None: no pings, or no wait for
    their pong): a client that reads answers all the time learns of a dead connection
    from its reads, and a load client's pings would only add traffic to what it measures.
    """

    def __init__(
        self,
        url: str,
        token: str,
        *,
        encoding: Encoding,
        reconnect: Reconnect,
        timeout_s: float | None = 30.0,
        deflate: bool = True,
        sock: socket.socket | None = None,
        ping_interval_s: float | None = PING_INTERVAL_S,
        ping_timeout_s: float | None = PING_TIMEOUT_S,
        max_queued: float = DEFAULT_MAX_QUEUED,
    ) -> None:
        self.url = url
        self.reconnects = 0  # connections made after the first
        self.timeout_s = timeout_s
        self._pipeline = Pipeline(encoding)
        self._retries = Retries(reconnect)
        self.max_queued = max_queued_option(max_queued)
        # While an asyncio stream reconnects: what is sent meanwhile (None otherwise).
        self._held: SendQueue[int] | None = None
        self._connection: Connection | None = None
        # close() was called: an asyncio stream's reconnect under way in another task
        # stops rather than open a connection nobody would close.
        self._closed = False
        self._sock = sock  # taken by the first _open()
        self._connect_options: dict[str, Any] = {
            "additional_headers": {"Authorization": f"Bearer {token}"},
            "open_timeout": OPEN_TIMEOUT_S,
            "max_size": MAX_ANSWER_BYTES,
            "ping_interval": ping_interval_s,
            "ping_timeout": ping_timeout_s,
        }
        if not deflate:
            self._connect_options["compression"] = None

    def _take_sock(self) -> dict[str, Any]:
        """``sock=`` for the first connection only: a socket carries one handshake."""
        sock, self._sock = self._sock, None
        return {} if sock is None else {"sock": sock}

    @property
    def connection(self) -> Connection:
        """The current websockets connection (a test drops it: ``transport.abort()``
        for asyncio's, ``socket.shutdown`` for the threading one)."""
        if self._connection is None:
            raise IKClientError("the stream is not open")
        return self._connection

    @property
    def in_flight(self) -> int:
        """Messages sent that have no answer yet."""
        return self._pipeline.in_flight

    @property
    def reconnecting(self) -> bool:
        """A task is reconnecting this (asyncio) stream: a send now waits for the new
        connection (at most ``max_queued`` of them); a game can skip its sends meanwhile
        rather than have stale targets solved."""
        return self._held is not None

    @property
    def queued(self) -> int:
        """Of those, the ones sent while reconnecting, waiting for the new connection
        (at most ``max_queued``; always 0 for the blocking ``Stream``)."""
        return 0 if self._held is None else len(self._held)

    def _answer(self, data: str | bytes) -> Answer:
        """The answer ``data`` carries (``Pipeline.answer``); any answer but one that
        is part of the outage (``NotServing``) gives the reconnect budget back."""
        serving = True
        try:
            return self._pipeline.answer(data, outage=self._retries.outage)
        except NotServing:
            serving = False
            raise
        finally:
            if serving:  # error answers included: the server answered
                self._retries.answered()

    def _note_failure(self, exc: ConnectionClosed | NotServing) -> None:
        """Count ``exc`` against the reconnect budget, or raise it when reconnecting
        cannot mend it (``Retries``)."""
        if isinstance(exc, NotServing):
            self._retries.not_serving(exc)
        else:
            self._retries.closed(exc)

    def _reconnected(self, connection: Connection) -> None:
        self._connection = connection
        self.reconnects += 1
