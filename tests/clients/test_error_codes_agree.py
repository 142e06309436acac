"""Both clients know exactly the service's error codes (``schemas.ErrorCode``, and the
Python client the termination codes: its copy is generated, tests/clients/client_codes.py) and
WebSocket close codes (``service.errors.WS_CLOSE_CODES``): the clients mirror them (they
are packages of their own and do not import the server), and a code added to the
service and not to a client would reach that client's users untyped."""

from __future__ import annotations

import re
from pathlib import Path

import ik_client

import schemas
from service.errors import WS_CLOSE_CODES
from solver.optim.termination import Termination

from . import client_codes

ROOT = Path(__file__).resolve().parents[2]
# The codes a client can see: the server's, and 1006 (a drop, which no server sends).
CLOSE_CODES = set(WS_CLOSE_CODES) | {1006}


def typescript_object(name: str, file: str) -> str:
    """The body of ``export const <name> = { ... }`` in clients/typescript/src/<file>."""
    source = (ROOT / "clients/typescript/src" / file).read_text()
    block = re.search(rf"export const {name}[^=]*= \{{(.*?)\}}", source, re.DOTALL)
    assert block is not None, f"clients/typescript/src/{file} has no {name} object"
    return block.group(1)


def test_python_client_codes_are_the_services() -> None:
    """ik_client/codes.py is what tests/clients/client_codes.py renders from the service."""
    assert client_codes.CODES_FILE.read_text() == client_codes.render(), (
        "ik_client/codes.py is stale: python -m tests.clients.client_codes"
    )
    assert {c.value for c in ik_client.ErrorCode} == {c.value for c in schemas.ErrorCode}
    assert {t.value for t in ik_client.Termination} == {t.value for t in Termination}


def test_each_code_has_one_python_exception() -> None:
    """``service_error`` raises a code's own class; ``ServerFault`` only for unknown codes."""
    listed = [code for kind in ik_client.ServiceError.__subclasses__() for code in kind.codes]
    assert sorted(listed) == sorted(ik_client.ErrorCode)
    for code in ik_client.ErrorCode:
        assert code in type(ik_client.errors.service_error(code, "")).codes
    assert type(ik_client.errors.service_error("a_code_of_tomorrow", "")) is ik_client.ServerFault


def test_typescript_client_codes_are_the_services() -> None:
    values = set(re.findall(r':\s*"([a-z_]+)"', typescript_object("ErrorCode", "errors.ts")))
    assert values == {c.value for c in schemas.ErrorCode}


def test_python_client_close_codes_are_the_services() -> None:
    assert {int(c) for c in ik_client.CloseCode} == CLOSE_CODES
    assert set(ik_client.CLOSE_CODE_MEANINGS) == CLOSE_CODES


def test_typescript_client_close_codes_are_the_services() -> None:
    codes = typescript_object("CloseCode", "errors.ts")
    assert {int(c) for c in re.findall(r":\s*(\d+)", codes)} == CLOSE_CODES
    meanings = typescript_object("CLOSE_CODE_MEANINGS", "errors.ts")
    assert {int(c) for c in re.findall(r"^\s*(\d+):", meanings, re.MULTILINE)} == CLOSE_CODES
