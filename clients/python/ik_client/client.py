"""``Client`` (blocking) and ``AsyncClient`` (asyncio): the same calls, over httpx.

Every call is written once, in calls.py (its signature, documentation, request and
answer); each client binds them to its transport, so ``Client.frame`` returns what
``AsyncClient.frame`` awaits. Every call returns a typed answer or raises a
``ServiceError`` subclass carrying the server's ``code``, ``field`` and
``retry_after_s``. ``stream()`` opens the session's WebSocket (``Stream`` /
``AsyncStream``).
"""

from __future__ import annotations

import abc
import functools
from collections.abc import Callable, Coroutine
from typing import Any, Concatenate, Generic, ParamSpec, TypeVar

import httpx

from . import calls
from .calls import Call, SessionRef
from .stream import AsyncStream, Reconnect, Stream
from .types import Encoding

T = TypeVar("T")
P = ParamSpec("P")
HTTP = TypeVar("HTTP", httpx.Client, httpx.AsyncClient)
DEFAULT_TIMEOUT_S = 30.0
DEFAULT_RECONNECT = Reconnect()


class _BaseClient(abc.ABC, Generic[HTTP]):
    """What both clients hold: the service's URL and an httpx client (``HTTP``).

    Args:
        base_url: The service, e.g. ``http://127.0.0.1:8000``.
        api_key: Sent as ``X-API-Key`` when the server has API keys (``IK_API_KEYS``).
        timeout_s: Per-request timeout [s].
        **httpx_options: Passed on to the httpx client (e.g. ``transport``, ``verify``).
    """

    def __init__(
        self,
        base_url: str,
        *,
        api_key: str | None = None,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        **httpx_options: Any,
    ) -> None:
        self.base_url = base_url
        headers = {"X-API-Key": api_key} if api_key is not None else {}
        self._http: HTTP = self._http_client(
            base_url=base_url, headers=headers, timeout=timeout_s, **httpx_options
        )

    @abc.abstractmethod
    def _http_client(self, **options: Any) -> HTTP: ...


def _blocking(build: Callable[P, Call[T]]) -> Callable[Concatenate[Client, P], T]:
    """``Client``'s method for the call ``build`` describes: send it, return the answer."""

    @functools.wraps(build)
    def method(self: Client, /, *args: P.args, **kwargs: P.kwargs) -> T:
        call = build(*args, **kwargs)
        response = self._http.request(
            call.method, call.path, json=call.json, params=call.params, headers=call.headers
        )
        return call.result(response)

    return method


def _awaited(
    build: Callable[P, Call[T]],
) -> Callable[Concatenate[AsyncClient, P], Coroutine[Any, Any, T]]:
    """``AsyncClient``'s method for the call ``build`` describes."""

    @functools.wraps(build)
    async def method(self: AsyncClient, /, *args: P.args, **kwargs: P.kwargs) -> T:
        call = build(*args, **kwargs)
        response = await self._http.request(
            call.method, call.path, json=call.json, params=call.params, headers=call.headers
        )
        return call.result(response)

    return method


class Client(_BaseClient[httpx.Client]):
    """The IK service over HTTP, blocking (arguments: ``_BaseClient``)."""

    def _http_client(self, **options: Any) -> httpx.Client:
        return httpx.Client(**options)

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    create_session = _blocking(calls.create_session)
    get_session = _blocking(calls.get_session)
    patch_session = _blocking(calls.patch_session)
    set_pose = _blocking(calls.set_pose)
    delete_session = _blocking(calls.delete_session)
    frame = _blocking(calls.frame)
    clip = _blocking(calls.clip)
    batch = _blocking(calls.batch)
    solve = _blocking(calls.solve)

    def stream(
        self,
        session: SessionRef,
        *,
        encoding: Encoding = Encoding.JSON,
        compact: bool = False,
        reconnect: Reconnect = DEFAULT_RECONNECT,
        timeout_s: float | None = DEFAULT_TIMEOUT_S,
    ) -> Stream:
        """The session's WebSocket; open it with ``with``."""
        url = calls.ws_url(self.base_url, session, compact)
        return Stream(
            url, session.token, encoding=encoding, reconnect=reconnect, timeout_s=timeout_s
        )


class AsyncClient(_BaseClient[httpx.AsyncClient]):
    """The IK service over HTTP, asyncio; the same calls as ``Client``, awaited."""

    def _http_client(self, **options: Any) -> httpx.AsyncClient:
        return httpx.AsyncClient(**options)

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    async def close(self) -> None:
        await self._http.aclose()

    create_session = _awaited(calls.create_session)
    get_session = _awaited(calls.get_session)
    patch_session = _awaited(calls.patch_session)
    set_pose = _awaited(calls.set_pose)
    delete_session = _awaited(calls.delete_session)
    frame = _awaited(calls.frame)
    clip = _awaited(calls.clip)
    batch = _awaited(calls.batch)
    solve = _awaited(calls.solve)

    def stream(
        self,
        session: SessionRef,
        *,
        encoding: Encoding = Encoding.JSON,
        compact: bool = False,
        reconnect: Reconnect = DEFAULT_RECONNECT,
    ) -> AsyncStream:
        """The session's WebSocket; open it with ``async with``."""
        url = calls.ws_url(self.base_url, session, compact)
        return AsyncStream(url, session.token, encoding=encoding, reconnect=reconnect)
