"""The bad-input catalogue (issue #6): one row per kind of bad input, over HTTP and
WebSocket, each with its expected status or error code and the field it names.

After every row: no 5xx, the app still serves (/healthz), and the session's next good
frame solves as before (nothing was corrupted).
"""

from __future__ import annotations

import copy
import dataclasses
import json
from collections.abc import Callable
from typing import Any

import msgpack
import pytest
from starlette.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from schemas.chain import EXAMPLE_ARM
from service.config import Settings
from service.sessions import InMemorySessionStore

from .helpers import Created, create, hand_frame

JSON = {"content-type": "application/json"}
GOOD = hand_frame(None)


def arm(**changes: Callable[[dict[str, Any]], None]) -> dict[str, Any]:
    chain = copy.deepcopy(EXAMPLE_ARM)
    for change in changes.values():
        change(chain)
    return chain


def joint(i: int, **values: Any) -> Callable[[dict[str, Any]], None]:
    def change(chain: dict[str, Any]) -> None:
        chain["joints"][i].update(values)

    return change


def n_joint_chain(n: int) -> dict[str, Any]:
    joints = [
        {
            "name": f"j{i}",
            "parent": f"l{i}",
            "child": f"l{i + 1}",
            "kind": "revolute",
            "origin": {"translation": {"x": 0.0, "y": 0.0, "z": 0.01}},
            "axis": {"x": 0.0, "y": 1.0, "z": 0.0},
            "lower": [-1.0],
            "upper": [1.0],
        }
        for i in range(n)
    ]
    return {
        "format": "hierarchy",
        "joints": joints,
        "effectors": [{"name": "tip", "link": f"l{n}"}],
    }


URDF_XXE = (
    '<?xml version="1.0"?><!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
    '<robot name="r"><link name="&x;"/></robot>'
)
URDF_LAUGHS = (
    '<?xml version="1.0"?><!DOCTYPE lolz [<!ENTITY lol0 "lol">'
    + "".join(f'<!ENTITY lol{i} "{f"&lol{i - 1};" * 10}">' for i in range(1, 10))
    + ']><robot name="&lol9;"/>'
)

URDF_FAR_ORIGIN = (
    '<robot name="r"><link name="a"/><link name="b"/>'
    '<joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
    '<origin xyz="1e308 0 0"/><axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint>'
    "</robot>"
)


def urdf_chain(text: str) -> dict[str, Any]:
    return {"format": "urdf", "urdf": text, "base_link": "a", "tip_links": ["b"]}


def body(chain: dict[str, Any]) -> dict[str, Any]:
    return {"chain": chain}


@dataclasses.dataclass
class Row:
    """One bad request: where it goes, what it is, what must come back."""

    id: str
    path: str  # "{sid}" is replaced by the session id
    payload: Any  # a JSON-able object, or bytes sent as they are
    status: int
    code: str
    field: str | None = None  # the field named (invalid_problem) or a loc (invalid_format)
    method: str = "POST"
    headers: dict[str, str] = dataclasses.field(default_factory=dict)
    auth: bool = True  # send the session's token


S = "/v1/sessions"
F = "/v1/sessions/{sid}/frames"
SOLVE = "/v1/solve"
DEEP_ARRAY = b"[" * 100_000 + b"]" * 100_000
DEEP_OBJECT = b'{"chain":' + b'{"a":' * 5_000 + b"1" + b"}" * 5_000 + b"}"
KM = {"targets": [{"effector": "hand", "position": {"x": 1000.0, "y": 0.0, "z": 0.0}}]}

HTTP_ROWS = [
    # -- syntax and types ----------------------------------------------------------------
    Row("malformed-json", S, b'{"chain": ', 422, "invalid_format", "body"),
    Row("malformed-json-frame", F, b'{"targets": [', 422, "invalid_format", "body"),
    Row("not-an-object", S, [1, 2], 422, "invalid_format", "body"),
    Row("chain-wrong-type", S, {"chain": 5}, 422, "invalid_format", "body.chain"),
    Row(
        "number-as-string",
        F,
        {"targets": [{"effector": "hand", "position": {"x": "0.3", "y": 0, "z": 0}}]},
        422,
        "invalid_format",
        "targets[0].position.x",
    ),
    Row("id-as-float", F, {**GOOD, "id": 1.5}, 422, "invalid_format", "frame.id"),
    Row("id-as-bool", F, {**GOOD, "id": True}, 422, "invalid_format", "frame.id"),
    Row("id-negative", F, {**GOOD, "id": -1}, 422, "invalid_format", "frame.id"),
    Row("id-over-2^53", F, {**GOOD, "id": 2**60}, 422, "invalid_format", "frame.id"),
    Row("id-5000-digits", F, b'{"id": ' + b"9" * 5000 + b', "targets": []}', 422, "invalid_format"),
    Row("invalid-utf8", F, b'{"targets": "\xff\xfe"}', 422, "invalid_format", "body"),
    Row("unknown-field", F, {**GOOD, "colour": "red"}, 422, "invalid_format", "colour"),
    Row("deep-array", S, DEEP_ARRAY, 422, "invalid_format", "body"),
    Row("deep-object", S, DEEP_OBJECT, 422, "invalid_format", "body"),
    Row("deep-frames", F, DEEP_ARRAY, 422, "invalid_format", "body"),
    # -- NaN and infinity ----------------------------------------------------------------
    Row(
        "nan-json-extension",
        F,
        b'{"targets": [{"effector": "hand", "position": {"x": NaN, "y": 0, "z": 0}}]}',
        422,
        "invalid_format",
        "position.x",
    ),
    Row(
        "infinity-json-extension",
        F,
        b'{"targets": [{"effector": "hand", "position": {"x": -Infinity, "y": 0, "z": 0}}]}',
        422,
        "invalid_format",
        "position.x",
    ),
    Row(
        "1e400-overflows-to-inf",
        F,
        b'{"targets": [{"effector": "hand", "position": {"x": 1e400, "y": 0, "z": 0}}]}',
        422,
        "invalid_format",
        "position.x",
    ),
    Row(
        "nan-string",
        F,
        {"targets": [{"effector": "hand", "position": {"x": "NaN", "y": 0, "z": 0}}]},
        422,
        "invalid_format",
        "position.x",
    ),
    Row(
        "infinity-string",
        F,
        {"targets": [{"effector": "hand", "position": {"x": "Infinity", "y": 0, "z": 0}}]},
        422,
        "invalid_format",
        "position.x",
    ),
    Row(
        "nan-in-chain",
        S,
        b'{"chain": {"format": "hierarchy", "joints": [{"name": "a", "parent": "b", '
        b'"child": "c", "kind": "fixed", "pivot": {"x": NaN, "y": 0, "z": 0}}], '
        b'"effectors": [{"name": "e", "link": "c"}]}}',
        422,
        "invalid_format",
        "pivot.x",
    ),
    Row(
        "nan-option",
        "/v1/sessions/{sid}",
        b'{"time_budget_us": NaN}',
        422,
        "invalid_format",
        "time_budget_us",
        method="PATCH",
    ),
    # -- chains --------------------------------------------------------------------------
    Row(
        "empty-chain",
        S,
        body({"format": "hierarchy", "joints": [], "effectors": [{"name": "e", "link": "c"}]}),
        422,
        "invalid_format",
        "joints",
    ),
    Row("over-the-joint-limit", S, body(n_joint_chain(257)), 422, "invalid_problem", "chain"),
    Row(
        "cycle",
        S,
        body(arm(a=joint(0, parent="hand"))),
        422,
        "invalid_problem",
        "chain.joints[0].parent",
    ),
    Row(
        "duplicate-joint-name",
        S,
        body(arm(a=joint(1, name="shoulder"))),
        422,
        "invalid_problem",
        "chain.joints[1].name",
    ),
    Row(
        "lower-over-upper",
        S,
        body(arm(a=joint(1, lower=[2.0], upper=[1.0]))),
        422,
        "invalid_problem",
        "chain.joints[1].lower",
    ),
    Row(
        "zero-length-axis",
        S,
        body(arm(a=joint(1, axis={"x": 0, "y": 0, "z": 0}))),
        422,
        "invalid_problem",
        "chain.joints[1].axis",
    ),
    Row(
        "denormal-axis",
        S,
        body(arm(a=joint(1, axis={"x": 1e-300, "y": 0, "z": 0}))),
        422,
        "invalid_problem",
        "chain.joints[1].axis",
    ),
    Row(
        "non-unit-quaternion",
        S,
        body(arm(a=joint(1, origin={"rotation": {"w": 2, "x": 0, "y": 0, "z": 0}}))),
        422,
        "invalid_format",
        "origin.rotation",
    ),
    Row(
        "zero-quaternion",
        S,
        body(arm(a=joint(1, origin={"rotation": {"w": 0, "x": 0, "y": 0, "z": 0}}))),
        422,
        "invalid_format",
        "origin.rotation",
    ),
    Row(  # found by schemathesis: the norm check squared 1e218 (OverflowError, a 500)
        "quaternion-1e218",
        S,
        body(arm(a=joint(1, origin={"rotation": {"w": 0, "x": 0, "y": 0, "z": 1e218}}))),
        422,
        "invalid_format",
        "origin.rotation",
    ),
    Row(
        "1e308-translation",
        S,
        body(arm(a=joint(1, origin={"translation": {"x": 1e308, "y": 0, "z": 0}}))),
        422,
        "invalid_format",
        "origin.translation.x",
    ),
    Row(
        "1e308-limits",
        S,
        body(arm(a=joint(1, lower=[-1e308], upper=[1e308]))),
        422,
        "invalid_format",
        "lower[0]",
    ),
    Row(
        "limits-of-the-wrong-length",
        S,
        body(arm(a=joint(1, lower=[0.0, 0.0], upper=[1.0, 1.0]))),
        422,
        "invalid_problem",
        "chain.joints[1].lower",
    ),
    Row(
        "unknown-effector-link",
        S,
        body({**EXAMPLE_ARM, "effectors": [{"name": "hand", "link": "nowhere"}]}),
        422,
        "invalid_problem",
        "chain.effectors[0].link",
    ),
    # -- URDF ------------------------------------------------------------------------------
    Row(
        "urdf-external-entity", S, body(urdf_chain(URDF_XXE)), 422, "invalid_problem", "chain.urdf"
    ),
    Row(
        "urdf-billion-laughs",
        S,
        body(urdf_chain(URDF_LAUGHS)),
        422,
        "invalid_problem",
        "chain.urdf",
    ),
    Row(
        "urdf-over-IK_MAX_URDF_BYTES",
        S,
        body(urdf_chain("<robot>" + " " * 3_000_000 + "</robot>")),
        422,
        "invalid_problem",
        "chain.urdf",
    ),
    Row(
        "urdf-100-MB",
        S,
        b'{"chain": {"format": "urdf", "urdf": "' + b"a" * (100 * 2**20) + b'"}}',
        413,
        "payload_too_large",
    ),
    Row("urdf-not-xml", S, body(urdf_chain("<robot")), 422, "invalid_problem", "chain.urdf"),
    Row(  # found by the hostile suite: accepted, then every frame ended ``nonfinite``
        "urdf-origin-1e308",
        S,
        body(urdf_chain(URDF_FAR_ORIGIN)),
        422,
        "invalid_problem",
        "chain.urdf",
    ),
    # -- frames ----------------------------------------------------------------------------
    Row(
        "unknown-effector",
        F,
        {"targets": [{"effector": "claw", "position": {"x": 0, "y": 0, "z": 0}}]},
        422,
        "invalid_problem",
        "targets[0].effector",
    ),
    Row("no-targets", F, {"targets": []}, 422, "invalid_format", "targets"),
    Row(
        "frame-list-over-the-limit",
        F,
        {"frames": [GOOD] * 601},
        422,
        "invalid_problem",
        "frames",
    ),
    Row(
        "target-over-1e6-m",
        F,
        {"targets": [{"effector": "hand", "position": {"x": 1e300, "y": 0, "z": 0}}]},
        422,
        "invalid_format",
        "position.x",
    ),
    Row(
        "option-overflow",
        "/v1/sessions/{sid}",
        {"posture_weight": 1e308},
        422,
        "invalid_format",
        "posture_weight",
        method="PATCH",
    ),
    Row(
        "pose-of-the-wrong-length",
        "/v1/sessions/{sid}/pose",
        {"q": [0.0]},
        422,
        "invalid_problem",
        "q",
        method="PUT",
    ),
    # -- sessions and tokens ---------------------------------------------------------------
    Row("unknown-session", "/v1/sessions/nosuchsession/frames", GOOD, 404, "not_found"),
    Row("missing-token", F, GOOD, 401, "unauthorized", auth=False),
    Row(
        "wrong-token",
        F,
        GOOD,
        403,
        "forbidden",
        auth=False,
        headers={"Authorization": "Bearer wrong"},
    ),
    Row(
        "basic-auth-instead-of-bearer",
        F,
        GOOD,
        401,
        "unauthorized",
        auth=False,
        headers={"Authorization": "Basic eDp5"},
    ),
    Row("wrong-method", S, None, 405, "method_not_allowed", method="PUT"),
]


def new_session(client: TestClient) -> Created:
    # A generous budget: "solves as before" must not depend on this machine's load.
    return create(client, options={"time_budget_us": 20_000})


def send(client: TestClient, row: Row, s: Created) -> Any:
    headers = {**(s.headers if row.auth else {}), **row.headers}
    path = row.path.replace("{sid}", s.id)
    if isinstance(row.payload, bytes):
        return client.request(row.method, path, content=row.payload, headers={**JSON, **headers})
    if row.payload is None:
        return client.request(row.method, path, headers=headers)
    return client.request(row.method, path, json=row.payload, headers=headers)


def named(err: dict[str, Any]) -> str:
    """Everything an error says about where: field, or the locs of a schema error
    (written as ``field`` writes a path: list indices in brackets)."""
    if isinstance(err.get("detail"), list):
        return " ".join(_path(e["loc"]) for e in err["detail"])
    return str(err.get("field"))


def _path(loc: list[Any]) -> str:
    return "".join(f"[{p}]" if type(p) is int else f".{p}" for p in loc).lstrip(".")


def assert_still_serving(client: TestClient, s: Created) -> None:
    assert client.get("/healthz").status_code == 200
    r = client.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(99), headers=s.headers)
    assert r.status_code == 200, r.text
    (result,) = r.json()["results"]
    assert result["success"] is True and result["id"] == 99


@pytest.mark.parametrize("row", HTTP_ROWS, ids=[r.id for r in HTTP_ROWS])
def test_http_bad_input(client: TestClient, row: Row) -> None:
    s = new_session(client)
    before = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["pose"]
    r = send(client, row, s)
    assert r.status_code == row.status, r.text
    err = r.json()
    assert err["code"] == row.code, err
    if row.field is not None:
        assert row.field in named(err), err
        # And ``field``, which a client reads: the same path, list indices in brackets
        # (FastAPI's leading "body." left out).
        assert row.field.removeprefix("body.") in str(err.get("field")), err
    # Nothing was solved, nothing moved: the session is as it was.
    after = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()
    assert after["pose"] == before and after["counters"]["frames"] == 0
    assert_still_serving(client, s)


def test_chain_at_the_joint_limit_is_accepted(client: TestClient) -> None:
    r = client.post("/v1/sessions", json=body(n_joint_chain(256)))
    assert r.status_code == 201, r.text
    assert r.json()["n_dof"] == 256


def test_target_a_kilometre_away_is_a_result_not_an_error(client: TestClient) -> None:
    # REACH: under the default, smooth, the arm comes back from the stretched pose at
    # 0.1 rad per frame and "still serving" would need several frames.
    s = create(client, options={"time_budget_us": 20_000, "continuity": "reach"})
    r = client.post(f"/v1/sessions/{s.id}/frames", json=KM, headers=s.headers)
    assert r.status_code == 200
    (result,) = r.json()["results"]
    assert result["success"] is False and result["status"] != "solved"
    assert result["effectors"][0]["position_error_m"] > 990
    assert_still_serving(client, s)


def test_frames_for_an_expired_or_deleted_session_are_404(
    make_client: Callable[..., TestClient],
) -> None:
    now = [0.0]
    store = InMemorySessionStore(max_sessions=10, ttl_s=5.0, clock=lambda: now[0])
    client = make_client(Settings(session_ttl_s=5.0), store=store)
    expired, deleted = new_session(client), new_session(client)
    assert client.delete(f"/v1/sessions/{deleted.id}", headers=deleted.headers).status_code == 204
    now[0] += 60.0
    for s in (expired, deleted):
        r = client.post(f"/v1/sessions/{s.id}/frames", json=GOOD, headers=s.headers)
        assert r.status_code == 404 and r.json()["code"] == "not_found"
    fresh = new_session(client)
    assert_still_serving(client, fresh)


# -- WebSocket ----------------------------------------------------------------------------
def frame_msg(frame_id: int, **pos: float) -> dict[str, Any]:
    return {"type": "frame", "id": frame_id, **hand_frame(None, **pos)}


WS_ROWS: list[tuple[str, str | bytes, str, str | None]] = [
    # (id, message, error code, field named)
    ("malformed-json", '{"type": "frame", ', "invalid_format", None),
    ("not-an-object", "[1, 2]", "invalid_format", None),
    ("null", "null", "invalid_format", None),
    ("unknown-type", json.dumps({"type": "dance", "id": 1}), "invalid_format", None),
    ("missing-id", json.dumps({"type": "ping"}), "invalid_format", "ping.id"),
    ("id-as-string", json.dumps({"type": "ping", "id": "1"}), "invalid_format", "ping.id"),
    ("id-5000-digits", '{"type": "ping", "id": ' + "9" * 5000 + "}", "invalid_format", None),
    (
        "nan-json-extension",
        '{"type": "frame", "id": 1, "targets": [{"effector": "hand", '
        '"position": {"x": NaN, "y": 0, "z": 0}}]}',
        "invalid_format",
        "frame.targets[0].position.x",
    ),
    (
        "infinity-string",
        json.dumps(
            {
                "type": "frame",
                "id": 1,
                "targets": [{"effector": "hand", "position": {"x": "Infinity", "y": 0, "z": 0}}],
            }
        ),
        "invalid_format",
        "frame.targets[0].position.x",
    ),
    (
        "non-unit-quaternion",
        json.dumps(
            {
                "type": "frame",
                "id": 1,
                "targets": [{"effector": "hand", "orientation": {"w": 3, "x": 0, "y": 0, "z": 0}}],
            }
        ),
        "invalid_format",
        "frame.targets[0].orientation",
    ),
    ("deep-nesting", "[" * 100_000 + "]" * 100_000, "invalid_format", None),
    (
        "unknown-effector",
        json.dumps(
            {
                "type": "frame",
                "id": 1,
                "targets": [{"effector": "claw", "position": {"x": 0, "y": 0, "z": 0}}],
            }
        ),
        "invalid_problem",
        "targets[0].effector",
    ),
    ("binary-garbage", b"\xc1\xc1\x00\xff garbage", "invalid_format", None),
    ("msgpack-deep-nesting", b"\x91" * 100_000 + b"\x00", "invalid_format", None),
    ("msgpack-int-keys", msgpack.packb({1: 2}), "invalid_format", None),
    (
        "msgpack-trailing-bytes",
        msgpack.packb({"type": "ping", "id": 1}) + b"\x00",
        "invalid_format",
        None,
    ),
    (
        "msgpack-bytes-as-id",
        msgpack.packb({"type": "ping", "id": b"12"}),
        "invalid_format",
        "ping.id",
    ),
    (
        "msgpack-nan",
        msgpack.packb(
            {
                "type": "frame",
                "id": 1,
                "targets": [{"effector": "hand", "position": {"x": float("nan"), "y": 0, "z": 0}}],
            }
        ),
        "invalid_format",
        "frame.targets[0].position.x",
    ),
]


@pytest.mark.parametrize(
    ("message", "code", "field"), [r[1:] for r in WS_ROWS], ids=[r[0] for r in WS_ROWS]
)
def test_ws_bad_input_is_an_error_message_and_the_socket_stays_open(
    client: TestClient, message: str | bytes, code: str, field: str | None
) -> None:
    s = new_session(client)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        if isinstance(message, bytes):
            ws.send_bytes(message)
            err = msgpack.unpackb(ws.receive_bytes())
        else:
            ws.send_text(message)
            err = ws.receive_json()
        assert err["type"] == "result" and err["success"] is False
        assert err["error"]["code"] == code, err
        if field is not None:
            assert err["error"].get("field") == field, err
        ws.send_json(frame_msg(2))
        ok = ws.receive_json()
        assert ok["id"] == 2 and ok["success"] is True
    assert_still_serving(client, s)


def test_ws_oversized_message_closes_1009_and_the_session_survives(
    make_client: Callable[..., TestClient],
) -> None:
    client = make_client(Settings(ws_max_message_bytes=4096))
    s = new_session(client)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_bytes(b"\x00" * 10_000)
        with pytest.raises(WebSocketDisconnect) as info:
            ws.receive_bytes()
    assert info.value.code == 1009
    assert_still_serving(client, s)


@pytest.mark.parametrize(
    ("path_id", "headers", "close_code"),
    [
        ("nosuchsession", None, 4404),
        (None, {}, 4401),
        (None, {"Authorization": "Bearer wrong"}, 4403),
    ],
    ids=["unknown-session", "missing-token", "wrong-token"],
)
def test_ws_bad_session_or_token_closes_with_its_code(
    client: TestClient, path_id: str | None, headers: dict[str, str] | None, close_code: int
) -> None:
    s = new_session(client)
    with pytest.raises(WebSocketDisconnect) as info:
        with client.websocket_connect(
            f"/v1/sessions/{path_id or s.id}/ws", headers=s.headers if headers is None else headers
        ) as ws:
            ws.receive_json()
    assert info.value.code == close_code
    assert_still_serving(client, s)


def test_ws_frames_for_an_expired_session_close_4404(
    make_client: Callable[..., TestClient],
) -> None:
    now = [0.0]
    store = InMemorySessionStore(max_sessions=10, ttl_s=5.0, clock=lambda: now[0])
    client = make_client(Settings(session_ttl_s=5.0), store=store)
    s = new_session(client)
    now[0] += 60.0
    with pytest.raises(WebSocketDisconnect) as info:
        with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
            ws.receive_json()
    assert info.value.code == 4404


def test_405_lists_every_method_of_the_path(client: TestClient) -> None:
    # Found by schemathesis: starlette named only the first route's methods (GET).
    s = new_session(client)
    r = client.request("OPTIONS", f"/v1/sessions/{s.id}", headers=s.headers)
    assert r.status_code == 405 and r.json()["code"] == "method_not_allowed"
    assert set(r.headers["allow"].split(", ")) == {"GET", "HEAD", "PATCH", "DELETE"}
    r = client.put("/v1/sessions", headers=s.headers)
    assert r.status_code == 405 and r.headers["allow"] == "POST"
