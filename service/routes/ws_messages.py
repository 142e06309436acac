"""The WebSocket's server messages: one builder per envelope (Home Assistant's
``websocket_api/messages.py``: ``result_message`` / ``error_message``).

Every answer the socket sends is built here, so its shape is in one place; the schemas
are ``schemas.ws`` (``ResultMessage``, ``ClipResultMessage``, ``BatchResultMessage``,
``ErrorMessage``, ``PongMessage``), which tests validate the answers against.
"""

from __future__ import annotations

from typing import Any, TypedDict

from schemas import ErrorCode


def result_message(msg_id: int, result: dict[str, Any]) -> dict[str, Any]:
    """The answer to a ``frame``: one rendered frame result."""
    return {"id": msg_id, "type": "result", "success": result["success"], "result": result}


def clip_result_message(
    msg_id: int, results: list[dict[str, Any]], plan: dict[str, Any] | None
) -> dict[str, Any]:
    """The answer to a ``clip``: its frames' results, ``plan`` set when planned."""
    success = all(r["success"] for r in results)
    return {
        "id": msg_id,
        "type": "clip_result",
        "success": success,
        "results": results,
        "plan": plan,
    }


def batch_result_message(msg_id: int, results: list[dict[str, Any]]) -> dict[str, Any]:
    """The answer to a ``batch``: each entry's result or error, in order."""
    success = all(r["success"] for r in results)
    return {"id": msg_id, "type": "batch_result", "success": success, "results": results}


def fk_result_message(msg_id: int, fk: dict[str, Any]) -> dict[str, Any]:
    """The answer to an ``fk``: the pose used, its effectors' world poses and, on
    skeleton chains, its bone data (an ``FkResult``)."""
    return {"id": msg_id, "type": "fk_result", **fk}


def pong_message(msg_id: int) -> dict[str, Any]:
    """The answer to a ``ping``."""
    return {"id": msg_id, "type": "pong"}


class ErrorDetails(TypedDict, total=False):
    """What an error message may add to its code and message."""

    field: str | None  # path of the offending field (frame.targets[0].position.x)
    retry_after_s: float | None  # when to send it again [s]


def error_message(
    msg_id: int | None,
    code: ErrorCode,
    message: str,
    field: str | None = None,
    retry_after_s: float | None = None,
) -> dict[str, Any]:
    """A recoverable error: message ``msg_id`` (None when it could not be read) failed."""
    error: dict[str, Any] = {"code": code.value, "message": message}
    if field is not None:
        error["field"] = field
    if retry_after_s is not None:
        error["retry_after_s"] = retry_after_s
    return {"id": msg_id, "type": "result", "success": False, "error": error}
