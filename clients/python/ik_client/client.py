"""``Client`` (blocking) and ``AsyncClient`` (asyncio): the same calls, over httpx.

Every call returns a typed answer or raises a ``ServiceError`` subclass carrying the
server's ``code``, ``field`` and ``retry_after_s``. ``stream()`` opens the session's
WebSocket (``Stream`` / ``AsyncStream``).
"""

from __future__ import annotations

from typing import Any, TypeVar

import httpx

from . import calls
from .calls import Call, SessionRef
from .stream import AsyncStream, Reconnect, Stream
from .types import (
    BatchEntryResult,
    BatchFrame,
    BoneOutput,
    Chain,
    ClipResult,
    Conventions,
    Encoding,
    Frame,
    FrameResult,
    Pose,
    PoseIn,
    Session,
    SessionInfo,
    SolverOptionsPatch,
    Target,
)

T = TypeVar("T")
DEFAULT_TIMEOUT_S = 30.0
DEFAULT_RECONNECT = Reconnect()


def _headers(api_key: str | None) -> dict[str, str]:
    return {"X-API-Key": api_key} if api_key is not None else {}


class Client:
    """The IK service over HTTP, blocking.

    Args:
        base_url: The service, e.g. ``http://127.0.0.1:8000``.
        api_key: Sent as ``X-API-Key`` when the server has API keys (``IK_API_KEYS``).
        timeout_s: Per-request timeout [s].
        **httpx_options: Passed on to ``httpx.Client`` (e.g. ``transport``, ``verify``).
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
        self._http = httpx.Client(
            base_url=base_url, headers=_headers(api_key), timeout=timeout_s, **httpx_options
        )

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _do(self, call: Call[T]) -> T:
        response = self._http.request(
            call.method, call.path, json=call.json, params=call.params, headers=call.headers
        )
        return call.result(response)

    def create_session(
        self,
        chain: Chain,
        *,
        options: SolverOptionsPatch | None = None,
        initial_pose: PoseIn | None = None,
        conventions: Conventions | None = None,
        bones: BoneOutput | None = None,
    ) -> Session:
        """A new session on ``chain`` (e.g. ``{"format": "example", "name": "panda_arm"}``),
        speaking ``conventions`` (e.g. ``{"preset": "unity"}``), answering with ``bones``."""
        return self._do(calls.create_session(chain, options, initial_pose, conventions, bones))

    def get_session(self, session: SessionRef) -> SessionInfo:
        return self._do(calls.get_session(session))

    def patch_session(self, session: SessionRef, options: SolverOptionsPatch) -> SessionInfo:
        """Change solver options; the options left out keep their value."""
        return self._do(calls.patch_session(session, options))

    def set_pose(
        self,
        session: SessionRef,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
    ) -> Pose:
        """Set the pose the next frame starts from: every DOF (``q``) or some by name."""
        return self._do(calls.set_pose(session, calls.pose_in(q, joints)))

    def delete_session(self, session: SessionRef) -> None:
        self._do(calls.delete_session(session))

    def frame(
        self,
        session: SessionRef,
        targets: list[Target],
        *,
        id: int | None = None,
        compact: bool = False,
    ) -> FrameResult:
        """Solve one frame from the session's pose (``compact``: no joints by name and no
        per-effector errors)."""
        return self._do(calls.frame(session, targets, id, compact))

    def clip(
        self,
        session: SessionRef,
        frames: list[Frame],
        *,
        plan: bool = False,
        compact: bool = False,
    ) -> ClipResult:
        """Solve frames in order, each from the previous answer, or with ``plan`` as a
        whole (the smoothest joint path; the answer's ``plan`` says how smooth)."""
        return self._do(calls.clip(session, frames, plan, compact))

    def batch(self, frames: list[BatchFrame], *, compact: bool = False) -> list[BatchEntryResult]:
        """One frame for each of several sessions (a game server's characters) in one
        request; one answer per entry, in order, each a result or its own error (an
        entry's error is not raised: the other entries were solved)."""
        return self._do(calls.batch(frames, compact))

    def solve(
        self,
        chain: Chain,
        targets: list[Target],
        *,
        seed: PoseIn | None = None,
        options: SolverOptionsPatch | None = None,
        id: int | None = None,
    ) -> FrameResult:
        """A stateless one-shot solve (no session)."""
        return self._do(calls.solve(chain, targets, seed, options, id))

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


class AsyncClient:
    """The IK service over HTTP, asyncio; the same calls as ``Client``, awaited."""

    def __init__(
        self,
        base_url: str,
        *,
        api_key: str | None = None,
        timeout_s: float = DEFAULT_TIMEOUT_S,
        **httpx_options: Any,
    ) -> None:
        self.base_url = base_url
        self._http = httpx.AsyncClient(
            base_url=base_url, headers=_headers(api_key), timeout=timeout_s, **httpx_options
        )

    async def __aenter__(self) -> AsyncClient:
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    async def close(self) -> None:
        await self._http.aclose()

    async def _do(self, call: Call[T]) -> T:
        response = await self._http.request(
            call.method, call.path, json=call.json, params=call.params, headers=call.headers
        )
        return call.result(response)

    async def create_session(
        self,
        chain: Chain,
        *,
        options: SolverOptionsPatch | None = None,
        initial_pose: PoseIn | None = None,
        conventions: Conventions | None = None,
        bones: BoneOutput | None = None,
    ) -> Session:
        return await self._do(
            calls.create_session(chain, options, initial_pose, conventions, bones)
        )

    async def get_session(self, session: SessionRef) -> SessionInfo:
        return await self._do(calls.get_session(session))

    async def patch_session(self, session: SessionRef, options: SolverOptionsPatch) -> SessionInfo:
        return await self._do(calls.patch_session(session, options))

    async def set_pose(
        self,
        session: SessionRef,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
    ) -> Pose:
        return await self._do(calls.set_pose(session, calls.pose_in(q, joints)))

    async def delete_session(self, session: SessionRef) -> None:
        await self._do(calls.delete_session(session))

    async def frame(
        self,
        session: SessionRef,
        targets: list[Target],
        *,
        id: int | None = None,
        compact: bool = False,
    ) -> FrameResult:
        return await self._do(calls.frame(session, targets, id, compact))

    async def clip(
        self,
        session: SessionRef,
        frames: list[Frame],
        *,
        plan: bool = False,
        compact: bool = False,
    ) -> ClipResult:
        return await self._do(calls.clip(session, frames, plan, compact))

    async def batch(
        self, frames: list[BatchFrame], *, compact: bool = False
    ) -> list[BatchEntryResult]:
        """As ``Client.batch``."""
        return await self._do(calls.batch(frames, compact))

    async def solve(
        self,
        chain: Chain,
        targets: list[Target],
        *,
        seed: PoseIn | None = None,
        options: SolverOptionsPatch | None = None,
        id: int | None = None,
    ) -> FrameResult:
        return await self._do(calls.solve(chain, targets, seed, options, id))

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
