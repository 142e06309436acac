"""A session's WebSocket as a stream of frames: ids, pipelining, encodings, reconnects.

The stream numbers its messages itself (0, 1, 2, ...), so a caller can send many and match
the answers by the id each ``send_*`` returned; the server answers in order. When the
connection drops (or the server closes 1011, 1012 or 1013, or answers ``shutting_down``, or
``not_ready`` after a reconnect), the stream reconnects within its ``Reconnect`` budget
(reconnect.py: a deadline, backoff with jitter) and sends again, in order, every message
that had no answer yet, under
the id it was first sent with (each connection wants increasing ids; the stream keeps one
counter over every connection, so they still increase). Of what other tasks send to an
``AsyncStream`` while it reconnects, at most ``max_queued`` messages wait for the new
connection (queued.py: the oldest beyond it are dropped unsent, ``MessageDropped``); the
blocking ``Stream`` reconnects inside the call that met the drop, so nothing waits
behind it. Answers are reported under the id the caller got, and each message gets
exactly one (a dropped one: its ``MessageDropped``). A server that keeps answers (sessions
in Redis, docs/operations.md) answers a message it had solved, and whose answer was lost
in the drop, with that stored answer (on another worker too): it is never solved twice.

``_Pipeline`` (ids, encodings, what waits for an answer) and ``_Retries`` (which failures
a reconnect can mend, and the budget) hold all of that without I/O; ``AsyncStream``
(websockets' asyncio client) and ``Stream`` (its threading client) only move bytes and
wait.
"""

from __future__ import annotations

import asyncio
import enum
import functools
import json
import math
import re
import socket
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import msgpack
from websockets.asyncio.client import ClientConnection as AsyncConnection
from websockets.asyncio.client import connect as async_connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus
from websockets.sync.client import ClientConnection as SyncConnection
from websockets.sync.client import connect as sync_connect

from .errors import (
    RECONNECTABLE,
    CloseCode,
    ConnectionLost,
    EncodeError,
    ErrorCode,
    IKClientError,
    MessageDropped,
    StreamClosed,
    UnexpectedAnswer,
    service_error,
    stream_closed,
)
from .queued import DEFAULT_MAX_QUEUED, SendQueue, max_queued_option
from .reconnect import Backoff, Reconnect, retry_after_s
from .types import (
    Answer,
    BatchAnswer,
    BatchEntryResult,
    BatchFrame,
    BoneOutput,
    ClipAnswer,
    ClipResult,
    Encoding,
    FkAnswer,
    FkResult,
    Frame,
    FrameAnswer,
    FrameResult,
    Pong,
    Target,
)

# JSON messages are written and answers read with orjson when it is installed (``pip
# install ik-client[fast]``): several times faster than json, which counts for a client
# streaming thousands of frames a second (loadtest); the same values either way.
_loads: Callable[[str | bytes], Any]
_orjson_dumps: Callable[[Any], bytes] | None
try:
    import orjson

    _loads = orjson.loads
    # orjson writes dataclasses and datetimes itself, which json refuses: passed
    # through, orjson refuses them too (TypeError) and json decides, so that a target
    # is accepted or refused the same with and without orjson. UUIDs and enum members,
    # which orjson always writes, json and msgpack write alike (``_default``).
    _orjson_dumps = functools.partial(
        orjson.dumps,
        option=orjson.OPT_PASSTHROUGH_DATACLASS | orjson.OPT_PASSTHROUGH_DATETIME,
    )
except ImportError:  # pragma: no cover - the test environment has orjson
    _loads = json.loads
    _orjson_dumps = None


# A float in MessagePack is 0xcb and 8 big-endian bytes (msgpack writes every Python
# float so); NaN and infinity have every exponent bit set: 0x7f or 0xff (the sign), then
# 0xf_. Other bytes can match too; a match only sends the message to the full check.
_MSGPACK_NON_FINITE = re.compile(rb"\xcb[\x7f\xff][\xf0-\xff]")


def _refuse_non_finite(
    value: Any, field: str = "", ancestors: frozenset[int] = frozenset()
) -> None:
    """Raise an EncodeError naming the first NaN or infinity in ``value`` (a message, or a
    part of it at ``field``): the server refuses them, and JSON cannot carry them (json
    refuses them, orjson writes null), so both encodings refuse them here, alike.
    A container met again inside itself is left to the encoder, which refuses it."""
    if isinstance(value, float):
        if not math.isfinite(value):
            raise EncodeError(
                f"{field} is {value!r}: the service takes finite numbers only", field=field
            )
        return
    if id(value) in ancestors:
        return
    if isinstance(value, dict):
        inner = ancestors | {id(value)}
        for key, item in value.items():
            _refuse_non_finite(item, f"{field}.{key}" if field else str(key), inner)
    elif isinstance(value, list | tuple):
        inner = ancestors | {id(value)}
        for index, item in enumerate(value):
            _refuse_non_finite(item, f"{field}[{index}]", inner)


def json_body(body: Any, what: str = "the body") -> str:
    """``body`` as the JSON the service reads, written as a stream writes its messages:
    NaN and infinity refused naming the field, a UUID or enum member as orjson writes
    it; anything else that cannot be written is an EncodeError with the encoder's
    error as its cause. Raised here, before anything is sent."""
    try:
        return _dumps(body)
    except EncodeError:
        raise
    except (TypeError, ValueError, OverflowError) as exc:  # a dataclass, a cycle, 2**64
        raise EncodeError(f"{what} cannot be written as JSON: {exc}") from exc


def _default(value: Any) -> Any:
    """What json and msgpack write for the two types orjson writes natively and they do
    not: a UUID as its canonical string, an enum member as its value (orjson's forms), so
    that a message is written the same in every encoding, with orjson or without."""
    if isinstance(value, uuid.UUID):
        return str(value)
    if isinstance(value, enum.Enum):
        return value.value
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


def _dumps(payload: Any) -> str:
    """``payload`` as compact JSON; NaN and infinity refused (ValueError naming the
    field), as the server refuses them, here where the caller is."""
    if _orjson_dumps is not None:
        try:
            data = _orjson_dumps(payload)
        except TypeError:  # orjson.JSONEncodeError: int keys, which json writes, or a
            pass  # value neither writes (a dataclass, a datetime), which json refuses
        else:
            if b"null" not in data:  # orjson writes NaN and infinity as null: json decides
                return data.decode()
    try:
        return json.dumps(payload, separators=(",", ":"), allow_nan=False, default=_default)
    except ValueError:
        _refuse_non_finite(payload)  # when a NaN or infinity is why, the same error as msgpack's
        raise


def _packb(payload: dict[str, Any]) -> bytes:
    """``payload`` as MessagePack; NaN and infinity refused as by ``_dumps``."""
    data: bytes = msgpack.packb(payload, default=_default)
    if _MSGPACK_NON_FINITE.search(data):  # perhaps one: the full check decides
        _refuse_non_finite(payload)
    return data


# What ends one reconnect attempt and lets the next one start (``_Retries.attempt_failed``).
_ATTEMPT_FAILURES = (ConnectionClosed, OSError, InvalidHandshake, TimeoutError)
# Handshake refusals a reconnect waits out: a timeout, too many requests, and a server
# or balancer that cannot serve now (502-504: no worker up). Any other status (401, 403,
# 404 from a proxy in front) is the same on every try.
_RETRIED_STATUSES = frozenset({408, 425, 429, 500, 502, 503, 504})
# Answers of long clips of big chains can be large; the server bounds what it sends.
MAX_ANSWER_BYTES = 64 * 2**20
OPEN_TIMEOUT_S = 30.0
# websockets' own keepalive defaults: a ping every 20 s, the connection dropped (1011)
# when its pong takes longer than 20 s.
PING_INTERVAL_S = 20.0
PING_TIMEOUT_S = 20.0


@dataclass(slots=True)
class _Message:
    id: int  # the id the caller was given
    wire_id: int  # the id it carries on every connection
    # The message as first sent, id included: a reconnect sends these bytes again. A new
    # encoding of the body could differ (the caller may have changed its dicts since)
    # or fail, and the server recognises a resent message by its id and content.
    data: str | bytes


class _Pipeline:
    """Ids, encoding, and the messages still waiting for an answer, in order."""

    def __init__(self, encoding: Encoding) -> None:
        self.encoding = encoding
        self._next_id = 0  # the caller's ids
        self._next_wire_id = 0  # ids on the wire: one counter over every connection
        self._waiting: OrderedDict[int, _Message] = OrderedDict()  # by wire id
        # Held while reconnecting and dropped unsent (queued.py): wire id -> caller id,
        # each raised as MessageDropped in its turn.
        self._dropped: OrderedDict[int, int] = OrderedDict()

    @property
    def in_flight(self) -> int:
        return len(self._waiting)

    def add(self, body: dict[str, Any]) -> tuple[int, str | bytes]:
        """Number a new message; returns its id and its encoding.

        Raises:
            EncodeError: ``body`` cannot be written (a ValueError and a TypeError too);
                nothing was counted.
        """
        data = self._encode(body, self._next_wire_id)
        message = _Message(self._next_id, self._next_wire_id, data)
        self._next_id += 1
        self._next_wire_id += 1
        self._waiting[message.wire_id] = message
        return message.id, data

    def hold(self, body: dict[str, Any], held: SendQueue[int]) -> int:
        """Number a message sent while reconnecting: it waits for the new connection in
        ``held``, and the oldest held beyond its limit is dropped (never sent); returns
        its id. Raises as ``add``."""
        message_id, _ = self.add(body)
        for wire_id in held.add(self._next_wire_id - 1):
            self._dropped[wire_id] = self._waiting.pop(wire_id).id
        return message_id

    def take_dropped(self) -> int | None:
        """The caller id of the next message in the order sent, taken off, if it was
        dropped; else None (its answer comes from the server)."""
        if not self._dropped:
            return None
        wire_id = next(iter(self._dropped))
        if self._waiting and next(iter(self._waiting)) < wire_id:
            return None
        return self._dropped.pop(wire_id)

    def resend(self) -> list[str | bytes]:
        """Every waiting message, in order, as first sent: what a new connection gets.
        The same id and content let a server that stored the answer give it again
        rather than solve the frame twice; and nothing is encoded again, so nothing
        here can fail to encode."""
        return [m.data for m in self._waiting.values()]

    def answer(self, data: str | bytes, *, outage: frozenset[str] = frozenset()) -> Answer:
        """The answer ``data`` carries, under its message's caller id.

        Args:
            outage: The error codes that are part of an outage now (``_Retries.outage``):
                such an answer is not the message's.

        Raises:
            ServiceError: The message was answered with an error (its subclass by code).
            _NotServing: The server cannot serve the message now but another connection
                can; it stays waiting, to be sent again.
        """
        envelope = _envelope(data)
        wire_id = envelope.get("id")
        if wire_id is None and self._waiting:  # the server could not read the id: in order
            wire_id = next(iter(self._waiting))
        message = self._waiting.get(wire_id) if isinstance(wire_id, int) else None
        if message is None:
            raise UnexpectedAnswer(
                f"an answer to id {wire_id!r}, which is not waiting: {envelope}",
                id=None,
                envelope=envelope,
            )
        kind = envelope.get("type")
        if "error" in envelope:
            error = envelope["error"]
            if error.get("code") in outage:
                raise _NotServing.of(error)
            del self._waiting[message.wire_id]
            raise service_error(
                error.get("code"),
                error.get("message", ""),
                field=error.get("field"),
                retry_after_s=error.get("retry_after_s"),
                id=message.id,
            )
        del self._waiting[message.wire_id]
        if kind == "result":
            result = envelope["result"]
            frame = FrameResult.from_json({**result, "id": message.id})
            return FrameAnswer(message.id, frame, bool(envelope["success"]))
        if kind == "clip_result":
            return ClipAnswer(message.id, ClipResult.from_json(envelope))
        if kind == "batch_result":
            results = [BatchEntryResult.from_json(e) for e in envelope["results"]]
            return BatchAnswer(message.id, results, bool(envelope["success"]))
        if kind == "fk_result":
            return FkAnswer(message.id, FkResult.from_json(envelope))
        if kind == "pong":
            return Pong(message.id)
        # Not the envelope in the message: formatting it costs more than the rest.
        raise UnexpectedAnswer(
            f"an answer of unknown type {kind!r} to id {wire_id}", id=message.id, envelope=envelope
        )

    def _encode(self, body: dict[str, Any], wire_id: int) -> str | bytes:
        payload = {**body, "id": wire_id}
        try:
            if self.encoding is Encoding.MSGPACK:
                return _packb(payload)
            return _dumps(payload)
        except EncodeError:
            raise
        except (TypeError, ValueError, OverflowError) as exc:  # a dataclass, a cycle, 2**64
            raise EncodeError(
                f"the message cannot be written as {self.encoding.value}: {exc}"
            ) from exc


class _NotServing(Exception):
    """An error answer that says the server cannot serve the message now, where a new
    connection, after a wait, can: the stream reconnects and sends it again. ``close``
    is what the stream raises if its reconnect budget runs out."""

    def __init__(self, close: StreamClosed, retry_after_s: float | None) -> None:
        super().__init__(str(close))
        self.close = close
        self.retry_after_s = retry_after_s

    @classmethod
    def of(cls, error: dict[str, Any]) -> _NotServing:
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


def _frame(targets: list[Target], bones: BoneOutput | None) -> dict[str, Any]:
    """A frame message; ``bones`` overrides the session's bone output for this frame."""
    if bones is None:
        return {"type": "frame", "targets": targets}
    return {"type": "frame", "targets": targets, "bones": bones}


def _clip(frames: list[Frame], plan: bool) -> dict[str, Any]:
    return {"type": "clip", "frames": frames, "plan": plan}


def _envelope(data: str | bytes) -> dict[str, Any]:
    """An answer decoded (MessagePack when binary, else JSON) to the object it must be.

    Raises:
        UnexpectedAnswer: It is not one (garbled, or an array or a number): nothing is
            taken off the in-flight messages, and the stream goes on.
    """
    try:
        envelope = msgpack.unpackb(data, raw=False) if isinstance(data, bytes) else _loads(data)
    except Exception as e:  # each decoder has its own errors; all mean the same here
        raise UnexpectedAnswer(
            f"an answer that does not decode ({type(e).__name__}): {data[:80]!r}",
            id=None,
            envelope={},
            data=data,
        ) from e
    if not isinstance(envelope, dict):
        raise UnexpectedAnswer(
            f"an answer that is not an object: {data[:80]!r}", id=None, envelope={}, data=data
        )
    return envelope


def _batch(frames: list[BatchFrame]) -> dict[str, Any]:
    return {"type": "batch", "frames": frames}


def _fk(
    q: list[float] | None, joints: dict[str, float] | None, bones: BoneOutput | None
) -> dict[str, Any]:
    """An fk message: the pose ``q``, or ``joints`` by name, or neither (the session's)."""
    body: dict[str, Any] = {"type": "fk"}
    for key, value in (("q", q), ("joints", joints), ("bones", bones)):
        if value is not None:
            body[key] = value
    return body


def _open_failed(url: str, exc: Exception) -> ConnectionLost:
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


class _Retries:
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

    def not_serving(self, exc: _NotServing) -> None:
        """Note an answer that the server cannot serve now (``_NotServing``)."""
        self._lost(exc.close, exc)
        self._retry_after_s = exc.retry_after_s

    def attempt_failed(self, exc: Exception) -> None:
        """Note a reconnect attempt that failed (one of ``_ATTEMPT_FAILURES``): a close is
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


def _expect_frame(answer: Answer) -> FrameResult:
    if not isinstance(answer, FrameAnswer):
        raise IKClientError(f"expected a frame result, got {answer!r}")
    return answer.result


def _expect_fk(answer: Answer) -> FkResult:
    if not isinstance(answer, FkAnswer):
        raise IKClientError(f"expected an fk result, got {answer!r}")
    return answer.result


def _expect_pong(answer: Answer) -> Pong:
    if not isinstance(answer, Pong):
        raise IKClientError(f"expected a pong, got {answer!r}")
    return answer


def _expect_clip(answer: Answer) -> ClipResult:
    if not isinstance(answer, ClipAnswer):
        raise IKClientError(f"expected a clip result, got {answer!r}")
    return answer.clip


def _expect_batch(answer: Answer) -> list[BatchEntryResult]:
    if not isinstance(answer, BatchAnswer):
        raise IKClientError(f"expected a batch result, got {answer!r}")
    return answer.results


Connection = TypeVar("Connection", SyncConnection, AsyncConnection)


class _BaseStream(Generic[Connection]):
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
        self._pipeline = _Pipeline(encoding)
        self._retries = _Retries(reconnect)
        self.max_queued = max_queued_option(max_queued)
        # While an asyncio stream reconnects: what is sent meanwhile (None otherwise).
        self._held: SendQueue[int] | None = None
        self._connection: Connection | None = None
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
        """The answer ``data`` carries (``_Pipeline.answer``); any answer but one that
        is part of the outage (``_NotServing``) gives the reconnect budget back."""
        serving = True
        try:
            return self._pipeline.answer(data, outage=self._retries.outage)
        except _NotServing:
            serving = False
            raise
        finally:
            if serving:  # error answers included: the server answered
                self._retries.answered()

    def _note_failure(self, exc: ConnectionClosed | _NotServing) -> None:
        """Count ``exc`` against the reconnect budget, or raise it when reconnecting
        cannot mend it (``_Retries``)."""
        if isinstance(exc, _NotServing):
            self._retries.not_serving(exc)
        else:
            self._retries.closed(exc)

    def _reconnected(self, connection: Connection) -> None:
        self._connection = connection
        self.reconnects += 1


class AsyncStream(_BaseStream[AsyncConnection]):
    """A session's WebSocket (asyncio). Use as ``async with client.stream(session) as s``.

    ``send_frame`` / ``send_clip`` / ``send_batch`` / ``send_ping`` return the message's
    id; ``receive`` returns the next answer (in the order sent) or raises its
    ``ServiceError`` (an answer it cannot read: ``UnexpectedAnswer``; a message dropped
    unsent while reconnecting: ``MessageDropped``), waiting at most ``timeout_s``
    (``TimeoutError``). While a task reconnects, a send from another task returns at
    once and its message waits for the new connection (``queued``, at most
    ``max_queued``). ``frame``, ``clip``, ``batch`` and ``ping`` send
    one message and wait for its answer. Sends may come from several tasks; answers are read
    by one task at a time.
    """

    @functools.cached_property
    def _lock(self) -> asyncio.Lock:
        """One sender or one reconnect at a time."""
        return asyncio.Lock()

    async def __aenter__(self) -> AsyncStream:
        try:
            self._connection = await self._open()
        except _ATTEMPT_FAILURES as exc:
            raise _open_failed(self.url, exc) from exc
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        await self.close()

    async def close(self) -> None:
        if self._connection is not None:
            await self._connection.close()

    async def send_frame(self, targets: list[Target], *, bones: BoneOutput | None = None) -> int:
        return await self._send(_frame(targets, bones))

    async def send_clip(self, frames: list[Frame], *, plan: bool = False) -> int:
        return await self._send(_clip(frames, plan))

    async def send_batch(self, frames: list[BatchFrame]) -> int:
        return await self._send(_batch(frames))

    async def send_ping(self) -> int:
        return await self._send({"type": "ping"})

    async def send_fk(
        self,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
        bones: BoneOutput | None = None,
    ) -> int:
        return await self._send(_fk(q, joints, bones))

    async def receive(self) -> Answer:
        while True:
            if (dropped := self._pipeline.take_dropped()) is not None:
                raise MessageDropped(dropped, self.max_queued)
            connection = self.connection
            try:
                # Cancelling recv() loses nothing (websockets' guarantee).
                data = await asyncio.wait_for(connection.recv(), self.timeout_s)
            except ConnectionClosed as exc:
                await self._recover(connection, exc)
                continue
            try:
                return self._answer(data)
            except _NotServing as exc:
                await connection.close()  # what waits is sent again on a new connection
                await self._recover(connection, exc)

    async def frame(self, targets: list[Target], *, bones: BoneOutput | None = None) -> FrameResult:
        await self.send_frame(targets, bones=bones)
        return _expect_frame(await self.receive())

    async def clip(self, frames: list[Frame], *, plan: bool = False) -> ClipResult:
        await self.send_clip(frames, plan=plan)
        return _expect_clip(await self.receive())

    async def batch(self, frames: list[BatchFrame]) -> list[BatchEntryResult]:
        await self.send_batch(frames)
        return _expect_batch(await self.receive())

    async def ping(self) -> Pong:
        await self.send_ping()
        return _expect_pong(await self.receive())

    async def fk(
        self,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
        bones: BoneOutput | None = None,
    ) -> FkResult:
        """Forward kinematics of a pose (``q``, ``joints`` by name, or neither: the
        session's current pose): its effectors' world poses (and, on skeleton chains,
        bone data) in the session's conventions; the pose does not change."""
        await self.send_fk(q=q, joints=joints, bones=bones)
        return _expect_fk(await self.receive())

    async def _open(self) -> AsyncConnection:
        return await async_connect(self.url, **self._connect_options, **self._take_sock())

    async def _send(self, body: dict[str, Any]) -> int:
        if self._held is not None:  # reconnecting: it goes out on the new connection
            return self._pipeline.hold(body, self._held)
        async with self._lock:
            # Waiting before it is sent: a send that fails is sent again after reconnecting.
            message_id, data = self._pipeline.add(body)
            connection = self.connection
            try:
                await connection.send(data)
                return message_id
            except ConnectionClosed as exc:
                failure = exc
        await self._recover(connection, failure)
        return message_id

    async def _recover(self, failed: AsyncConnection, exc: ConnectionClosed | _NotServing) -> None:
        """Reconnect and resend what is waiting, or raise the close as a ``StreamClosed``."""
        self._note_failure(exc)
        async with self._lock:
            if self._connection is not failed:
                return  # another task has reconnected already
            self._held = SendQueue(self.max_queued)  # what other tasks send meanwhile
            try:
                await self._reconnect()
            finally:
                self._held = None

    async def _reconnect(self) -> None:
        """Connect again (holding the lock) and resend what waits, within the budget."""
        for delay in self._retries.delays():
            await asyncio.sleep(delay)
            try:
                connection = await self._open()
                # What is held goes out now with the rest; a send from here on waits
                # for the lock and goes out after them.
                self._held = None
                for data in self._pipeline.resend():
                    await connection.send(data)
            except _ATTEMPT_FAILURES as failure:
                if self._held is None:  # they went out on a connection that failed:
                    self._held = SendQueue(self.max_queued)  # kept, and counted no more
                self._retries.attempt_failed(failure)
                continue
            self._reconnected(connection)
            return


class Stream(_BaseStream[SyncConnection]):
    """A session's WebSocket (blocking; one thread at a time). Use as
    ``with client.stream(session) as s``; the same calls as ``AsyncStream``.
    ``receive`` waits at most ``timeout_s`` (``TimeoutError``)."""

    def __enter__(self) -> Stream:
        try:
            self._connection = self._open()
        except _ATTEMPT_FAILURES as exc:
            raise _open_failed(self.url, exc) from exc
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()

    def send_frame(self, targets: list[Target], *, bones: BoneOutput | None = None) -> int:
        return self._send(_frame(targets, bones))

    def send_clip(self, frames: list[Frame], *, plan: bool = False) -> int:
        return self._send(_clip(frames, plan))

    def send_batch(self, frames: list[BatchFrame]) -> int:
        return self._send(_batch(frames))

    def send_ping(self) -> int:
        return self._send({"type": "ping"})

    def send_fk(
        self,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
        bones: BoneOutput | None = None,
    ) -> int:
        return self._send(_fk(q, joints, bones))

    def receive(self) -> Answer:
        while True:
            try:
                data = self.connection.recv(timeout=self.timeout_s)
            except ConnectionClosed as exc:
                self._recover(exc)
                continue
            try:
                return self._answer(data)
            except _NotServing as exc:
                self.connection.close()  # what waits is sent again on a new connection
                self._recover(exc)

    def frame(self, targets: list[Target], *, bones: BoneOutput | None = None) -> FrameResult:
        self.send_frame(targets, bones=bones)
        return _expect_frame(self.receive())

    def clip(self, frames: list[Frame], *, plan: bool = False) -> ClipResult:
        self.send_clip(frames, plan=plan)
        return _expect_clip(self.receive())

    def batch(self, frames: list[BatchFrame]) -> list[BatchEntryResult]:
        self.send_batch(frames)
        return _expect_batch(self.receive())

    def ping(self) -> Pong:
        self.send_ping()
        return _expect_pong(self.receive())

    def fk(
        self,
        *,
        q: list[float] | None = None,
        joints: dict[str, float] | None = None,
        bones: BoneOutput | None = None,
    ) -> FkResult:
        """Forward kinematics of a pose (``q``, ``joints`` by name, or neither: the
        session's current pose): its effectors' world poses (and, on skeleton chains,
        bone data) in the session's conventions; the pose does not change."""
        self.send_fk(q=q, joints=joints, bones=bones)
        return _expect_fk(self.receive())

    def _open(self) -> SyncConnection:
        options = {**self._connect_options, **self._take_sock()}
        connection: SyncConnection = sync_connect(self.url, **options)
        # websockets 17.1 warns about a connection not entered as a context manager;
        # this one lives as long as the stream, which closes it (its exit is close()).
        return connection.__enter__()

    def _send(self, body: dict[str, Any]) -> int:
        message_id, data = self._pipeline.add(body)
        try:
            self.connection.send(data)
        except ConnectionClosed as exc:
            self._recover(exc)
        return message_id

    def _recover(self, exc: ConnectionClosed | _NotServing) -> None:
        """Reconnect and resend what is waiting, or raise the close as a ``StreamClosed``."""
        self._note_failure(exc)
        for delay in self._retries.delays():
            time.sleep(delay)
            try:
                connection = self._open()
                for data in self._pipeline.resend():
                    connection.send(data)
            except _ATTEMPT_FAILURES as failure:
                self._retries.attempt_failed(failure)
                continue
            self._reconnected(connection)
            return
