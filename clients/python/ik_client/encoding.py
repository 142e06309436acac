"""How the client writes what it sends and reads what it gets: JSON (with orjson when
it is installed) and MessagePack, NaN and infinity refused naming the field, a UUID or an
enum member written alike in every encoding. The HTTP calls (``json_body``) and the
stream's messages use the same rules, so a body is refused or accepted alike by both.
"""

from __future__ import annotations

import enum
import functools
import json
import math
import re
import uuid
from collections.abc import Callable
from typing import Any

import msgpack

from .errors import EncodeError, UnexpectedAnswer
from .types import Encoding

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


def decode_answer(data: str | bytes) -> dict[str, Any]:
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


def encode_message(payload: dict[str, Any], encoding: Encoding) -> str | bytes:
    """``payload``, a stream message with its id, in ``encoding``.

    Raises:
        EncodeError: ``payload`` cannot be written (a ValueError and a TypeError too).
    """
    try:
        if encoding is Encoding.MSGPACK:
            return _packb(payload)
        return _dumps(payload)
    except EncodeError:
        raise
    except (TypeError, ValueError, OverflowError) as exc:  # a dataclass, a cycle, 2**64
        raise EncodeError(f"the message cannot be written as {encoding.value}: {exc}") from exc
