"""JSON responses rendered with orjson (FastAPI's ORJSONResponse is deprecated), static
files served with the caching their URLs allow, and the pages' Content-Security-Policy."""

from __future__ import annotations

import os
from typing import Any, Final

import msgpack
import orjson
from starlette.responses import JSONResponse, Response
from starlette.staticfiles import StaticFiles
from starlette.types import Scope

# A page's policy: every kind of source from the page's own origin only, and framed by
# that origin only; a page adds what it needs (django-csp's ``csp_update``). The order is
# the header's.
_CSP_DIRECTIVES: Final = (
    "default-src",
    "script-src",
    "style-src",
    "img-src",
    "font-src",
    "worker-src",
    "connect-src",
    "frame-ancestors",
)
_CSP_OPTIONAL: Final = frozenset({"font-src", "worker-src"})  # only when a page adds sources


def content_security_policy(**also: str) -> str:
    """The strict policy plus the sources ``also`` allows per directive, ``_`` for ``-``:
    ``content_security_policy(img_src="data:")`` allows ``img-src 'self' data:``."""
    extra = {name.replace("_", "-"): sources for name, sources in also.items()}
    if unknown := extra.keys() - set(_CSP_DIRECTIVES):
        raise ValueError(f"unknown CSP directives: {sorted(unknown)}")
    return "; ".join(
        f"{directive} 'self' {extra[directive]}" if directive in extra else f"{directive} 'self'"
        for directive in _CSP_DIRECTIVES
        if directive in extra or directive not in _CSP_OPTIONAL
    )


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


class CachedStaticFiles(StaticFiles):
    """Static files, each response with the ``Cache-Control`` given: ``"no-cache"``
    for URLs that carry no version (revalidated on every load), a year and immutable
    for versioned ones."""

    def __init__(self, *, cache_control: str, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.cache_control = cache_control

    def file_response(
        self,
        full_path: str | os.PathLike[str],
        stat_result: os.stat_result,
        scope: Scope,
        status_code: int = 200,
    ) -> Response:
        response = super().file_response(full_path, stat_result, scope, status_code)
        response.headers["Cache-Control"] = self.cache_control
        return response
