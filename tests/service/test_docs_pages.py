"""The runnable examples of docs/websocket.md, sent to the app as a client would."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from starlette.testclient import TestClient

from .helpers import create

DOCS = Path(__file__).resolve().parents[2] / "docs"


def block(page: str, name: str) -> str:
    text = (DOCS / page).read_text()
    m = re.search(rf"<!-- {name}:start -->\s*```\w*\n(.*?)```\s*<!-- {name}:end -->", text, re.S)
    assert m is not None, f"docs/{page} has no {name} block"
    return m.group(1)


def documented_answers() -> list[dict[str, Any]]:
    """id, type and the keys each documented server message shows (they are shortened
    with `...`, so they are read by pattern, not parsed)."""
    answers = []
    for line in block("websocket.md", "ws-server-messages").strip().splitlines():
        head = re.match(r'\{"id": (\d+), "type": "(\w+)"(?:, "success": (true|false))?', line)
        assert head is not None, line
        answers.append(
            {
                "id": int(head.group(1)),
                "type": head.group(2),
                "success": None if head.group(3) is None else head.group(3) == "true",
                "error_code": (m.group(1) if (m := re.search(r'"code": "(\w+)"', line)) else None),
                "field": (m.group(1) if (m := re.search(r'"field": "([^"]+)"', line)) else None),
            }
        )
    return answers


def test_websocket_page_messages_get_the_documented_answers(client: TestClient) -> None:
    messages = [
        json.loads(line) for line in block("websocket.md", "ws-client-messages").split("\n") if line
    ]
    expected = documented_answers()
    assert [m["id"] for m in messages] == [a["id"] for a in expected]
    session = create(client, {"format": "example", "name": "panda_arm"})
    url = f"/v1/sessions/{session.id}/ws"
    with client.websocket_connect(url, headers=session.headers) as ws:
        for message in messages:
            ws.send_text(json.dumps(message))
        answers = [ws.receive_json() for _ in messages]
    for answer, doc in zip(answers, expected, strict=True):
        assert (answer["id"], answer["type"]) == (doc["id"], doc["type"])
        if doc["success"] is not None:
            assert answer["success"] is doc["success"], answer
        if doc["error_code"] is not None:
            assert answer["error"]["code"] == doc["error_code"]
            assert answer["error"]["field"] == doc["field"]
    frame, _pong, _error, clip, fk = answers
    assert frame["result"]["termination"] == "goal_reached"
    assert [r["id"] for r in clip["results"]] == [0, 1]
    assert clip["plan"]["largest_step_rad"] <= clip["plan"]["tracked_largest_step_rad"]
    # fk of the current pose (the clip's last answer): the tool on the clip's last target.
    assert fk["q"] == clip["results"][-1]["q"]
    (tool,) = fk["effectors"]
    target = messages[3]["frames"][-1]["targets"][0]
    assert tool["name"] == "tool" and tool["direction"] is None
    for key in ("x", "y", "z"):
        assert abs(tool["position"][key] - target["position"][key]) < 1e-3
    assert abs(abs(tool["orientation"]["x"]) - 1.0) < 1e-3


def test_operations_page_lists_every_setting_with_its_default() -> None:
    from service.config import Settings

    text = (DOCS / "operations.md").read_text()
    section = text[text.index("## Configuration") :]
    rows = dict(re.findall(r"^\| `(IK_[A-Z0-9_]+)` \| ([^|]+) \|", section, re.MULTILINE))
    assert set(rows) == {f"IK_{name.upper()}" for name in Settings.model_fields}
    for name, field in Settings.model_fields.items():
        documented = rows[f"IK_{name.upper()}"].strip().strip("`")
        default = field.default
        if hasattr(default, "get_secret_value"):
            default = default.get_secret_value()
        if default == "":
            assert documented == "empty", name
        elif default is None:  # the variable is not set: the solver's own default applies
            assert documented == "unset", name
        elif isinstance(default, bool):  # before int: a bool is one; documented as set
            assert documented == str(default).lower(), name
        elif isinstance(default, int | float):
            assert float(documented) == float(default), name
        else:
            assert documented == str(default), name
