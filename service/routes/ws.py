"""WebSocket ``/v1/sessions/{session_id}/ws``: the game-client path.

The client sends ``frame`` messages (and ``clip``, ``batch``: a frame for each of several
sessions, service/batch.py, ``fk`` and ``ping``), each with an increasing ``id``;
the server answers each one, in order, before reading the next. JSON text messages get JSON
text answers, MessagePack binary messages get MessagePack answers.

A message's way through this module: ``_serve`` receives it, ``_Connection.handle``
decodes it (``convert.fast_frame``, else pydantic), checks its id once, runs it
(``convert`` -> ``Runner`` -> ``convert.render_frames``) and sends the envelope
``ws_messages`` builds; ``_Connection.exception_reply`` is the one place that turns
an exception into an error message.

Recoverable errors (an error ``result`` message; the socket stays open): invalid_format,
invalid_problem, id_reuse, not_ready, rate_limited, and for a planned clip plans_busy
and too_many_plans. Closes: 4401 unauthorized, 4403 forbidden (wrong token) or
forbidden_origin (an Origin not in IK_CORS_ORIGINS), 4404 not_found (at connect, or when
the session was deleted / expired), 1009 payload_too_large, 1013 too_many_websockets,
1008 slow_reader, 1011 internal_error (after an internal_error message), 1012
shutting_down.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import time
from collections.abc import Sequence
from typing import Annotated, Any, Unpack, cast

from fastapi import APIRouter, Query, WebSocket, WebSocketDisconnect
from starlette import status

import schemas as S
from schemas import ErrorCode
from solver.arrays import Vector
from solver.errors import IKError
from solver.ik import Target as SolverTarget

from .. import convert
from ..auth import authenticate, origin_allowed, websocket_subprotocol, websocket_token
from ..convert import FastFrame
from ..dependencies import Services, services
from ..errors import (
    WS_FORBIDDEN,
    WS_NOT_FOUND,
    WS_UNAUTHORIZED,
    ServiceError,
    solver_error,
)
from ..responses import dumps_message, packb_message
from ..session_tokens import SessionTokens
from ..sessions import Session
from ..solving import session_client
from .ws_batch import RawBatch, batch_reply
from .ws_decode import ClientMessage, Unreadable, decode
from .ws_messages import (
    ErrorDetails,
    clip_result_message,
    error_message,
    fk_result_message,
    pong_message,
    result_message,
)

log = logging.getLogger("service")
# Less than this between an answer and the next message taken: it was waiting in
# uvicorn's queue, not sent after the answer arrived. 1 ms: a client that waits for its
# answers (60 Hz: one frame every 16.7 ms) sends well after it, while a turn of a busy
# loop on shared cores can take longer than 0.1 ms.
BACKLOG_GAP_S = 1e-3
router = APIRouter(prefix="/v1")

_AUTH_CLOSE = {
    ErrorCode.UNAUTHORIZED: WS_UNAUTHORIZED,
    ErrorCode.FORBIDDEN: WS_FORBIDDEN,
    ErrorCode.NOT_FOUND: WS_NOT_FOUND,
}


class _SlowReader(Exception):
    """The client stopped reading its answers."""


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
        self.backlog = False
        self.tokens = SessionTokens(svc.store)  # the sessions this socket's batches opened
        self._loop = asyncio.get_running_loop()
        self._task = asyncio.current_task()
        self._send_timeout_s = svc.settings.ws_send_timeout_s
        self._sending_since: float | None = None  # loop.time() when a send started
        self._timed_out = False
        self._watch: asyncio.TimerHandle | None = None
        # The message being solved (id, binary), and the last one the shutdown answered.
        self._solving: tuple[int, bool] | None = None
        self._answered_by_shutdown: int | None = None

    @functools.cached_property
    def client(self) -> str:
        """Whom this socket's pooled work counts against (service/work.py)."""
        peer = self.ws.client.host if self.ws.client else None
        return session_client(self.session, peer)

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
                await self.ws.send_bytes(packb_message(payload))
            else:
                await self.ws.send_text(dumps_message(payload))
        except asyncio.CancelledError:
            task = self._task
            if self._timed_out and task is not None and task.uncancel() == 0:
                raise _SlowReader from None
            raise
        finally:
            self._sending_since = None

    def error_reply(
        self, msg_id: int | None, code: ErrorCode, message: str, **details: Unpack[ErrorDetails]
    ) -> dict[str, Any]:
        """An error message for ``msg_id`` (``error_message``), counted in the metrics."""
        self.svc.metrics.error(code, "ws")
        return error_message(msg_id, code, message, **details)

    def exception_reply(self, msg_id: int, exc: ServiceError | IKError) -> dict[str, Any]:
        """The one place that turns a handler's exception into an error message
        (Home Assistant's ``async_handle_exception``).

        Raises:
            ServiceError: ``not_found``: the session went away while the message waited;
                ``_serve`` closes the socket 4404.
        """
        # convert names the field first; a solver error that got past it is still the
        # invalid_problem it is, as over HTTP (errors.solver_error is HTTP's safety net).
        err = solver_error(exc) if isinstance(exc, IKError) else exc
        if err.code is ErrorCode.NOT_FOUND:
            raise err
        return self.error_reply(
            msg_id, err.code, err.detail, field=err.field, retry_after_s=err.retry_after_s
        )

    def decode(self, data: str | bytes, binary: bool) -> FastFrame | RawBatch | ClientMessage:
        """The message read against this socket's session (``ws_decode.decode``).

        Raises:
            Unreadable: not JSON / MessagePack, or not a valid client message.
        """
        return decode(data, binary, self.session.view)

    async def handle(self, data: str | bytes, t0: float, backlog: bool = False) -> None:
        """Answer one message: decode, check its id, run it, send the one reply.
        ``backlog``: the message was already waiting (see ``_serve``)."""
        self.backlog = backlog
        binary = isinstance(data, bytes)
        try:
            msg = self.decode(data, binary)
        except Unreadable as e:
            reply = self.error_reply(e.msg_id, ErrorCode.INVALID_FORMAT, e.message, field=e.field)
            await self.send(reply, binary)
            return
        msg_id = msg[0] if isinstance(msg, tuple) else msg.id  # a RawBatch's [0]: its id
        if msg_id <= self.last_id:
            message = f"id must be greater than {self.last_id}"
            reply = self.error_reply(msg_id, ErrorCode.ID_REUSE, message, field="id")
            await self.send(reply, binary)
            return
        self.last_id = msg_id
        # The fast path's (id, targets), a stream's usual message, is tested first and
        # by exact type: isinstance against a pydantic model goes through ABCMeta's
        # __instancecheck__ (two per frame otherwise: ping, then batch).
        fast = type(msg) is tuple
        if not fast and isinstance(msg, S.PingMessage):
            await self.send(pong_message(msg_id), binary)
            return
        self._solving = (msg_id, binary)
        try:
            if fast:
                reply = await self.frame(msg_id, cast(FastFrame, msg)[1], t0)
            elif isinstance(msg, RawBatch | S.BatchMessage):
                reply = await batch_reply(msg, binary, t0, self)
            elif isinstance(msg, S.FrameMessage):
                view = self.session.view
                targets = convert.targets(msg.targets, view, "targets")
                if msg.bones is not None:
                    convert.check_bone_output(msg.bones, view.skeleton, "bones")
                pose = convert.frame_pose(msg.pose, view, "pose")
                reply = await self.frame(msg_id, targets, t0, msg.bones, pose)
            elif isinstance(msg, S.ClipMessage):
                reply = await self.clip(msg, t0)
            else:  # an FkMessage (a ping was answered above)
                assert isinstance(msg, S.FkMessage)
                if msg.q is None:  # the current pose: another worker may have moved it
                    await self.svc.store.latest(self.session)
                out = convert.fk_dict(
                    self.session.view, self.session.solver.q, msg.q, msg.joints, msg.bones, ""
                )
                reply = fk_result_message(msg_id, out)
        except (ServiceError, IKError) as e:
            reply = self.exception_reply(msg_id, e)
        finally:
            self._solving = None
        if self._answered_by_shutdown != msg_id:
            await self.send(reply, binary)

    async def shutdown_reply(self) -> None:
        """Answer the message being solved, if any, when the server stops first
        (``__main__``'s shutdown calls it; registered once per connection, in ``_serve``)."""
        if self._solving is None:
            return
        msg_id, binary = self._solving
        self._answered_by_shutdown = msg_id
        message = "the server is shutting down before this message was solved; send it again "
        message += "after reconnecting (another replica, or this one once restarted)"
        reply = self.error_reply(msg_id, ErrorCode.SHUTTING_DOWN, message, retry_after_s=1.0)
        ws = self.ws
        await (
            ws.send_bytes(packb_message(reply)) if binary else ws.send_text(dumps_message(reply))
        )

    async def frame(
        self,
        msg_id: int,
        targets: Sequence[SolverTarget],
        t0: float,
        bones: S.BoneOutput | None = None,
        pose: Vector | None = None,
    ) -> dict[str, Any]:
        """Solve one valid frame (from the fast path, or validated by pydantic; only
        the latter carries an animated ``pose``: ``convert.frame_pose``)."""
        (solved,) = await self.svc.runner.session_frames(
            self.session,
            self.svc.store,
            [(msg_id, targets, pose)],
            t0,
            "ws",
            self.client,
            may_inline=not self.backlog,
        )
        result = self.build(solved.result, msg_id, solved.server_us, solved.step)
        view = self.session.view
        chosen = view.bone_output if bones is None else bones
        if chosen is not None and convert.wants_bones(chosen):
            result["bones"] = convert.bones_dict(view, solved.result.q, chosen)
        return result_message(msg_id, result)

    async def clip(self, msg: S.ClipMessage, t0: float) -> dict[str, Any]:
        """Solve a clip (in order, or planned as a whole); as ``POST .../frames`` with
        ``{"frames": [...]}``."""
        runner = self.svc.runner
        limit = self.svc.settings.max_frames_per_request
        view = self.session.view
        jobs = convert.clip_jobs(msg.frames, view, limit, plan=msg.plan)
        outputs = [f.bones for f in msg.frames]
        for i, output in enumerate(outputs):
            if output is not None:
                convert.check_bone_output(output, view.skeleton, f"frames[{i}].bones")
        plan = None
        if msg.plan:
            solved, planned = await runner.session_plan(
                self.session, self.svc.store, jobs, t0, "ws"
            )
            plan = convert.plan_summary(planned)
        else:
            solved = await runner.session_frames(
                self.session, self.svc.store, jobs, t0, "ws", self.client
            )
        results = convert.add_bones(
            convert.render_frames(solved, self.build), solved, view, outputs
        )
        return clip_result_message(msg.id, results, plan)


@router.websocket("/sessions/{session_id}/ws")
async def session_ws(
    ws: WebSocket,
    session_id: str,
    results: Annotated[str, Query()] = S.ResultView.FULL.value,
) -> None:
    """Frames over a WebSocket (protocol in docs/websocket.md); ``?results=compact`` answers
    with CompactFrameResults. A bad ``results`` value closes 1008 ``invalid_format``:
    checked here, after the handshake, because FastAPI's own check refuses the handshake
    (HTTP 403), which browsers report as a bare network error."""
    svc = services(ws)
    await ws.accept(subprotocol=websocket_subprotocol(ws))
    try:
        view = S.ResultView(results)
    except ValueError:
        await _close(ws, svc, status.WS_1008_POLICY_VIOLATION, ErrorCode.INVALID_FORMAT)
        return
    if not origin_allowed(ws, svc.settings.cors_origin_list()):
        await _close(ws, svc, WS_FORBIDDEN, ErrorCode.FORBIDDEN_ORIGIN)
        return
    try:
        session = await authenticate(svc.store, session_id, websocket_token(ws))
    except ServiceError as e:
        await _close(ws, svc, _AUTH_CLOSE.get(e.code, status.WS_1013_TRY_AGAIN_LATER), e.code)
        return
    if svc.open_websockets >= svc.settings.max_websockets:
        await _close(ws, svc, status.WS_1013_TRY_AGAIN_LATER, ErrorCode.TOO_MANY_WEBSOCKETS)
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
        frame_loop = _serve(ws, svc, session, convert.result_builder(view))
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
    shutdown_reply = conn.shutdown_reply  # one bound method: the set holds this one
    svc.shutdown_replies.add(shutdown_reply)
    done_at = -math.inf
    try:
        while True:
            message = await ws.receive()
            t0 = time.perf_counter()
            # A message that was already waiting (taken with no pause since the last
            # answer) is from a client sending faster than it is answered: its frames
            # are solved off the loop, so that they cannot take turns from clients that
            # wait for their answers (measured under 10 such sockets: loadtest.hostile).
            backlog = t0 - done_at < BACKLOG_GAP_S
            if message["type"] == "websocket.disconnect":
                return
            if backlog:
                # Let every other ready connection take its turn before this message.
                # uvicorn queues all the messages of one read, and taking one from a
                # non-empty queue does not suspend: without this, one socket that sends
                # a thousand frames back to back holds the loop for all of them
                # (measured: a second client's round trip went from 1 ms to 1.2 s).
                # With it, a client waits at most one message per busy connection. Only
                # a message taken with no pause needs it: one taken 1 ms or more after
                # the answer was taken after the receive had suspended, when the others
                # had their turn (or after the process was descheduled or paused for
                # garbage collection, when they did not: one message more). A yield
                # after every answer was one more turn of the loop per frame (one
                # paired loadtest.cost run, 30 clients x 60 Hz, without any yield:
                # 174, 177 -> 161, 164 us of the worker's CPU per frame).
                await asyncio.sleep(0)
            data: str | bytes | None = message.get("text")
            if data is None:
                data = message.get("bytes")
            if data is None:
                continue
            if len(data) > limit:
                await ws.close(
                    code=status.WS_1009_MESSAGE_TOO_BIG, reason=ErrorCode.PAYLOAD_TOO_LARGE
                )
                return
            if session.closed:
                await ws.close(code=WS_NOT_FOUND, reason=ErrorCode.NOT_FOUND)
                return
            if svc.draining:
                # Shutting down, and this message was not in flight when the stop began (checked
                # with no await before it is counted in flight, which the drain waits for):
                # the socket closes 1012 as an idle one does (clients send it again after
                # reconnecting) instead of starting a solve that the end of the drain
                # would cut short with a shutting_down error (the demo's page showed one).
                await ws.close(code=status.WS_1012_SERVICE_RESTART, reason=ErrorCode.SHUTTING_DOWN)
                return
            svc.ws_in_flight += 1
            try:
                await conn.handle(data, t0, backlog)
            except ServiceError as e:  # the session went away while the frame waited
                await ws.close(code=WS_NOT_FOUND, reason=e.code)
                return
            finally:
                svc.ws_in_flight -= 1
            if svc.draining:  # shutting down: this message was answered; no more
                await ws.close(code=status.WS_1012_SERVICE_RESTART, reason=ErrorCode.SHUTTING_DOWN)
                return
            done_at = time.perf_counter()
    except WebSocketDisconnect:
        return
    except _SlowReader:
        svc.metrics.error(ErrorCode.SLOW_READER, "ws")
        log.info("dropped a WebSocket whose client stopped reading")
        # The close frame queues behind the unread answers; if even that cannot be
        # written, give up: returning lets the server close the transport.
        with contextlib.suppress(Exception):
            await asyncio.wait_for(
                ws.close(code=status.WS_1008_POLICY_VIOLATION, reason=ErrorCode.SLOW_READER),
                1.0,
            )
        return
    except Exception:
        log.exception("unexpected error on a WebSocket")
        try:
            internal = ErrorCode.INTERNAL_ERROR
            await conn.send(error_message(None, internal, "internal server error"), False)
            await ws.close(code=status.WS_1011_INTERNAL_ERROR, reason=internal)
        except Exception:  # the socket may be gone already
            pass
    finally:
        svc.shutdown_replies.discard(shutdown_reply)
        conn.stop_watch()


async def _close(ws: WebSocket, svc: Services, code: int, reason: ErrorCode) -> None:
    """Refuse the socket at connect: count the reason, close with ``code``."""
    svc.metrics.error(reason, "ws")
    await ws.close(code=code, reason=reason)
