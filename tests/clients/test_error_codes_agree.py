"""Both clients know exactly the service's error codes (``schemas.ErrorCode``): a code
added to the service and not to a client would reach that client's users untyped."""

from __future__ import annotations

import re
from pathlib import Path

import ik_client

import schemas

ROOT = Path(__file__).resolve().parents[2]


def test_python_client_codes_are_the_services() -> None:
    assert {c.value for c in ik_client.ErrorCode} == {c.value for c in schemas.ErrorCode}


def test_each_code_has_one_python_exception() -> None:
    """``service_error`` raises a code's own class; ``ServerFault`` only for unknown codes."""
    listed = [code for kind in ik_client.ServiceError.__subclasses__() for code in kind.codes]
    assert sorted(listed) == sorted(ik_client.ErrorCode)
    for code in ik_client.ErrorCode:
        assert code in type(ik_client.errors.service_error(code, "")).codes
    assert type(ik_client.errors.service_error("a_code_of_tomorrow", "")) is ik_client.ServerFault


def test_typescript_client_codes_are_the_services() -> None:
    source = (ROOT / "clients/typescript/src/errors.ts").read_text()
    block = re.search(r"export const ErrorCode = \{(.*?)\}", source, re.DOTALL)
    assert block is not None, "clients/typescript/src/errors.ts has no ErrorCode object"
    values = set(re.findall(r':\s*"([a-z_]+)"', block.group(1)))
    assert values == {c.value for c in schemas.ErrorCode}
