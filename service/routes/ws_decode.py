"""Reading one WebSocket message: bytes or text -> the fast path's frame, a batch's
envelope, or a validated client message; else ``Unreadable`` with the one error the
client is told (``invalid_format``: its message, its field, the message's id when the
id can be read).

A WebSocket error message carries one error, where an HTTP 422 lists them all, so the
one chosen is the most helpful (``errors.most_helpful``): a misspelt ``target`` is told
"did you mean 'targets'?", not only that ``targets`` is missing.
"""

from __future__ import annotations

from typing import Any

import msgpack
import orjson
from pydantic import TypeAdapter, ValidationError
from pydantic_core import from_json

import schemas as S

from .. import convert, hints
from ..convert import ChainView, FastFrame
from ..errors import echoable_id, field_path, most_helpful
from .ws_batch import RawBatch, raw_batch

ClientMessage = S.FrameMessage | S.ClipMessage | S.BatchMessage | S.FkMessage | S.PingMessage
_CLIENT_MESSAGE: TypeAdapter[ClientMessage] = TypeAdapter(S.ClientMessage)
# pydantic's error types, at the message's top level, for a message whose ``type`` is
# missing or unknown, or that is not an object at all: answered with the types there are
# (dict_type from JSON, model_attributes_type from MessagePack).
_NO_MESSAGE_TYPE = frozenset(
    {"union_tag_not_found", "union_tag_invalid", "dict_type", "model_attributes_type"}
)


class Unreadable(Exception):
    """A message that is not a valid client message: answered ``invalid_format``."""

    def __init__(self, msg_id: int | None, message: str, field: str | None = None) -> None:
        super().__init__(message)
        self.msg_id = msg_id
        self.message = message
        self.field = field


def decode(
    data: str | bytes, binary: bool, view: ChainView
) -> FastFrame | RawBatch | ClientMessage:
    """A well-formed frame as the fast path's ``(id, targets)`` (convert.fast_frame), a
    batch as its entries (ws_batch.raw_batch: each is read on its own); any other
    message validated by pydantic, which gives the documented error.

    Raises:
        Unreadable: not JSON / MessagePack, or not a valid client message.
    """
    raw: Any = None
    if binary:
        try:
            raw = msgpack.unpackb(data, raw=False, strict_map_key=True)
        except Exception as e:  # msgpack's errors share no useful base class
            raise Unreadable(raw_id(_lenient(data, binary)), _not_msgpack(e, data)) from None
    else:
        try:
            raw = orjson.loads(data)
        except orjson.JSONDecodeError:
            pass  # validate_json below says why
    if raw is not None and (fast := convert.fast_frame(raw, view)) is not None:
        return fast
    if (envelope := raw_batch(raw)) is not None:
        return envelope
    try:
        if binary:
            return _CLIENT_MESSAGE.validate_python(raw)
        # validate_json, not validate_python(raw): JSON mode is the documented schema
        return _CLIENT_MESSAGE.validate_json(data)
    except ValidationError as e:
        if raw is None:  # orjson refused it: NaN, Infinity, 1e400 (still an object)
            raw = _lenient(data, binary)
        if binary and (key := _bytes_key(raw)) is not None:
            message = "a MessagePack map key must be a string, and this message has the bin "
            message += f"key {key!r} (bytes packed as bin: pack the keys as str)"
            raise Unreadable(raw_id(raw), message) from None
        error = most_helpful(e.errors())
        message, field = str(error["msg"]), field_path(error["loc"])
        if field is None and error["type"] in _NO_MESSAGE_TYPE:
            message, field = hints.message_type_hint(raw), "type"
        raise Unreadable(raw_id(raw), message, field) from None


def raw_id(raw: Any) -> int | None:
    """The id of a message that failed validation, if an error may echo it."""
    return echoable_id(raw.get("id")) if isinstance(raw, dict) else None


def _lenient(data: str | bytes, binary: bool) -> Any:
    """A message the strict decoders refused, read by a lenient one, for its id and
    type only: JSON with ``NaN``, ``Infinity`` or a number beyond float64 (which orjson
    refuses and pydantic's JSON mode reports by field), MessagePack with a key that is
    not a string. None if unreadable even so (or nested too deep)."""
    try:
        if binary:
            return msgpack.unpackb(data, raw=False, strict_map_key=False)
        return from_json(data, allow_inf_nan=True)
    except Exception:
        return None


def _not_msgpack(e: Exception, data: bytes | str) -> str:
    """What a client is told of a binary message msgpack cannot read. A map key that
    is not a string is valid MessagePack that msgpack refuses (``strict_map_key``, a
    guard against hash flooding); it is told as such, not as unreadable bytes. JSON in
    a binary frame (a ``ClientWebSocket`` sending bytes) is told to go as text."""
    text = str(e)
    if type(e) is ValueError and "not allowed for map key" in text:
        kind = text.split(" ", 1)[0]
        return f"a MessagePack map key must be a string, and this message has a key of type {kind}"
    try:
        json_object = isinstance(orjson.loads(data), dict)
    except orjson.JSONDecodeError:
        json_object = False
    if json_object:
        return "a binary message is read as MessagePack and this one is JSON: send JSON as text"
    return f"not MessagePack: {type(e).__name__}" + (f" ({text})" if text else "")


def _bytes_key(raw: Any, depth: int = 0) -> bytes | None:
    """The first bin (bytes) map key in a decoded MessagePack message, if any: msgpack
    lets them through ``strict_map_key``, and the schema would only say a key is
    missing. Looked for on the error path only, 32 levels deep at most."""
    if depth > 32:
        return None
    if isinstance(raw, dict):
        for k, v in raw.items():
            if isinstance(k, bytes):
                return k
            if (found := _bytes_key(v, depth + 1)) is not None:
                return found
    elif isinstance(raw, list):
        for v in raw:
            if (found := _bytes_key(v, depth + 1)) is not None:
                return found
    return None
