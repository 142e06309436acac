"""The WebSocket protocol as an AsyncAPI 3.0 document, built from ``schemas/ws.py``.

Served at ``/asyncapi.json`` next to ``/openapi.json``. Every message's payload is the
JSON Schema pydantic generates for the model the server validates (client messages) or
renders (server messages) with, so the document cannot drift from the code; the close
codes come from ``service.errors.WS_CLOSE_CODES``. ``tests/live/test_asyncapi.py``
checks the messages a live server really sends and accepts against it.

AsyncAPI has no notion of a WebSocket close code: they are listed in the channel's
description and, machine-readable, in the specification extension ``x-close-codes``.
Payloads use AsyncAPI's default schema format (a superset of JSON Schema draft 07); the
only draft 2020-12 keyword pydantic emits for these models, ``discriminator`` as an
object, is not used because each message is its own payload (no union).
"""

from __future__ import annotations

from typing import Any, Final, NamedTuple

from pydantic import BaseModel
from pydantic.json_schema import JsonSchemaMode, models_json_schema

from schemas import ws
from schemas.errors import ErrorCode

from .errors import WS_CLOSE_CODES

ASYNCAPI_VERSION: Final = "3.0.0"
CHANNEL: Final = "session"
WS_ADDRESS: Final = "/v1/sessions/{session_id}/ws"
_REF: Final = "#/components/schemas/{model}"


class WsMessage(NamedTuple):
    """A message of the protocol: its ``type``, the model of its payload and a summary;
    for a client message, the server message that answers it (or an error, possible for
    every one)."""

    name: str
    model: type[BaseModel]
    summary: str
    reply: str | None = None


# What a client sends ...
CLIENT_MESSAGES: Final = (
    WsMessage("frame", ws.FrameMessage, "Solve one frame from the session's pose", "result"),
    WsMessage("clip", ws.ClipMessage, "Solve (or plan) a clip of frames", "clip_result"),
    WsMessage("fk", ws.FkMessage, "Forward kinematics of a pose, without moving it", "fk_result"),
    WsMessage("ping", ws.PingMessage, "Keep-alive and round-trip time", "pong"),
    WsMessage(
        "batch",
        ws.BatchMessage,
        "One frame for each of several sessions (many characters)",
        "batch_result",
    ),
)
# ... and what the server answers.
SERVER_MESSAGES: Final = (
    WsMessage("result", ws.ResultMessage, "A frame's result"),
    WsMessage("clip_result", ws.ClipResultMessage, "A clip's results, one per frame"),
    WsMessage(
        "fk_result",
        ws.FkResultMessage,
        "An fk message's pose, its effectors' world poses and (skeletons) bone data",
    ),
    WsMessage("pong", ws.PongMessage, "The answer to a ping"),
    WsMessage("batch_result", ws.BatchResultMessage, "A batch's results, one entry per frame"),
    WsMessage("error", ws.ErrorMessage, "A message that failed; the socket stays open"),
)
# The reason (an ErrorCode) each close code is sent with.
CLOSE_REASONS: Final[dict[int, tuple[ErrorCode | str, ...]]] = {
    1000: (),
    1008: (ErrorCode.INVALID_FORMAT, ErrorCode.SLOW_READER),
    1009: (ErrorCode.PAYLOAD_TOO_LARGE,),
    1011: (ErrorCode.INTERNAL_ERROR,),
    # At shutdown uvicorn closes the sockets with no message in flight itself, with no
    # reason; a socket whose message is being answered gets shutting_down.
    1012: (ErrorCode.SHUTTING_DOWN, ""),
    1013: (ErrorCode.TOO_MANY_WEBSOCKETS, ErrorCode.STORE_UNAVAILABLE),
    4401: (ErrorCode.UNAUTHORIZED,),
    4403: (ErrorCode.FORBIDDEN, ErrorCode.FORBIDDEN_ORIGIN),
    4404: (ErrorCode.NOT_FOUND,),
}

_DESCRIPTION: Final = """\
One WebSocket per session: `GET /v1/sessions/{session_id}/ws` with the session's token as
`Authorization: Bearer <token>`, as the subprotocol `ik.token.<token>` next to `ik.v1`
(browsers), or `?token=`. Messages are JSON text or MessagePack binary messages of the same
shapes; each answer uses the encoding of the message it answers. Every client message has
an `id` greater than the previous one on the connection; answers come in order and carry
it. `?results=compact` makes results CompactFrameResults. The close reason is an ErrorCode.
"""


# A message over IK_WS_MAX_MESSAGE_BYTES is refused by uvicorn's WebSocket protocol
# (--ws-max-size) before the application sees it: the close reason is then the websockets
# library's own text ("frame exceeds limit of N bytes"), not an ErrorCode.
LIBRARY_REASONS: Final = frozenset({1009})


def _close_codes() -> list[dict[str, Any]]:
    return [
        {
            "code": code,
            "reasons": [str(r) for r in CLOSE_REASONS[code]],
            "library_reason": code in LIBRARY_REASONS,
            "meaning": meaning,
        }
        for code, meaning in sorted(WS_CLOSE_CODES.items())
    ]


def _close_line(entry: dict[str, Any]) -> str:
    reasons = ", ".join(r or "(no reason)" for r in entry["reasons"]) or "(no reason)"
    if entry["library_reason"]:
        reasons += " (or the WebSocket library's own text)"
    return f"- {entry['code']} {reasons}: {entry['meaning']}"


def _message(message: WsMessage) -> dict[str, Any]:
    model = message.model
    return {
        "name": message.name,
        "title": model.__name__,
        "summary": message.summary,
        "description": (model.__doc__ or "").strip(),
        "contentType": "application/json",
        "payload": {"$ref": _REF.format(model=model.__name__)},
    }


def _schemas() -> dict[str, Any]:
    models: list[tuple[type[BaseModel], JsonSchemaMode]] = [
        (m.model, "validation") for m in CLIENT_MESSAGES
    ]
    models += [(m.model, "serialization") for m in SERVER_MESSAGES]
    _, top = models_json_schema(models, ref_template=_REF)
    schemas: dict[str, Any] = top.get("$defs", {})
    return schemas


def asyncapi_document(*, title: str, version: str) -> dict[str, Any]:
    """The AsyncAPI 3.0 document of the session WebSocket."""
    messages = CLIENT_MESSAGES + SERVER_MESSAGES
    channel_messages = {m.name: {"$ref": f"#/components/messages/{m.name}"} for m in messages}
    close_table = "\n".join(_close_line(c) for c in _close_codes())

    def message_ref(name: str) -> dict[str, str]:
        return {"$ref": f"#/channels/{CHANNEL}/messages/{name}"}

    operations: dict[str, Any] = {}
    for m in CLIENT_MESSAGES:
        assert m.reply is not None, f"client message {m.name} has no reply"
        operations[f"send_{m.name}"] = {
            "action": "send",
            "channel": {"$ref": f"#/channels/{CHANNEL}"},
            "summary": m.summary,
            "messages": [message_ref(m.name)],
            "reply": {
                "channel": {"$ref": f"#/channels/{CHANNEL}"},
                "messages": [message_ref(m.reply), message_ref("error")],
            },
        }
    for m in SERVER_MESSAGES:
        operations[f"receive_{m.name}"] = {
            "action": "receive",
            "channel": {"$ref": f"#/channels/{CHANNEL}"},
            "summary": m.summary,
            "messages": [message_ref(m.name)],
        }
    return {
        "asyncapi": ASYNCAPI_VERSION,
        "info": {
            "title": f"{title} WebSocket",
            "version": version,
            "description": _DESCRIPTION + "\nClose codes:\n" + close_table,
        },
        "defaultContentType": "application/json",
        "channels": {
            CHANNEL: {
                "address": WS_ADDRESS,
                "title": "A session's frame stream",
                "description": _DESCRIPTION,
                "parameters": {"session_id": {"description": "The session's id"}},
                "messages": channel_messages,
                "bindings": {
                    "ws": {
                        "method": "GET",
                        "query": {
                            "type": "object",
                            "properties": {
                                "results": {"type": "string", "enum": ["full", "compact"]},
                                "token": {"type": "string"},
                            },
                        },
                        "bindingVersion": "0.1.0",
                    }
                },
                "x-close-codes": _close_codes(),
            }
        },
        "operations": operations,
        "components": {
            "messages": {m.name: _message(m) for m in messages},
            "schemas": _schemas(),
        },
    }
