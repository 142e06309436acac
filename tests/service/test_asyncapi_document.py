"""/asyncapi.json names every WebSocket message schemas/ws.py defines.

service/asyncapi.py lists the messages explicitly (each with its summary and the answers
it may get); this fails when a message type is added to schemas/ws.py and not there.
The live checks of the document are in tests/live/test_asyncapi.py.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import get_args

from schemas import ErrorCode, ws
from schemas.common import ErrorPayload
from service.asyncapi import CLIENT_MESSAGES, SERVER_MESSAGES, asyncapi_document

ROOT = Path(__file__).resolve().parents[2]
# The codes a WebSocket error message carries retry_after_s with (service/errors.py,
# service/work.py, service/solving.py; shutting_down: service/routes/ws.py).
RETRY_CODES = (
    ErrorCode.NOT_READY,
    ErrorCode.RATE_LIMITED,
    ErrorCode.PLANS_BUSY,
    ErrorCode.TOO_MANY_PLANS,
    ErrorCode.SERVER_BUSY,
    ErrorCode.TOO_MUCH_WORK,
    ErrorCode.STORE_UNAVAILABLE,
    ErrorCode.SHUTTING_DOWN,
)


def test_every_client_message_type_is_in_the_document() -> None:
    assert {m.name for m in CLIENT_MESSAGES} == set(ws.CLIENT_MESSAGE_TYPES)
    # Each is answered by a server message of the document.
    assert {m.reply for m in CLIENT_MESSAGES} <= {m.name for m in SERVER_MESSAGES}


def test_every_server_message_model_is_in_the_document() -> None:
    assert {m.model for m in SERVER_MESSAGES} == set(get_args(ws.ServerMessage))


def _close_table(markdown: str) -> dict[int, set[str]]:
    """docs/websocket.md's close codes: code -> the reasons its rows name."""
    section = markdown.split("## Close codes", 1)[1].split("\n## ", 1)[0]
    table: dict[int, set[str]] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 3 and cells[0].isdigit():
            reasons = set(re.findall(r"`([a-z_]+)`", cells[1]))
            table.setdefault(int(cells[0]), set()).update(reasons)
    return table


def test_the_documents_close_codes_are_those_websocket_md_lists() -> None:
    """The AsyncAPI document and the page a client developer reads name the same close
    codes with the same reasons (the document once lacked 1013 store_unavailable)."""
    documented = _close_table((ROOT / "docs" / "websocket.md").read_text())
    in_document = {
        entry["code"]: {r for r in entry["reasons"] if r}
        for entry in asyncapi_document(title="t", version="0")["channels"]["session"][
            "x-close-codes"
        ]
    }
    assert in_document == documented


def test_retry_after_is_described_for_every_code_that_carries_it_on_the_websocket() -> None:
    """ErrorPayload's description and docs/websocket.md's sentence name the same codes:
    those a WebSocket error carries ``retry_after_s`` with."""
    description = ErrorPayload.model_fields["retry_after_s"].description or ""
    page = " ".join((ROOT / "docs" / "websocket.md").read_text().split())
    sentence = page.split(" errors carry `retry_after_s`", 1)[0].rsplit(". ", 1)[-1]
    assert set(re.findall(r"`([a-z_]+)`", sentence)) == {c.value for c in RETRY_CODES}
    named = {c.value for c in ErrorCode if re.search(rf"\b{c.value}\b", description)}
    assert named == {c.value for c in RETRY_CODES}
