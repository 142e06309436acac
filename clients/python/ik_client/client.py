"""``Client`` (blocking) and ``AsyncClient`` (asyncio): the same calls, over httpx.

Every call is written once, in calls.py (its signature, documentation, request and
answer), and listed once, in ``_BaseClient``; each client only sends (``_send``: httpx's
blocking or asyncio transport), so ``Client.frame`` returns what ``AsyncClient.frame``
awaits. Every call returns a typed answer or raises a ``ServiceError`` subclass carrying
the server's ``code``, ``field`` and ``retry_after_s``, or ``NoAnswer`` when no answer
came (the connection failed, or the timeout passed). A call that got no answer (the
connection failed or dropped, not a timeout; or a balancer's or the server's 502 or 503)
is sent again, as first encoded, when it is repeatable (``calls.Call``: reads, a pose
or options set, a stateless solve, a frame with an id), as the client's ``reconnect``
says (reconnect.py: backoff with jitter until a deadline from the call's first
failure), no sooner than a ``Retry-After`` and not at all when that would end after the
deadline. ``stream()`` opens the session's WebSocket (``Stream`` / ``AsyncStream``;
its own ``reconnect`` argument).
"""

from __future__ import annotations

import abc
import asyncio
import functools
import socket
import time
from collections.abc import Callable, Coroutine
from typing import Any, Generic, ParamSpec, TypeVar, overload

import httpx

from . import calls
from .calls import Call, SessionRef
from .errors import NoAnswer
from .queued import DEFAULT_MAX_QUEUED
from .reconnect import DEFAULT_RECONNECT, Backoff, Reconnect, retry_after_s
from .stream import PING_INTERVAL_S, PING_TIMEOUT_S, AsyncStream, Stream
from .types import Encoding

T = TypeVar("T")
P = ParamSpec("P")
HTTP = TypeVar("HTTP", httpx.Client, httpx.AsyncClient)
S = TypeVar("S", Stream, AsyncStream)
DEFAULT_TIMEOUT_S = 30.0
# What a balancer answers for a worker it cannot reach, and the server for a store or
# solver it cannot reach yet: the call itself was not answered. (Not 504: the worker may
# still be solving it.)
_NO_ANSWER_STATUSES = frozenset({502, 503})
# The connection failed before the call was answered, and not because it took too long
# (a timeout may leave the server solving it: sent again, a server without a shared
# store would solve it twice).
# NetworkError: ConnectError, ReadError, WriteError, CloseError.
_NO_ANSWER_ERRORS = (httpx.NetworkError, httpx.ConnectTimeout, httpx.RemoteProtocolError)


def _no_answer(call: Call[Any], error: httpx.TransportError) -> NoAnswer:
    """The ``NoAnswer`` a transport error comes to (``timed_out`` only where the call
    may have reached the server)."""
    # Connect and pool timeouts: nothing was sent; a read or write timeout: maybe acted on.
    timed_out = isinstance(error, httpx.TimeoutException) and not isinstance(
        error, (httpx.ConnectTimeout, httpx.PoolTimeout)
    )
    what = "timed out" if timed_out else f"the connection failed: {error}"
    return NoAnswer(f"{call.method} {call.path}: no answer ({what})", timed_out=timed_out)


class _Endpoint(Generic[P, T]):
    """A client method for the call ``build`` describes (calls.py): on a ``Client`` it
    sends the call and returns the answer; on an ``AsyncClient`` it is a coroutine
    function that does the same, awaited. Its name, docstring and parameters are
    ``build``'s."""

    def __init__(self, build: Callable[P, Call[T]]) -> None:
        self.build = build
        self.__doc__ = build.__doc__
        self.__wrapped__ = build  # help() and inspect.signature show the call's parameters

    @overload
    def __get__(self, client: None, owner: type) -> _Endpoint[P, T]: ...
    @overload
    def __get__(self, client: Client, owner: type) -> Callable[P, T]: ...
    @overload
    def __get__(self, client: AsyncClient, owner: type) -> Callable[P, Coroutine[Any, Any, T]]: ...
    def __get__(self, client: Client | AsyncClient | None, owner: type) -> Any:
        if client is None:
            return self
        build = self.build
        if isinstance(client, AsyncClient):

            async def awaited(*args: P.args, **kwargs: P.kwargs) -> T:
                return await client._send(build(*args, **kwargs))

            return functools.wraps(build)(awaited)

        def blocking(*args: P.args, **kwargs: P.kwargs) -> T:
            return client._send(build(*args, **kwargs))

        return functools.wraps(build)(blocking)


class _BaseClient(abc.ABC, Generic[HTTP, S]):
    """What both clients hold: the service's URL and an httpx client (``HTTP``), and how
    they open a session's WebSocket (``S``: ``Stream`` or ``AsyncStream``).

    Args:
        base_url: The service, e.g. ``http://127.0.0.1:8000``.
        api_key: Sent as ``X-API-Key`` when the server has API keys (``IK_API_KEYS``).
        timeout_s: Per-request timeout [s].
        reconnect: How long and how often a repeatable HTTP call that got no answer
            is sent again (default: for up to 30 s; ``Reconnect.OFF``: never, the
            error is raised at once). ``timeout_s`` bounds each attempt. A stream's
            reconnects are ``stream()``'s own argument.
        **httpx_options: Passed on to the httpx client (e.g. ``transport``, ``verify``).
    """

    _stream_type: type[S]

    def __init__(
        self,
        base_url: str,
        *,
        api_key: str | None = None,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        reconnect: Reconnect = DEFAULT_RECONNECT,
        **httpx_options: Any,
    ) -> None:
        self.base_url = base_url
        self.reconnect = reconnect
        headers = {"X-API-Key": api_key} if api_key is not None else {}
        self._http: HTTP = self._http_client(
            base_url=base_url, headers=headers, timeout=timeout_s, **httpx_options
        )

    @abc.abstractmethod
    def _http_client(self, **options: Any) -> HTTP: ...

    def _wait_before_resending(
        self, call: Call[Any], backoff: Backoff, response: httpx.Response | None
    ) -> float | None:
        """Seconds to wait before sending ``call`` again after a send that got
        ``response`` (None: the connection failed), or None: do not send it again (not
        repeatable, answered, or ``backoff``'s deadline spent or shorter than the
        answer's ``Retry-After``: the caller decides)."""
        if not call.repeatable:
            return None
        if response is None:
            return backoff.next_wait_s()
        if response.status_code not in _NO_ANSWER_STATUSES:
            return None
        return backoff.next_wait_s(retry_after_s(response.headers.get("Retry-After")))

    create_session = _Endpoint(calls.create_session)
    get_session = _Endpoint(calls.get_session)
    patch_session = _Endpoint(calls.patch_session)
    set_pose = _Endpoint(calls.set_pose)
    delete_session = _Endpoint(calls.delete_session)
    frame = _Endpoint(calls.frame)
    clip = _Endpoint(calls.clip)
    batch = _Endpoint(calls.batch)
    solve = _Endpoint(calls.solve)
    fk = _Endpoint(calls.fk)

    def stream(
        self,
        session: SessionRef,
        *,
        encoding: Encoding = Encoding.JSON,
        compact: bool = False,
        reconnect: Reconnect = DEFAULT_RECONNECT,
        timeout_s: float | None = DEFAULT_TIMEOUT_S,
        deflate: bool = True,
        sock: socket.socket | None = None,
        ping_interval_s: float | None = PING_INTERVAL_S,
        ping_timeout_s: float | None = PING_TIMEOUT_S,
        max_queued: float = DEFAULT_MAX_QUEUED,
    ) -> S:
        """The session's WebSocket; open it with ``with`` (``Stream``) or ``async with``
        (``AsyncStream``). The server accepts the handshake and then closes a socket
        whose token or session is wrong (4401, 4403, 4404): the first message raises it
        (``StreamAuthError``, ``SessionGone``), not the opening; ``stream.ping()``
        checks at once. An opening that cannot connect at all (the server down or
        restarting, a balancer refusing the upgrade) raises ``ConnectionLost`` at once,
        not retried.

        Args:
            session: The session (or anything with ``id`` and ``token``).
            encoding: JSON text or MessagePack binary messages.
            compact: Compact frame results (``?results=compact``).
            reconnect: How long and how often to reconnect after a drop (default:
                for up to 30 s from the drop, each new drop since an answer with the
                whole budget); ``Reconnect.OFF`` raises the drop as a ``StreamClosed``
                instead.
            timeout_s: Bounds each wait for an answer [s]; None waits for ever.
            deflate: Offer permessage-deflate (False: messages go uncompressed, which
                costs less CPU at both ends for frames of a few hundred bytes).
            sock: An open TCP connection to the server for the first handshake, e.g.
                the keep-alive connection that created the session, so the WebSocket
                reaches the worker holding it; reconnects open new connections.
            ping_interval_s: Period of websockets' keepalive pings [s] (its default,
                20); None sends none (a load client: they would add to what it measures).
            ping_timeout_s: How long a ping may wait for its pong before the connection
                counts as dropped [s] (its default, 20); None waits for ever.
            max_queued: How many messages other tasks send to an ``AsyncStream`` while
                it reconnects may wait for the new connection (``DEFAULT_MAX_QUEUED``,
                60; ``math.inf``: all); one more drops the oldest of them unsent
                (``receive`` raises ``MessageDropped`` in its turn). Messages sent
                before the drop are sent again and answered, whatever this is. The
                blocking ``Stream`` never holds any: its sends wait for the reconnect.
        """
        url = calls.ws_url(self.base_url, session, compact)
        return self._stream_type(
            url,
            session.token,
            encoding=encoding,
            reconnect=reconnect,
            timeout_s=timeout_s,
            deflate=deflate,
            sock=sock,
            ping_interval_s=ping_interval_s,
            ping_timeout_s=ping_timeout_s,
            max_queued=max_queued,
        )


class Client(_BaseClient[httpx.Client, Stream]):
    """The IK service over HTTP, blocking (arguments: ``_BaseClient``)."""

    _stream_type = Stream

    def _http_client(self, **options: Any) -> httpx.Client:
        return httpx.Client(**options)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _send(self, call: Call[T]) -> T:
        backoff = Backoff(self.reconnect)  # this call's own clock, from its first failure
        request = call.request(self._http)  # encoded once: sent again as first sent
        while True:
            try:
                response = self._http.send(request)
            except _NO_ANSWER_ERRORS as e:
                wait = self._wait_before_resending(call, backoff, None)
                if wait is None:
                    raise _no_answer(call, e) from e
            except httpx.TimeoutException as e:  # not sent again: it may be under way
                raise _no_answer(call, e) from e
            else:
                wait = self._wait_before_resending(call, backoff, response)
                if wait is None:
                    return call.result(response)
            time.sleep(wait)


class AsyncClient(_BaseClient[httpx.AsyncClient, AsyncStream]):
    """The IK service over HTTP, asyncio; the same calls as ``Client``, awaited."""

    _stream_type = AsyncStream

    def _http_client(self, **options: Any) -> httpx.AsyncClient:
        return httpx.AsyncClient(**options)

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    async def close(self) -> None:
        await self._http.aclose()

    async def _send(self, call: Call[T]) -> T:
        backoff = Backoff(self.reconnect)  # this call's own clock, from its first failure
        request = call.request(self._http)  # encoded once: sent again as first sent
        while True:
            try:
                response = await self._http.send(request)
            except _NO_ANSWER_ERRORS as e:
                wait = self._wait_before_resending(call, backoff, None)
                if wait is None:
                    raise _no_answer(call, e) from e
            except httpx.TimeoutException as e:  # not sent again: it may be under way
                raise _no_answer(call, e) from e
            else:
                wait = self._wait_before_resending(call, backoff, response)
                if wait is None:
                    return call.result(response)
            await asyncio.sleep(wait)
