"""/asyncapi.json against what a live server really sends, accepts and closes with.

The document itself is validated against the AsyncAPI 3.0.0 JSON Schema (copied unchanged
from the npm package @asyncapi/specs 6.11.1, Apache-2.0: tests/schemas/asyncapi/). Then a
real `python -m service` gets every kind of client message over a raw WebSocket (the
protocol itself is under test here, so no client library), in JSON and MessagePack, on
full and compact sockets: each message sent validates against its client message, each
answer against exactly one server message (and the one the operation's reply names),
and each close code with its reason is one the document lists.
"""

from __future__ import annotations

import json
import signal
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import jsonschema_rs
import msgpack
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from schemas.chain import EXAMPLE_GLTF_LEG

from .conftest import Server

pytestmark = pytest.mark.live

TIMEOUT_S = 30.0
SPEC_SCHEMA = Path(__file__).resolve().parents[1] / "schemas" / "asyncapi"
PANDA = {"format": "example", "name": "panda_arm"}
TOOL = {
    "effector": "tool",
    "position": {"x": 0.4, "y": 0.1, "z": 0.5},
    "orientation": {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0},
}


class Spec:
    """The served document: one validator per message, the replies, the close codes."""

    def __init__(self, document: dict[str, Any]) -> None:
        self.document = document
        components = document["components"]
        self.validators = {
            name: jsonschema_rs.Draft7Validator(
                {**message["payload"], "components": {"schemas": components["schemas"]}}
            )
            for name, message in components["messages"].items()
        }
        operations = document["operations"].values()
        self.sent_by_client = {
            op["messages"][0]["$ref"].rsplit("/", 1)[1]
            for op in operations
            if op["action"] == "send"
        }
        self.replies = {
            op["messages"][0]["$ref"].rsplit("/", 1)[1]: {
                ref["$ref"].rsplit("/", 1)[1] for ref in op["reply"]["messages"]
            }
            for op in operations
            if op["action"] == "send"
        }
        self.close_codes = {
            (entry["code"], reason)
            for entry in document["channels"]["session"]["x-close-codes"]
            for reason in entry["reasons"] or [""]
        }
        self.any_reason = {
            entry["code"]
            for entry in document["channels"]["session"]["x-close-codes"]
            if entry["library_reason"]
        }
        self.seen_answers: set[str] = set()
        self.seen_closes: set[tuple[int, str]] = set()

    def matches(self, message: Any, names: set[str]) -> set[str]:
        return {name for name in names if self.validators[name].is_valid(message)}

    def check_sent(self, message: dict[str, Any]) -> str:
        matched = self.matches(message, self.sent_by_client)
        assert len(matched) == 1, (message, matched)
        return matched.pop()

    def check_answer(self, sent_type: str, answer: Any) -> str:
        server_messages = set(self.validators) - self.sent_by_client
        matched = self.matches(answer, server_messages)
        assert len(matched) == 1, (answer, matched)
        name = matched.pop()
        if sent_type in self.replies:
            assert name in self.replies[sent_type], (sent_type, name)
        self.seen_answers.add(name)
        return name

    def check_close(self, closed: ConnectionClosed) -> None:
        assert closed.rcvd is not None, "the server closed without a close frame"
        pair = (closed.rcvd.code, closed.rcvd.reason)
        assert pair in self.close_codes or pair[0] in self.any_reason, pair
        self.seen_closes.add(pair)


@pytest.fixture(scope="module")
def spec(server: Server) -> Spec:
    document = httpx.get(f"{server.base}/asyncapi.json", timeout=TIMEOUT_S).json()
    return Spec(document)


def create(server: Server, chain: dict[str, Any], **extra: Any) -> tuple[str, str]:
    r = httpx.post(f"{server.base}/v1/sessions", json={"chain": chain, **extra}, timeout=TIMEOUT_S)
    assert r.status_code == 201, r.text
    return r.json()["id"], r.json()["token"]


def ws(server: Server, sid: str, token: str | None, query: str = "") -> ClientConnection:
    url = server.base.replace("http", "ws", 1) + f"/v1/sessions/{sid}/ws{query}"
    headers = {} if token is None else {"Authorization": f"Bearer {token}"}
    return connect(url, additional_headers=headers, open_timeout=TIMEOUT_S, max_size=None)


def exchange(spec: Spec, socket: ClientConnection, message: Any, *, binary: bool = False) -> str:
    """Send one message (checked against the document if it is well formed), check the
    answer; returns the answer's message name."""
    sent_type = spec.check_sent(message) if isinstance(message, dict) else ""
    socket.send(msgpack.packb(message) if binary else json.dumps(message))
    raw = socket.recv(timeout=TIMEOUT_S)
    answer = msgpack.unpackb(raw) if isinstance(raw, bytes) else json.loads(raw)
    assert isinstance(raw, bytes) == binary, "answered in another encoding"
    return spec.check_answer(sent_type, answer)


def closed_by_server(spec: Spec, socket: ClientConnection, send: Any = None) -> None:
    with pytest.raises(ConnectionClosed) as info:
        if send is not None:
            socket.send(send)
        socket.recv(timeout=TIMEOUT_S)
    spec.check_close(info.value)


def test_the_document_is_asyncapi_3(spec: Spec) -> None:
    schema = json.loads((SPEC_SCHEMA / "asyncapi-3.0.0.schema.json").read_text())
    validator = jsonschema_rs.validator_for(schema)
    errors = [f"{list(e.instance_path)}: {e.message}" for e in validator.iter_errors(spec.document)]
    assert not errors, errors[:5]
    # The schema is not vacuous: a wrong action is refused.
    broken = json.loads(json.dumps(spec.document))
    next(iter(broken["operations"].values()))["action"] = "publish"
    assert not validator.is_valid(broken)


def test_every_message_the_server_sends_matches_the_document(server: Server, spec: Spec) -> None:
    sid, token = create(server, PANDA)
    with ws(server, sid, token) as socket:
        assert exchange(spec, socket, {"type": "frame", "id": 1, "targets": [TOOL]}) == "result"
        frames = [{"id": i, "targets": [TOOL]} for i in range(3)]
        assert exchange(spec, socket, {"type": "clip", "id": 2, "frames": frames}) == (
            "clip_result"
        )
        planned = {"type": "clip", "id": 3, "frames": frames, "plan": True}
        assert exchange(spec, socket, planned) == "clip_result"
        assert exchange(spec, socket, {"type": "ping", "id": 4}) == "pong"
        ping = {"type": "ping", "id": 5}
        assert exchange(spec, socket, ping, binary=True) == "pong"
        frame = {"type": "frame", "id": 6, "targets": [TOOL]}
        assert exchange(spec, socket, frame, binary=True) == "result"
        # Errors: unknown effector, an id not increasing, bone data asked of a chain
        # without bones (its fk answers the effectors' poses), then messages the
        # document refuses too (the server answers invalid_format).
        claw = {"type": "frame", "id": 7, "targets": [{**TOOL, "effector": "claw"}]}
        assert exchange(spec, socket, claw) == "error"
        assert exchange(spec, socket, {"type": "ping", "id": 7}) == "error"
        bones = {"type": "fk", "id": 8, "bones": {"local_rotations": True}}
        assert exchange(spec, socket, bones) == "error"
        assert exchange(spec, socket, {"type": "fk", "id": 9}, binary=True) == "fk_result"
        for bad in ({"type": "dance", "id": 10}, {"type": "frame", "id": 11, "targets": []}):
            assert not spec.matches(bad, spec.sent_by_client), bad
            socket.send(json.dumps(bad))
            answer = json.loads(socket.recv(timeout=TIMEOUT_S))
            assert spec.check_answer("", answer) == "error"
            assert answer["error"]["code"] == "invalid_format"
        socket.send("{not json")
        assert spec.check_answer("", json.loads(socket.recv(timeout=TIMEOUT_S))) == "error"

    sid, token = create(server, PANDA)
    with ws(server, sid, token, "?results=compact") as socket:
        assert exchange(spec, socket, {"type": "frame", "id": 1, "targets": [TOOL]}) == "result"
        clip = {"type": "clip", "id": 2, "frames": [{"targets": [TOOL]}]}
        assert exchange(spec, socket, clip, binary=True) == "clip_result"

    # A batch: frames for two sessions over one socket, one of them refused in its place.
    (a, a_token), (b, b_token) = create(server, PANDA), create(server, PANDA)
    with ws(server, a, a_token) as socket:
        entries = [
            {"session": a, "token": a_token, "id": 1, "targets": [TOOL]},
            {"session": b, "token": b_token, "id": 1, "targets": [TOOL]},
            {"session": b, "token": "wrong", "id": 2, "targets": [TOOL]},
        ]
        batch = {"type": "batch", "id": 1, "frames": entries}
        assert exchange(spec, socket, batch) == "batch_result"
        assert exchange(spec, socket, {**batch, "id": 2}, binary=True) == "batch_result"

    # A skeleton chain (the /docs glTF leg), so that fk has bones to answer with.
    sid, token = create(server, EXAMPLE_GLTF_LEG, bones={"local_rotations": True})
    with ws(server, sid, token) as socket:
        assert exchange(spec, socket, {"type": "fk", "id": 1}) == "fk_result"
        foot = {"effector": "foot", "position": {"x": 0.1, "y": 0.3, "z": 0.2}}
        assert exchange(spec, socket, {"type": "frame", "id": 2, "targets": [foot]}) == "result"
        fk = {"type": "fk", "id": 3, "q": [0.1, 0.0, 0.0, 0.2, 0.0, 0.0], "bones": {"world": []}}
        exchange(spec, socket, fk)  # fk_result or, if q has the wrong length, an error
    assert spec.seen_answers == {
        "result",
        "clip_result",
        "fk_result",
        "pong",
        "error",
        "batch_result",
    }


def test_every_close_code_the_server_sends_is_in_the_document(
    server: Server, spec: Spec, start_server: Callable[..., Server]
) -> None:
    sid, token = create(server, PANDA)
    with ws(server, sid, None) as socket:
        closed_by_server(spec, socket)
    with ws(server, sid, "wrong") as socket:
        closed_by_server(spec, socket)
    with ws(server, "no-such-session", token) as socket:
        closed_by_server(spec, socket)
    with ws(server, sid, token, "?results=bogus") as socket:
        closed_by_server(spec, socket)
    url = server.base.replace("http", "ws", 1) + f"/v1/sessions/{sid}/ws"
    evil = {"Authorization": f"Bearer {token}", "Origin": "https://evil.example"}
    with connect(url, additional_headers=evil, open_timeout=TIMEOUT_S) as socket:
        closed_by_server(spec, socket)
    # Deleted while connected: the next message is answered by 4404.
    with ws(server, sid, token) as socket:
        httpx.delete(
            f"{server.base}/v1/sessions/{sid}",
            headers={"Authorization": f"Bearer {token}"},
            timeout=TIMEOUT_S,
        )
        closed_by_server(spec, socket, json.dumps({"type": "ping", "id": 1}))

    small = start_server(IK_WS_MAX_MESSAGE_BYTES="4096", IK_MAX_WEBSOCKETS="1")
    sid, token = create(small, PANDA)
    with ws(small, sid, token) as first:
        with ws(small, sid, token) as second:  # one socket too many
            closed_by_server(spec, second)
        closed_by_server(spec, first, json.dumps({"type": "ping", "id": 1, "pad": "x" * 8000}))
    with ws(small, sid, token) as socket:
        assert exchange(spec, socket, {"type": "ping", "id": 1}) == "pong"
        small.proc.send_signal(signal.SIGTERM)
        closed_by_server(spec, socket)
    assert {code for code, _ in spec.seen_closes} == {1008, 1009, 1012, 1013, 4401, 4403, 4404}
