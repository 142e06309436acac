"""JSON responses rendered with orjson (FastAPI's ORJSONResponse is deprecated)."""

from __future__ import annotations

from typing import Any

import orjson
from starlette.responses import JSONResponse


def dumps(content: Any) -> bytes:
    """orjson with numpy support; floats stay float64 (the contract has no NaN/inf).

    The body ends with a newline, as curl's users expect (``curl .../readyz`` otherwise
    leaves the prompt on the JSON's line); JSON parsers skip it. WebSocket messages are
    encoded elsewhere (service/routes/ws.py) and stay as they are."""
    return orjson.dumps(content, option=orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_APPEND_NEWLINE)


class ORJSONResponse(JSONResponse):
    """application/json rendered by orjson."""

    def render(self, content: Any) -> bytes:
        return dumps(content)
