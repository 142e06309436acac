"""Access control and limits (issue #6 items 2 and 3): API keys, per-key session cap,
session tokens on every transport, CORS closed by default, frames per second per
session, and a WebSocket client that stops reading."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

import pytest
from pydantic import SecretStr
from starlette.testclient import TestClient
from starlette.websockets import WebSocket, WebSocketDisconnect

from schemas.chain import EXAMPLE_ARM
from service.auth import check_api_key
from service.config import Settings
from service.errors import ServiceError
from service.sessions import InMemorySessionStore

from .helpers import Created, create, hand_frame

KEYS = Settings(api_keys=SecretStr("alpha-key,beta-key"), max_sessions_per_key=2)


def create_with_key(client: TestClient, key: str | None) -> Any:
    headers = {} if key is None else {"X-API-Key": key}
    return client.post("/v1/sessions", json={"chain": EXAMPLE_ARM}, headers=headers)


# -- API keys --------------------------------------------------------------------------------
def test_without_configured_keys_no_key_is_needed(client: TestClient) -> None:
    assert create_with_key(client, None).status_code == 201
    assert create_with_key(client, "anything").status_code == 201


@pytest.mark.parametrize(
    ("key", "status", "code"),
    [(None, 401, "unauthorized"), ("", 401, "unauthorized"), ("alpha", 403, "forbidden")],
    ids=["missing", "empty", "wrong"],
)
def test_api_key_required_when_configured(
    make_client: Callable[..., TestClient], key: str | None, status: int, code: str
) -> None:
    client = make_client(KEYS)
    r = create_with_key(client, key)
    assert r.status_code == status and r.json()["code"] == code
    one_shot = client.post(
        "/v1/solve",
        json={"chain": EXAMPLE_ARM, "targets": hand_frame(None)["targets"]},
        headers={} if key is None else {"X-API-Key": key},
    )
    assert one_shot.status_code == status and one_shot.json()["code"] == code
    assert create_with_key(client, "beta-key").status_code == 201


def test_sessions_per_key_are_capped_and_freed_by_delete(
    make_client: Callable[..., TestClient],
) -> None:
    client = make_client(KEYS)
    first = create_with_key(client, "alpha-key").json()
    assert create_with_key(client, "alpha-key").status_code == 201
    r = create_with_key(client, "alpha-key")
    assert r.status_code == 429 and r.json()["code"] == "key_session_limit"
    # Another key has its own allowance.
    assert create_with_key(client, "beta-key").status_code == 201
    auth = {"Authorization": f"Bearer {first['token']}"}
    assert client.delete(f"/v1/sessions/{first['id']}", headers=auth).status_code == 204
    assert create_with_key(client, "alpha-key").status_code == 201


def test_keys_are_compared_in_constant_time_and_never_shown(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    import hmac

    calls: list[tuple[bytes, bytes]] = []
    real = hmac.compare_digest

    def spy(a: bytes, b: bytes) -> bool:
        calls.append((a, b))
        return real(a, b)

    monkeypatch.setattr(hmac, "compare_digest", spy)
    keys = KEYS.api_key_list()
    fingerprint = check_api_key(keys, "alpha-key")
    assert fingerprint is not None and "alpha" not in fingerprint
    assert len(calls) == len(keys)  # every key compared, no early exit on a match
    with pytest.raises(ServiceError):
        check_api_key(keys, "nope")
    assert "alpha-key" not in repr(KEYS) and "alpha-key" not in str(KEYS.model_dump())
    with caplog.at_level(logging.DEBUG):
        check_api_key(keys, "beta-key")
    assert "beta-key" not in caplog.text


def test_env_parsing_of_keys_and_origins(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("IK_API_KEYS", " k1 , k2,,")
    monkeypatch.setenv("IK_CORS_ORIGINS", "https://a.example, https://b.example")
    s = Settings()
    assert s.api_key_list() == (b"k1", b"k2")
    assert s.cors_origin_list() == ["https://a.example", "https://b.example"]


# -- session tokens on WebSockets ----------------------------------------------------------
def test_ws_token_in_a_subprotocol(client: TestClient, session: Created) -> None:
    with client.websocket_connect(
        f"/v1/sessions/{session.id}/ws", subprotocols=["ik.v1", f"ik.token.{session.token}"]
    ) as ws:
        assert ws.accepted_subprotocol == "ik.v1"  # never the token
        ws.send_json({"type": "ping", "id": 1})
        assert ws.receive_json() == {"id": 1, "type": "pong"}


def test_ws_wrong_token_in_a_subprotocol_closes_4403(client: TestClient, session: Created) -> None:
    with pytest.raises(WebSocketDisconnect) as info:
        with client.websocket_connect(
            f"/v1/sessions/{session.id}/ws", subprotocols=["ik.v1", "ik.token.wrong"]
        ) as ws:
            ws.receive_json()
    assert info.value.code == 4403


# -- CORS and browser origins -------------------------------------------------------------
def test_cors_closed_by_default(client: TestClient) -> None:
    r = client.options(
        "/v1/sessions",
        headers={"Origin": "https://evil.example", "Access-Control-Request-Method": "POST"},
    )
    assert "access-control-allow-origin" not in r.headers
    r = client.get("/healthz", headers={"Origin": "https://evil.example"})
    assert "access-control-allow-origin" not in r.headers


def test_cors_allows_only_configured_origins(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(cors_origins="https://app.example"))
    ok = client.options(
        "/v1/sessions",
        headers={
            "Origin": "https://app.example",
            "Access-Control-Request-Method": "POST",
            "Access-Control-Request-Headers": "x-api-key, content-type",
        },
    )
    assert ok.status_code == 200
    assert ok.headers["access-control-allow-origin"] == "https://app.example"
    bad = client.get("/healthz", headers={"Origin": "https://evil.example"})
    assert "access-control-allow-origin" not in bad.headers


def test_body_too_large_answer_carries_cors_headers(
    make_client: Callable[..., TestClient],
) -> None:
    """The 413 is answered before the app reads the body; a browser must still see it
    as a 413 (with the CORS headers), not as a CORS failure."""
    client = make_client(Settings(cors_origins="https://app.example", max_body_bytes=2048))
    r = client.post(
        "/v1/sessions",
        content=b"x" * 5000,
        headers={"Origin": "https://app.example", "Content-Type": "application/json"},
    )
    assert r.status_code == 413
    assert r.json()["code"] == "payload_too_large"
    assert r.headers["access-control-allow-origin"] == "https://app.example"


def test_ws_from_an_unlisted_browser_origin_closes_4403(
    make_client: Callable[..., TestClient],
) -> None:
    client = make_client(Settings(cors_origins="https://app.example"))
    s = create(client)
    url = f"/v1/sessions/{s.id}/ws"
    with pytest.raises(WebSocketDisconnect) as info:
        with client.websocket_connect(
            url, headers={**s.headers, "Origin": "https://evil.example"}
        ) as ws:
            ws.receive_json()
    assert info.value.code == 4403
    with client.websocket_connect(
        url, headers={**s.headers, "Origin": "https://app.example"}
    ) as ws:
        ws.send_json({"type": "ping", "id": 1})
        assert ws.receive_json()["type"] == "pong"


def test_ws_from_a_page_of_the_service_itself_is_allowed(
    make_client: Callable[..., TestClient],
) -> None:
    """/demo's socket: Origin is the host the socket connects to (no IK_CORS_ORIGINS)."""
    client = make_client(Settings())
    s = create(client)
    url = f"/v1/sessions/{s.id}/ws"
    host = {"Host": "ik.example:8000"}
    with client.websocket_connect(
        url, headers={**s.headers, **host, "Origin": "http://ik.example:8000"}
    ) as ws:
        ws.send_json({"type": "ping", "id": 1})
        assert ws.receive_json()["type"] == "pong"
    for other in ("http://ik.example:8001", "https://evil.example", "file://ik.example:8000"):
        with pytest.raises(WebSocketDisconnect) as info:
            with client.websocket_connect(
                url, headers={**s.headers, **host, "Origin": other}
            ) as ws:
                ws.receive_json()
        assert info.value.code == 4403, other


# -- frames per second per session --------------------------------------------------------
def rate_client(make_client: Callable[..., TestClient], now: list[float]) -> TestClient:
    store = InMemorySessionStore(max_sessions=10, ttl_s=1e9, clock=lambda: now[0])
    return make_client(Settings(max_frames_per_s=5, max_frames_per_request=3), store=store)


def test_http_frames_over_the_rate_are_429_with_retry_after(
    make_client: Callable[..., TestClient],
) -> None:
    now = [0.0]
    client = rate_client(make_client, now)
    s = create(client)
    url = f"/v1/sessions/{s.id}/frames"
    for i in range(5):  # the burst: one second's worth
        assert client.post(url, json=hand_frame(i), headers=s.headers).status_code == 200
    r = client.post(url, json=hand_frame(5), headers=s.headers)
    assert r.status_code == 429 and r.json()["code"] == "rate_limited"
    assert int(r.headers["Retry-After"]) >= 1
    now[0] += 1.0  # refilled
    clip = {"frames": [hand_frame(i) for i in (6, 7, 8)]}
    assert client.post(url, json=clip, headers=s.headers).status_code == 200
    # Another session is not affected.
    other = create(client)
    r = client.post(f"/v1/sessions/{other.id}/frames", json=hand_frame(1), headers=other.headers)
    assert r.status_code == 200


def test_ws_frames_over_the_rate_get_rate_limited_and_stay_open(
    make_client: Callable[..., TestClient],
) -> None:
    now = [0.0]
    client = rate_client(make_client, now)
    s = create(client)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        for i in range(5):
            ws.send_json({"type": "frame", "id": i, **hand_frame(None)})
            assert ws.receive_json()["type"] == "result"
        ws.send_json({"type": "frame", "id": 5, **hand_frame(None)})
        err = ws.receive_json()
        assert err["id"] == 5 and err["error"]["code"] == "rate_limited"
        ws.send_json({"type": "ping", "id": 6})  # pings are not frames
        assert ws.receive_json()["type"] == "pong"
        now[0] += 1.0
        ws.send_json({"type": "frame", "id": 7, **hand_frame(None)})
        assert ws.receive_json()["success"] is True


def test_rate_zero_means_unlimited(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_frames_per_s=0))
    s = create(client)
    for i in range(20):
        r = client.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(i), headers=s.headers)
        assert r.status_code == 200


# -- a client that stops reading ----------------------------------------------------------
def test_ws_client_that_stops_reading_is_dropped_and_frees_its_slot(
    make_client: Callable[..., TestClient], monkeypatch: pytest.MonkeyPatch
) -> None:
    """uvicorn's send blocks while the write buffer is over its high-water mark; model
    that as a send that never returns: after ws_send_timeout_s the server drops the
    socket, frees the slot and keeps the session."""
    client = make_client(Settings(ws_send_timeout_s=0.2, max_websockets=1))
    s = create(client)
    svc = client.app.state.ik  # type: ignore[attr-defined]
    real_send_text = WebSocket.send_text

    async def blocked(self: WebSocket, data: str) -> None:
        await asyncio.sleep(3600)

    monkeypatch.setattr(WebSocket, "send_text", blocked)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "ping", "id": 1})
        with pytest.raises(WebSocketDisconnect) as info:
            ws.receive_json()
    assert info.value.code == 1008
    assert svc.open_websockets == 0
    assert client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["websockets"] == 0
    monkeypatch.setattr(WebSocket, "send_text", real_send_text)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "ping", "id": 1})
        assert ws.receive_json()["type"] == "pong"
