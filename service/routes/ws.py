"""WebSocket ``/v1/sessions/{session_id}/ws``: the game-client path.

The client sends ``frame`` messages (and ``clip``: several frames in one message,
solved in order or planned as a whole, and ``ping``), each with an increasing ``id``;
the server answers each one, in order, before reading the next. JSON text messages get JSON
text answers, MessagePack binary messages get MessagePack answers.

Recoverable errors (an error ``result`` message; the socket stays open): invalid_format,
invalid_problem, id_reuse, not_ready, rate_limited, and for a planned clip plans_busy
and too_many_plans. Closes: 4401 unauthorized, 4403
forbidden (wrong token, or an Origin not in IK_CORS_ORIGINS),
4404 not_found (at connect, or when the session was deleted / expired), 1009 message
too big, 1013 too many WebSockets, 1011 unexpected error (after an internal_error
message), 1012 server shutting down (uvicorn).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Annotated, Any

import msgpack
import orjson
from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect
from pydantic import TypeAdapter, ValidationError
from starlette import status

import schemas as S
from solver.errors import IKError
from solver.ik import Target as SolverTarget

from .. import convert, hints
from ..deps import Services, authenticate, services
from ..errors import (
    WS_FORBIDDEN,
    WS_NOT_FOUND,
    WS_UNAUTHORIZED,
    ServiceError,
    dotted_field,
    solver_error,
    validation_errors,
)
from ..sessions import Session

log = logging.getLogger("service")
router = APIRouter(prefix="/v1")

_CLIENT_MESSAGE: TypeAdapter[S.FrameMessage | S.ClipMessage | S.PingMessage] = TypeAdapter(
    S.ClientMessage
)
# pydantic's error types, at the message's top level, for a message whose ``type`` is
# missing or unknown, or that is not an object at all: answered with the types there are
# (dict_type from JSON, model_attributes_type from MessagePack).
_NO_MESSAGE_TYPE = frozenset(
    {"union_tag_not_found", "union_tag_invalid", "dict_type", "model_attributes_type"}
)
_AUTH_CLOSE = {
    "unauthorized": WS_UNAUTHORIZED,
    "forbidden": WS_FORBIDDEN,
    "not_found": WS_NOT_FOUND,
}


SUBPROTOCOL = "ik.v1"
TOKEN_SUBPROTOCOL_PREFIX = "ik.token."


def _token(ws: WebSocket) -> str | None:
    """The session token: ``Authorization: Bearer``, else a ``ik.token.<token>``
    subprotocol (browsers can set subprotocols, not headers), else ``?token=``."""
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


def _subprotocol(ws: WebSocket) -> str | None:
    """Echo ``ik.v1`` when offered (browsers fail a handshake that offered subprotocols
    and got none back); never echo the token."""
    return SUBPROTOCOL if SUBPROTOCOL in ws.scope.get("subprotocols", ()) else None


def _error(
    msg_id: int | None,
    code: str,
    message: str,
    field: str | None = None,
    retry_after_s: float | None = None,
) -> dict[str, Any]:
    err: dict[str, Any] = {"code": code, "message": message}
    if field is not None:
        err["field"] = field
    if retry_after_s is not None:
        err["retry_after_s"] = retry_after_s
    return {"id": msg_id, "type": "result", "success": False, "error": err}


def _raw_id(raw: Any) -> int | None:
    """The id of a message that failed validation, if it has a usable one."""
    if isinstance(raw, dict):
        v = raw.get("id")
        if isinstance(v, int) and not isinstance(v, bool):
            return v
    return None


class _SlowReader(Exception):
    """The client stopped reading its answers."""


def _origin_ok(ws: WebSocket, allowed: list[str]) -> bool:
    """Browsers send Origin; other clients usually do not. Only configured origins
    (IK_CORS_ORIGINS) may open a WebSocket from a browser."""
    origin = ws.headers.get("origin")
    return origin is None or origin in allowed or "*" in allowed


class _Connection:
    """One open socket: decoding, the id sequence, replies in the request's encoding."""

    def __init__(
        self,
        ws: WebSocket,
        svc: Services,
        session: Session,
        build: convert.ResultBuilder = convert.result_dict,
    ) -> None:
        self.ws = ws
        self.svc = svc
        self.session = session
        self.build = build
        self.last_id = -1
        self._loop = asyncio.get_running_loop()
        self._task = asyncio.current_task()
        self._send_timeout_s = svc.settings.ws_send_timeout_s
        self._sending_since: float | None = None  # loop.time() when a send started
        self._timed_out = False
        self._watch: asyncio.TimerHandle | None = None

    def start_watch(self) -> None:
        """Arm the send watchdog: one timer per connection, not one per send."""
        self._watch = self._loop.call_later(self._send_timeout_s, self._check_send)

    def stop_watch(self) -> None:
        if self._watch is not None:
            self._watch.cancel()
            self._watch = None

    def _check_send(self) -> None:
        """Timer callback: cancel the handler if a send has waited ws_send_timeout_s.

        It runs while the handler is suspended; a send in progress means the handler is
        suspended inside that send, so the cancellation lands there (see ``send``).
        """
        now = self._loop.time()
        since = self._sending_since
        if since is not None and now - since >= self._send_timeout_s and self._task is not None:
            self._timed_out = True
            self._watch = None
            self._task.cancel()
            return
        start = now if since is None else since
        self._watch = self._loop.call_at(start + self._send_timeout_s, self._check_send)

    async def send(self, payload: dict[str, Any], binary: bool) -> None:
        """Send one answer; a client that has not read for ws_send_timeout_s is dropped.

        uvicorn's send waits while the transport's write buffer is above its high-water
        mark, and the server reads the next message only after answering this one, so a
        client that stops reading costs at most one answer plus the socket buffers.

        The time limit is the connection's watchdog timer (``_check_send``), not
        ``asyncio.wait_for`` per send: wait_for wraps each send in a new task, a timer and
        a future, and costs the loop two more turns per answer (measured: the largest
        per-frame cost of the WebSocket path after the transport itself).
        """
        self._sending_since = self._loop.time()
        try:
            if binary:
                await self.ws.send_bytes(msgpack.packb(payload))
            else:
                await self.ws.send_text(orjson.dumps(payload).decode())
        except asyncio.CancelledError:
            task = self._task
            if self._timed_out and task is not None and task.uncancel() == 0:
                raise _SlowReader from None
            raise
        finally:
            self._sending_since = None

    async def reply_error(
        self,
        binary: bool,
        msg_id: int | None,
        code: str,
        message: str,
        field: str | None = None,
        retry_after_s: float | None = None,
    ) -> None:
        self.svc.metrics.error(code, "ws")
        await self.send(_error(msg_id, code, message, field, retry_after_s), binary)

    async def reply_service_error(self, binary: bool, msg_id: int, e: ServiceError) -> None:
        await self.reply_error(binary, msg_id, e.code, e.detail, e.field, e.retry_after_s)

    async def handle(self, data: str | bytes, t0: float) -> None:
        binary = isinstance(data, bytes)
        view = self.session.view
        raw: Any = None
        msg: S.FrameMessage | S.ClipMessage | S.PingMessage | None = None
        # A well-formed frame takes the fast path (convert.fast_frame); anything else is
        # validated by pydantic, which gives the documented error.
        try:
            if binary:
                raw = msgpack.unpackb(data, raw=False, strict_map_key=True)
                fast = convert.fast_frame(raw, view)
                if fast is None:
                    msg = _CLIENT_MESSAGE.validate_python(raw)
            else:
                fast = convert.fast_frame_json(data, view)
                if fast is None:
                    msg = _CLIENT_MESSAGE.validate_json(data)
        except ValidationError as e:
            if raw is None and not binary:
                try:
                    raw = orjson.loads(data)
                except orjson.JSONDecodeError:
                    raw = None
            errors = validation_errors(e.errors())
            first = errors[0] if errors else {"loc": [], "msg": "invalid message", "type": ""}
            message, field = str(first["msg"]), dotted_field(first["loc"])
            if field is None and first["type"] in _NO_MESSAGE_TYPE:
                message, field = hints.message_type_hint(raw), "type"
            await self.reply_error(binary, _raw_id(raw), "invalid_format", message, field)
            return
        except Exception as e:  # msgpack's errors share no useful base class
            await self.reply_error(
                binary, None, "invalid_format", f"not MessagePack: {type(e).__name__}"
            )
            return
        if fast is not None:
            await self.frame(binary, *fast, t0)
            return
        assert msg is not None
        if msg.id <= self.last_id:
            await self.reply_error(
                binary, msg.id, "id_reuse", f"id must be greater than {self.last_id}", "id"
            )
            return
        self.last_id = msg.id
        if isinstance(msg, S.PingMessage):
            await self.send({"id": msg.id, "type": "pong"}, binary)
            return
        if isinstance(msg, S.ClipMessage):
            await self.clip(binary, msg, t0)
            return
        try:
            targets = convert.targets(msg.targets, view, "targets")
        except ServiceError as e:
            await self.reply_error(binary, msg.id, e.code, e.detail, e.field)
            return
        await self.frame(binary, msg.id, targets, t0, checked_id=True)

    async def frame(
        self,
        binary: bool,
        msg_id: int,
        targets: list[SolverTarget],
        t0: float,
        *,
        checked_id: bool = False,
    ) -> None:
        """Solve one valid frame (from the fast path, or validated by pydantic) and
        answer it."""
        if not checked_id:
            if msg_id <= self.last_id:
                await self.reply_error(
                    binary, msg_id, "id_reuse", f"id must be greater than {self.last_id}", "id"
                )
                return
            self.last_id = msg_id
        try:
            (result,) = await self.svc.runner.session_frames(
                self.session, self.svc.store, [(msg_id, targets)], t0, "ws", self.build
            )
        except ServiceError as e:
            if e.code == "not_found":
                raise
            await self.reply_service_error(binary, msg_id, e)
            return
        except IKError as e:  # convert.py names the field first; this is the safety net
            await self.reply_service_error(binary, msg_id, solver_error(e))
            return
        await self.send(
            {"id": msg_id, "type": "result", "success": result["success"], "result": result}, binary
        )

    async def clip(self, binary: bool, msg: S.ClipMessage, t0: float) -> None:
        """Solve a clip (in order, or planned as a whole) and answer it in one
        ``clip_result``; as ``POST .../frames`` with ``{"frames": [...]}``."""
        runner = self.svc.runner
        try:
            limit = self.svc.settings.max_frames_per_request
            jobs = convert.clip_jobs(msg.frames, self.session.view, limit)
            plan = None
            if msg.plan:
                out, planned = await runner.session_plan(
                    self.session, self.svc.store, jobs, t0, "ws", self.build
                )
                plan = convert.plan_summary(planned)
            else:
                out = await runner.session_frames(
                    self.session, self.svc.store, jobs, t0, "ws", self.build
                )
        except ServiceError as e:
            if e.code == "not_found":
                raise
            await self.reply_service_error(binary, msg.id, e)
            return
        except IKError as e:  # convert.py names the field first; this is the safety net
            await self.reply_service_error(binary, msg.id, solver_error(e))
            return
        success = all(r["success"] for r in out)
        reply = {"id": msg.id, "type": "clip_result", "success": success, "results": out}
        await self.send({**reply, "plan": plan}, binary)


@router.websocket("/sessions/{session_id}/ws")
async def session_ws(
    ws: WebSocket,
    session_id: str,
    results: Annotated[S.ResultView, Query()] = S.ResultView.FULL,
) -> None:
    """Frames over a WebSocket (protocol in docs/websocket.md); ``?results=compact`` answers
    with CompactFrameResults. A bad ``results`` value closes 1008 (FastAPI's check)."""
    svc = services(ws)
    await ws.accept(subprotocol=_subprotocol(ws))
    if not _origin_ok(ws, svc.settings.cors_origin_list()):
        svc.metrics.error("forbidden_origin", "ws")
        await ws.close(code=WS_FORBIDDEN, reason="forbidden_origin")
        return
    try:
        session = await authenticate(svc.store, session_id, _token(ws))
    except ServiceError as e:
        svc.metrics.error(e.code, "ws")
        await ws.close(code=_AUTH_CLOSE[e.code], reason=e.code)
        return
    if svc.open_websockets >= svc.settings.max_websockets:
        svc.metrics.error("too_many_websockets", "ws")
        await ws.close(code=status.WS_1013_TRY_AGAIN_LATER, reason="too_many_websockets")
        return
    # The frame loop runs in a task of its own. Awaited here, it would sit under the
    # ~20 coroutine frames of uvicorn's and Starlette's ASGI stack, and every resume
    # (each received frame, each send that waits) would pass down through all of them
    # (perf of a loaded worker: PyIter_Send and PyGen_am_send alone were 5.3% of its
    # samples). Cancelling this handler cancels the task it awaits. The counts are
    # kept here, with no await between the check above and the increment.
    svc.open_websockets += 1
    svc.metrics.websockets.inc()
    session.websockets += 1
    try:
        frame_loop = _serve(ws, svc, session, convert.result_builder(results))
        await asyncio.create_task(frame_loop, name="ws-frame-loop")
    finally:
        session.websockets -= 1
        svc.open_websockets -= 1
        svc.metrics.websockets.dec()
        svc.store.touch(session)


async def _serve(
    ws: WebSocket, svc: Services, session: Session, build: convert.ResultBuilder
) -> None:
    """Read, solve and answer frames until the socket closes (its own task: see above)."""
    conn = _Connection(ws, svc, session, build)
    limit = svc.settings.ws_max_message_bytes
    conn.start_watch()
    try:
        while True:
            message = await ws.receive()
            t0 = time.perf_counter()
            if message["type"] == "websocket.disconnect":
                return
            data: str | bytes | None = message.get("text")
            if data is None:
                data = message.get("bytes")
            if data is None:
                continue
            if len(data) > limit:
                await ws.close(code=status.WS_1009_MESSAGE_TOO_BIG, reason="payload_too_large")
                return
            if session.closed:
                await ws.close(code=WS_NOT_FOUND, reason="not_found")
                return
            svc.ws_in_flight += 1
            try:
                await conn.handle(data, t0)
            except ServiceError as e:  # the session went away while the frame waited
                await ws.close(code=WS_NOT_FOUND, reason=e.code)
                return
            finally:
                svc.ws_in_flight -= 1
            if svc.draining:  # shutting down: this message was answered; no more
                await ws.close(code=status.WS_1012_SERVICE_RESTART, reason="shutting_down")
                return
    except WebSocketDisconnect:
        return
    except _SlowReader:
        svc.metrics.error("slow_reader", "ws")
        log.info("dropped a WebSocket whose client stopped reading")
        # The close frame queues behind the unread answers; if even that cannot be
        # written, give up: returning lets the server close the transport.
        with contextlib.suppress(Exception):
            await asyncio.wait_for(
                ws.close(code=status.WS_1008_POLICY_VIOLATION, reason="slow_reader"), 1.0
            )
        return
    except Exception:
        log.exception("unexpected error on a WebSocket")
        try:
            await conn.send(_error(None, "internal_error", "internal server error"), False)
            await ws.close(code=status.WS_1011_INTERNAL_ERROR, reason="internal_error")
        except Exception:  # the socket may be gone already
            pass
    finally:
        conn.stop_watch()
