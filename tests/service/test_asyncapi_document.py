"""/asyncapi.json names every WebSocket message schemas/ws.py defines.

service/asyncapi.py lists the messages explicitly (each with its summary and the answers
it may get); this fails when a message type is added to schemas/ws.py and not there.
The live checks of the document are in tests/live/test_asyncapi.py.
"""

from __future__ import annotations

from typing import get_args

from schemas import ws
from service.asyncapi import CLIENT_MESSAGES, REPLIES, SERVER_MESSAGES


def test_every_client_message_type_is_in_the_document() -> None:
    assert {name for name, _, _ in CLIENT_MESSAGES} == set(ws.CLIENT_MESSAGE_TYPES)
    assert set(REPLIES) == set(ws.CLIENT_MESSAGE_TYPES)


def test_every_server_message_model_is_in_the_document() -> None:
    assert {model for _, model, _ in SERVER_MESSAGES} == set(get_args(ws.ServerMessage))
