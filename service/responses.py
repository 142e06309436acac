"""JSON responses rendered with orjson (FastAPI's ORJSONResponse is deprecated)."""

from __future__ import annotations

from typing import Any

import msgpack
import orjson
from starlette.responses import JSONResponse


def encodable(content: Any) -> Any:
    """``content`` with every string UTF-8 can encode: a lone surrogate (``"\\udc80"``,
    which JSON's ``\\u`` escapes let a client send) becomes its escape as text.

    Error messages echo what the client sent (a joint name, an effector, a field name);
    orjson and msgpack refuse such strings, and the error would become a 500."""
    if isinstance(content, str):
        return content.encode("utf-8", "backslashreplace").decode("utf-8")
    if isinstance(content, dict):
        return {encodable(k): encodable(v) for k, v in content.items()}
    if isinstance(content, list | tuple):
        return [encodable(v) for v in content]
    return content


def dumps(content: Any) -> bytes:
    """orjson with numpy support; floats stay float64 (the contract has no NaN/inf).

    The body ends with a newline, as curl's users expect (``curl .../readyz`` otherwise
    leaves the prompt on the JSON's line); JSON parsers skip it. WebSocket messages are
    encoded with ``dumps_message`` / ``packb_message``."""
    option = orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_APPEND_NEWLINE
    try:
        return orjson.dumps(content, option=option)
    except orjson.JSONEncodeError:  # a string UTF-8 cannot encode (rare: walk only then)
        return orjson.dumps(encodable(content), option=option)


def dumps_message(content: Any) -> str:
    """A WebSocket text message (as ``dumps``, without the newline)."""
    try:
        return orjson.dumps(content).decode()
    except orjson.JSONEncodeError:
        return orjson.dumps(encodable(content)).decode()


def packb_message(content: Any) -> bytes:
    """A WebSocket MessagePack message."""
    try:
        packed: bytes = msgpack.packb(content)
    except UnicodeEncodeError:
        packed = msgpack.packb(encodable(content))
    return packed


class ORJSONResponse(JSONResponse):
    """application/json rendered by orjson."""

    def render(self, content: Any) -> bytes:
        return dumps(content)
