"""The stream's messages in flight: the ids it gives (the caller's, and the wire's, one
counter over every connection), each message as first sent, what still waits for an
answer, in order, and what was dropped unsent while reconnecting. No I/O.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from ..encoding import decode_answer, encode_message
from ..errors import UnexpectedAnswer, service_error
from ..queued import SendQueue
from ..types import (
    Answer,
    BatchAnswer,
    BatchEntryResult,
    ClipAnswer,
    ClipResult,
    Encoding,
    FkAnswer,
    FkResult,
    FrameAnswer,
    FrameResult,
    Pong,
)
from .recovery import NotServing


@dataclass(slots=True)
class _Message:
    id: int  # the id the caller was given
    wire_id: int  # the id it carries on every connection
    # The message as first sent, id included: a reconnect sends these bytes again. A new
    # encoding of the body could differ (the caller may have changed its dicts since)
    # or fail, and the server recognises a resent message by its id and content.
    data: str | bytes


class Pipeline:
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
        data = encode_message({**body, "id": self._next_wire_id}, self.encoding)
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
            outage: The error codes that are part of an outage now (``Retries.outage``):
                such an answer is not the message's.

        Raises:
            ServiceError: The message was answered with an error (its subclass by code).
            NotServing: The server cannot serve the message now but another connection
                can; it stays waiting, to be sent again.
        """
        envelope = decode_answer(data)
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
                raise NotServing.of(error)
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
