"""Floors: the same protocol surface as the service, with no solving behind it.

What a frame costs when nothing is solved, measured by the same generator in the same
run: a bare WebSocket echo (the frame message is sent back as it came) and a bare FastAPI
JSON endpoint (the body parsed into a dict, a one-result answer encoded). The service is
judged against them: WebSocket frames/s at least 50% of the echo's, HTTP at least 70%
of the bare endpoint's.

Serve with ``python -m loadtest.serve --app floors`` (same uvicorn settings as the service).
"""

from __future__ import annotations

import secrets
from typing import Any

from fastapi import FastAPI, WebSocket
from fastapi.responses import JSONResponse
from starlette import status


def create_floor_app() -> FastAPI:
    """Session creation, WebSocket and HTTP frames at the service's paths; no solver."""
    app = FastAPI(openapi_url=None, docs_url=None, redoc_url=None)

    @app.get("/readyz")
    async def readyz() -> dict[str, str]:
        """Always ready: nothing to warm up."""
        return {"status": "ready"}

    @app.post("/v1/sessions", status_code=status.HTTP_201_CREATED)
    async def create_session(body: dict[str, Any]) -> dict[str, str]:
        """An id and a token, so the generator runs unchanged; nothing is stored."""
        return {"id": secrets.token_hex(16), "token": "floor"}

    @app.websocket("/v1/sessions/{session_id}/ws")
    async def echo(ws: WebSocket, session_id: str) -> None:
        """Bare echo: every text message goes back as it came."""
        await ws.accept()
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            text = message.get("text")
            if text is not None:
                await ws.send_text(text)

    @app.post("/v1/sessions/{session_id}/frames")
    async def frames(session_id: str, body: dict[str, Any]) -> JSONResponse:
        """Bare endpoint: the body parsed by FastAPI, a one-result JSON answer."""
        return JSONResponse({"results": [{"id": body.get("id"), "termination": "echo"}]})

    return app
