"""Writes the Python client's mirror of the service's codes, ``ik_client/codes.py``.

The client is a package of its own and does not import the server, so it holds a copy of
``schemas.ErrorCode`` and ``solver.optim.Termination``; this module renders that copy from
them, with each code's description as its docstring (Home Assistant's generated modules,
``script/hassfest``, work the same way). tests/clients/test_error_codes_agree.py fails
when the file is stale; rewrite it with

    python -m tests.clients.client_codes
"""

from __future__ import annotations

import enum
import textwrap
from collections.abc import Mapping
from pathlib import Path

from schemas.errors import ERROR_CODE_DESCRIPTIONS, ErrorCode
from solver.optim.termination import TERMINATION_MESSAGES, Termination

CODES_FILE = Path(__file__).resolve().parents[2] / "clients/python/ik_client/codes.py"

HEADER = '''\
"""The service's error codes and termination codes (generated: do not edit).

Written by ``python -m tests.clients.client_codes`` from ``schemas/errors.py`` and
``solver/optim/termination.py``; tests/clients/test_error_codes_agree.py fails when it
is stale.
"""

from __future__ import annotations

import enum
'''


def _docstring(text: str) -> str:
    """``text`` as a member docstring, wrapped at 100 columns."""
    lines = textwrap.wrap(text, width=100 - len('    """""'))
    return "    " + '"""' + "\n    ".join(lines) + '"""\n'


def _enum(name: str, doc: str, descriptions: Mapping[enum.StrEnum, str]) -> str:
    members = "".join(
        f'    {code.name} = "{code.value}"\n' + _docstring(text)
        for code, text in descriptions.items()
    )
    return f'\n\nclass {name}(enum.StrEnum):\n    """{doc}"""\n\n{members}'


def render() -> str:
    """The text ``ik_client/codes.py`` must hold."""
    assert list(ERROR_CODE_DESCRIPTIONS) == list(ErrorCode), "a code without a description"
    assert list(TERMINATION_MESSAGES) == list(Termination), "a code without a message"
    return (
        HEADER
        + _enum(
            "ErrorCode",
            "The service's stable error codes (docs/api.md and docs/websocket.md, Errors).",
            ERROR_CODE_DESCRIPTIONS,
        )
        + _enum(
            "Termination",
            "How the optimizer's last pass ended (docs/api.md, Termination codes).",
            TERMINATION_MESSAGES,
        )
    )


if __name__ == "__main__":
    CODES_FILE.write_text(render())
    print(f"wrote {CODES_FILE}")
