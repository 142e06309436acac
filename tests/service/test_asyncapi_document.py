"""/asyncapi.json names every WebSocket message schemas/ws.py defines.

service/asyncapi.py lists the messages explicitly (each with its summary and the answers
it may get); this fails when a message type is added to schemas/ws.py and not there.
The live checks of the document are in tests/live/test_asyncapi.py.
"""

from __future__ import annotations

from typing import get_args

from schemas import ws
from service.asyncapi import CLIENT_MESSAGES, SERVER_MESSAGES


def test_every_client_message_type_is_in_the_document() -> None:
    assert {m.name for m in CLIENT_MESSAGES} == set(ws.CLIENT_MESSAGE_TYPES)
    # Each is answered by a server message of the document.
    assert {m.reply for m in CLIENT_MESSAGES} <= {m.name for m in SERVER_MESSAGES}


def test_every_server_message_model_is_in_the_document() -> None:
    assert {m.model for m in SERVER_MESSAGES} == set(get_args(ws.ServerMessage))
