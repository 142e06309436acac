"""schemas.ErrorCode is the one list of error codes: docs/api.md, the table in
service/errors.py and the OpenAPI schema say the same, and every code is described."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from pydantic import ValidationError

import schemas as S
from schemas import ERROR_CODE_DESCRIPTIONS, ErrorCode
from service import errors
from service.config import Settings
from service.main import create_app

ROOT = Path(__file__).resolve().parents[2]
ENUM_CODES = {code.value for code in ErrorCode}


def _markdown_table_codes(text: str, header: str) -> list[str]:
    """The backticked first cells of the Markdown table whose header row is ``header``."""
    lines = text.splitlines()
    start = lines.index(header)
    codes = []
    for line in lines[start + 2 :]:  # past the header and its |---| row
        if not line.startswith("|"):
            break
        cell = line.split("|")[1].strip()
        codes.extend(re.findall(r"`([a-z_]+)`", cell))
    return codes


def test_docs_api_lists_exactly_the_enum_codes() -> None:
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    listed = _markdown_table_codes(text, "| code | HTTP | when |")
    assert len(listed) == len(set(listed)), "a code listed twice"
    assert set(listed) == ENUM_CODES


def test_service_errors_table_lists_exactly_the_enum_codes() -> None:
    doc = errors.__doc__ or ""
    # reST simple table: rows between the second and third ==== rule lines.
    rules = [i for i, line in enumerate(doc.splitlines()) if line.startswith("====")]
    rows = doc.splitlines()[rules[1] + 1 : rules[2]]
    listed = [row.split()[0] for row in rows]
    assert len(listed) == len(set(listed))
    assert set(listed) == ENUM_CODES


def test_every_code_has_a_description() -> None:
    assert set(ERROR_CODE_DESCRIPTIONS) == set(ErrorCode)
    assert all(text.strip() for text in ERROR_CODE_DESCRIPTIONS.values())


def test_openapi_lists_and_describes_every_code() -> None:
    schema = create_app(Settings()).openapi()
    code = schema["components"]["schemas"]["ErrorCode"]
    assert set(code["enum"]) == ENUM_CODES
    assert set(code["x-enumDescriptions"]) == ENUM_CODES
    for value in ENUM_CODES:
        assert f"`{value}`" in code["description"]
    body = schema["components"]["schemas"]["ErrorBody"]
    assert body["properties"]["code"]["$ref"] == "#/components/schemas/ErrorCode"


def test_error_bodies_and_messages_accept_codes_and_refuse_others() -> None:
    body = S.ErrorBody.model_validate({"detail": "x", "code": "not_found"})
    assert body.code is ErrorCode.NOT_FOUND
    payload = S.ErrorPayload.model_validate({"code": "id_reuse", "message": "x"})
    assert payload.code is ErrorCode.ID_REUSE
    with pytest.raises(ValidationError):
        S.ErrorBody.model_validate({"detail": "x", "code": "no_such_code"})
    with pytest.raises(ValidationError):
        S.ErrorPayload.model_validate({"code": "no_such_code", "message": "x"})
