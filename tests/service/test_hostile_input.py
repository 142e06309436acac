"""Any string anywhere gets a clear error, never a 500 (issue 23): lone surrogates (JSON's
``\\u`` escapes let a client send them, orjson and msgpack cannot encode them back),
control characters and 1 MB strings, in every key and value of every body the API takes.

Each test starts from a valid body and puts one hostile string in one place: a value, a
key, or a new key, anywhere in the tree (hypothesis picks the place and the string).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from starlette.testclient import TestClient

from schemas.chain import EXAMPLE_ARM
from service.config import Settings

from .helpers import create, hand_frame

MEGABYTE = 1_000_000
hostile_text = st.one_of(
    st.sampled_from(["\udc80", "\ud800x", "x\udfff", "\x00", "\x1b[2J", "\u202e", "\ufeff"]),
    st.text(st.characters(categories=["Cs", "Cc", "Zl", "Co"]), min_size=1, max_size=8),
    st.text(max_size=8),
    st.sampled_from(["x" * MEGABYTE, "\udc80" * 1000, "\x00" * 1000]),
)
settings_ = settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)

FRAME = hand_frame(1)
BODIES: dict[str, dict[str, Any]] = {
    "create": {
        "chain": EXAMPLE_ARM,
        "options": {"time_budget_us": 1000, "max_iter": 50},
        "initial_pose": {"joints": {"elbow": 1.0, "shoulder": [0.1, 0.2]}},
    },
    "pose": {"joints": {"elbow": 0.5}},
    "options": {"time_budget_us": 500, "position_tolerance_m": 0.001},
    "frame": FRAME,
    "clip": {"frames": [hand_frame(2), hand_frame(3)], "plan": False},
    "solve": {
        "chain": EXAMPLE_ARM,
        "targets": FRAME["targets"],
        "seed": {"joints": {"elbow": 1.0}},
        "options": {"time_budget_us": 1000},
    },
}


def _places(tree: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every path to a value in ``tree`` (dict keys and list indices)."""
    out = [path]
    if isinstance(tree, dict):
        for k, v in tree.items():
            out.extend(_places(v, (*path, k)))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            out.extend(_places(v, (*path, i)))
    return out


@st.composite
def hostile(draw: st.DrawFn, body: dict[str, Any]) -> Any:
    """``body`` with one hostile string: as a value, as a key, or as a new key."""
    tree = json.loads(json.dumps(body))  # a deep copy
    path = draw(st.sampled_from(_places(tree)))
    text = draw(hostile_text)
    how = draw(st.sampled_from(["value", "rename", "add"]))
    if not path:  # the root: a body that is a string, or a new key at the top
        if how == "value":
            return text
        tree[text] = 1.0
        return tree
    parent = tree
    for step in path[:-1]:
        parent = parent[step]
    last = path[-1]
    if how == "value" or isinstance(parent, list):
        parent[last] = text
    elif how == "rename":
        parent[text] = parent.pop(last)
    else:
        parent[text] = parent[last]
    return tree


def _json(body: Any) -> bytes:
    # ensure_ascii: a lone surrogate goes over the wire as JSON's \udc80 escape.
    return json.dumps(body, ensure_ascii=True).encode()


# An error names what was wrong, but does not echo a 1 MB string back in full.
MAX_ERROR_BYTES = 50_000


def _answered_clearly(status: int, body: bytes) -> None:
    assert status < 500, body[:500]
    if status >= 400:
        assert len(body) < MAX_ERROR_BYTES, body[:500]
        reply = json.loads(body)
        assert reply["code"] and isinstance(reply["detail"], str | list)


@pytest.fixture
def client(make_client: Callable[..., TestClient]) -> TestClient:
    # Each example creates a session: more than one address may create per minute.
    return make_client(Settings(sessions_per_address_per_min=0))


@settings_
@given(data=st.data())
def test_session_bodies(client: TestClient, data: st.DataObject) -> None:
    s = create(client)
    url = f"/v1/sessions/{s.id}"
    for method, path, name in [
        ("POST", "/v1/sessions", "create"),
        ("PUT", f"{url}/pose", "pose"),
        ("PATCH", url, "options"),
        ("POST", f"{url}/frames", "frame"),
        ("POST", f"{url}/frames", "clip"),
        ("POST", "/v1/solve", "solve"),
    ]:
        body = data.draw(hostile(BODIES[name]), label=name)
        r = client.request(
            method,
            path,
            content=_json(body),
            headers={**s.headers, "content-type": "application/json"},
        )
        _answered_clearly(r.status_code, r.content)
    client.delete(url, headers=s.headers)


@settings_
@given(data=st.data())
def test_websocket_messages(client: TestClient, data: st.DataObject) -> None:
    s = create(client)
    messages = [
        {"type": "frame", **hand_frame(1)},
        {"type": "clip", "id": 1, "frames": [hand_frame(2)]},
        {"type": "ping", "id": 1},
    ]
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        for i, message in enumerate(messages):
            body = data.draw(hostile(message), label=message["type"])
            if isinstance(body, dict) and isinstance(body.get("id"), int):
                body["id"] = 10 * data.draw(st.integers(0, 1000)) + i  # any order
            if data.draw(st.booleans(), label="msgpack"):
                ws.send_bytes(msgpack.packb(body, unicode_errors="surrogatepass"))
                raw: bytes | str = ws.receive_bytes()
                reply = msgpack.unpackb(raw)
            else:
                ws.send_text(_json(body).decode())
                raw = ws.receive_text()
                reply = json.loads(raw)
            assert len(raw) < MAX_ERROR_BYTES, raw[:500]
            assert reply["type"] in {"result", "clip_result", "pong"}, reply
            error = reply.get("error") or {}
            assert error.get("code") != "internal_error", reply
