"""``?results=compact``: frame results without ``joints`` by name and per-effector
``effectors``, over HTTP and WebSocket (JSON and MessagePack); the default is unchanged."""

from __future__ import annotations

from typing import Any

import msgpack
import pytest
from numpy.testing import assert_allclose
from pydantic import TypeAdapter
from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

import schemas as S

from .helpers import Created, create, hand_frame

# Without "bones": results carry it only when a session or frame asks (test_bones.py).
COMPACT_KEYS = set(S.CompactFrameResult.model_fields) - {"bones"}
FULL_KEYS = set(S.FrameResult.model_fields) - {"bones"}
SERVER_MESSAGE: TypeAdapter[Any] = TypeAdapter(S.ServerMessage)


def frames(n: int) -> list[dict[str, Any]]:
    return [hand_frame(i, y=0.1 + 0.01 * i) for i in range(n)]


def test_keys_are_the_full_ones_minus_joints_and_effectors() -> None:
    assert COMPACT_KEYS == FULL_KEYS - {"joints", "effectors"}


def test_ws_compact_json_results_in_order(client: TestClient, session: Created) -> None:
    url = f"/v1/sessions/{session.id}/ws?results=compact"
    with client.websocket_connect(url, headers=session.headers) as ws:
        for f in frames(4):
            ws.send_json({"type": "frame", **f})
        replies = [ws.receive_json() for _ in range(4)]
        ws.send_json({"type": "ping", "id": 9})
        assert ws.receive_json() == {"id": 9, "type": "pong"}
    assert [r["id"] for r in replies] == [0, 1, 2, 3]
    for r in replies:
        assert set(r["result"]) == COMPACT_KEYS
        S.CompactFrameResult.model_validate(r["result"])  # strict: no extra keys
        assert isinstance(SERVER_MESSAGE.validate_python(r), S.ResultMessage)
        assert r["success"] is r["result"]["success"] is True
    pose = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()["pose"]
    assert replies[-1]["result"]["q"] == pose["q"]


def test_ws_compact_msgpack(client: TestClient, session: Created) -> None:
    url = f"/v1/sessions/{session.id}/ws?results=compact"
    with client.websocket_connect(url, headers=session.headers) as ws:
        ws.send_bytes(msgpack.packb({"type": "frame", **hand_frame(5)}))
        reply = msgpack.unpackb(ws.receive_bytes())
    assert reply["id"] == 5 and set(reply["result"]) == COMPACT_KEYS


def test_ws_compact_and_full_give_the_same_values(client: TestClient) -> None:
    """Two fresh sessions, the same frames: ``q`` agrees; the full one adds ``joints``
    (the same numbers by name) and ``effectors``."""
    got: dict[str, list[dict[str, Any]]] = {}
    for view in ("full", "compact"):
        s = create(client)
        with client.websocket_connect(
            f"/v1/sessions/{s.id}/ws?results={view}", headers=s.headers
        ) as ws:
            for f in frames(3):
                ws.send_json({"type": "frame", **f})
            got[view] = [ws.receive_json()["result"] for _ in range(3)]
    for full, compact in zip(got["full"], got["compact"], strict=True):
        assert set(full) == FULL_KEYS
        assert_allclose(compact["q"], full["q"], rtol=0.0, atol=1e-9)
        assert list(full["joints"].values()) == full["q"]
        assert {k: full[k] for k in ("id", "success", "status")} == {
            k: compact[k] for k in ("id", "success", "status")
        }


def test_ws_compact_errors_are_unchanged(client: TestClient, session: Created) -> None:
    url = f"/v1/sessions/{session.id}/ws?results=compact"
    with client.websocket_connect(url, headers=session.headers) as ws:
        bad = {"type": "frame", "id": 1, "targets": [{"effector": "claw", "position": {}}]}
        ws.send_json(bad)
        err = ws.receive_json()
        ws.send_json({"type": "frame", "id": 2, **hand_frame(None)})
        ok = ws.receive_json()
    assert err["success"] is False and err["error"]["code"] == "invalid_format"
    assert ok["id"] == 2 and set(ok["result"]) == COMPACT_KEYS


def test_ws_bad_results_value_closes_1008(client: TestClient, session: Created) -> None:
    url = f"/v1/sessions/{session.id}/ws?results=tiny"
    with (
        pytest.raises(WebSocketDisconnect) as info,
        client.websocket_connect(url, headers=session.headers) as ws,
    ):
        ws.receive_json()
    assert info.value.code == 1008


def test_http_compact_frame_and_clip(client: TestClient, session: Created) -> None:
    base = f"/v1/sessions/{session.id}/frames"
    one = client.post(f"{base}?results=compact", json=hand_frame(1), headers=session.headers)
    clip = client.post(
        f"{base}?results=compact", json={"frames": frames(3)}, headers=session.headers
    )
    full = client.post(base, json=hand_frame(7), headers=session.headers)
    assert one.status_code == clip.status_code == full.status_code == 200
    S.CompactFrameResults.model_validate(one.json())
    S.CompactFrameResults.model_validate(clip.json())
    assert [r["id"] for r in clip.json()["results"]] == [0, 1, 2]
    assert set(one.json()["results"][0]) == COMPACT_KEYS
    assert set(full.json()["results"][0]) == FULL_KEYS  # the default is unchanged


def test_http_bad_results_value_is_422_naming_the_parameter(
    client: TestClient, session: Created
) -> None:
    r = client.post(
        f"/v1/sessions/{session.id}/frames?results=tiny",
        json=hand_frame(1),
        headers=session.headers,
    )
    assert r.status_code == 422
    body = r.json()
    assert body["code"] == "invalid_format"
    assert body["detail"][0]["loc"] == ["query", "results"]


def test_http_unknown_query_parameter_is_422(client: TestClient, session: Created) -> None:
    """As unknown body fields are (found by schemathesis once the operation had a query)."""
    r = client.post(
        f"/v1/sessions/{session.id}/frames?results=compact&colour=red",
        json=hand_frame(1),
        headers=session.headers,
    )
    assert r.status_code == 422
    body = r.json()
    assert body["code"] == "invalid_format"
    assert body["detail"][0]["loc"] == ["query", "colour"]
