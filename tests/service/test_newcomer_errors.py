"""The errors a newcomer meets in the first minutes say what to send instead (issue 19).

Codes stay as they were (invalid_format, invalid_problem, unauthorized); what these
tests check is the message and the field, because here the message is the point.
"""

from __future__ import annotations

import copy
import json
import math
from typing import Any

import msgpack
import orjson
import pytest
from starlette.testclient import TestClient

import schemas as S
from schemas.chain import EXAMPLE_ARM, EXAMPLE_BVH_LEG

from .helpers import Created, create, hand_frame


def arm_with(joint: int, **values: Any) -> dict[str, Any]:
    chain = copy.deepcopy(EXAMPLE_ARM)
    chain["joints"][joint].update(values)
    return chain


def ws_exchange(client: TestClient, s: Created, message: Any, *, binary: bool = False) -> Any:
    """Send one message on a fresh socket; return the answer (decoded)."""
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        if binary:
            ws.send_bytes(msgpack.packb(message))
            return msgpack.unpackb(ws.receive_bytes())
        ws.send_text(message if isinstance(message, str) else json.dumps(message))
        return ws.receive_json()


# -- 1. a WebSocket message without a known type --------------------------------------------
@pytest.mark.parametrize("binary", [False, True], ids=["json", "msgpack"])
@pytest.mark.parametrize(
    "message",
    [{"id": 1}, {"type": "dance", "id": 1}, {"type": 3, "id": 1}, {"type": None, "id": 1}, [1]],
    ids=["no-type", "unknown-type", "number-type", "null-type", "not-an-object"],
)
def test_a_message_without_a_known_type_is_told_the_types(
    client: TestClient, session: Created, message: Any, binary: bool
) -> None:
    answer = ws_exchange(client, session, message, binary=binary)
    error = answer["error"]
    assert error["code"] == "invalid_format" and error["field"] == "type", answer
    for tag in S.CLIENT_MESSAGE_TYPES:
        assert f'"{tag}"' in error["message"], error
    if isinstance(message, dict):
        assert answer["id"] == 1


def test_the_listed_types_are_the_ones_the_server_takes(
    client: TestClient, session: Created
) -> None:
    """Each listed type gets past the type check (its error, if any, is about another
    field), and the list holds every type the README documents."""
    assert {"frame", "clip", "ping"} <= set(S.CLIENT_MESSAGE_TYPES)
    with client.websocket_connect(f"/v1/sessions/{session.id}/ws", headers=session.headers) as ws:
        for i, tag in enumerate(S.CLIENT_MESSAGE_TYPES, start=1):
            ws.send_json({"type": tag, "id": i})
            answer = ws.receive_json()
            assert answer.get("error", {}).get("field") != "type", (tag, answer)


def test_a_near_miss_type_is_named(client: TestClient, session: Created) -> None:
    answer = ws_exchange(client, session, {"type": "frames", "id": 1, **hand_frame(None)})
    assert 'did you mean "frame"' in answer["error"]["message"], answer


# -- 2. an array where a quaternion (or vector) object belongs --------------------------------
QUATERNION_FORM = '{"w": ..., "x": ..., "y": ..., "z": ...}'


def test_an_array_quaternion_in_a_chain_is_422_with_the_object_form(client: TestClient) -> None:
    chain = arm_with(1, origin={"rotation": [0, 0, 0, 1]})
    r = client.post("/v1/sessions", json={"chain": chain})
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["code"] == "invalid_format"
    assert body["field"] == "chain.joints[1].origin.rotation"
    (error,) = body["detail"]
    message = error["msg"]
    assert QUATERNION_FORM in message and "x, y, z, w" in message, message
    # Both readings of the array, as objects the client can paste.
    assert '{"w":0,"x":0,"y":0,"z":1}' in message
    assert '{"w":1,"x":0,"y":0,"z":0}' in message


def test_an_array_quaternion_in_a_frame_is_invalid_format_on_both_transports(
    client: TestClient,
) -> None:
    pose_arm = copy.deepcopy(EXAMPLE_ARM)
    pose_arm["effectors"] = [{"name": "hand", "link": "hand", "mode": "pose"}]
    s = create(client, pose_arm)
    target = {"effector": "hand", "orientation": [1, 0, 0, 0]}
    r = client.post(f"/v1/sessions/{s.id}/frames", json={"targets": [target]}, headers=s.headers)
    assert r.status_code == 422 and r.json()["code"] == "invalid_format", r.text
    assert r.json()["field"] == "frame.targets[0].orientation"
    assert QUATERNION_FORM in r.json()["detail"][0]["msg"]
    for binary in (False, True):
        answer = ws_exchange(
            client, s, {"type": "frame", "id": 1, "targets": [target]}, binary=binary
        )
        error = answer["error"]
        assert error["code"] == "invalid_format", answer
        assert error["field"] == "frame.targets[0].orientation"
        assert QUATERNION_FORM in error["message"] and "x, y, z, w" in error["message"]


def test_an_array_position_is_told_the_object_form(client: TestClient, session: Created) -> None:
    frame = {"targets": [{"effector": "hand", "position": [0.3, 0.1, 0.6]}]}
    r = client.post(f"/v1/sessions/{session.id}/frames", json=frame, headers=session.headers)
    assert r.status_code == 422 and r.json()["code"] == "invalid_format", r.text
    assert '{"x":0.3,"y":0.1,"z":0.6}' in r.json()["detail"][0]["msg"]


# -- 3. rotation limits are radians -------------------------------------------------------------
@pytest.mark.parametrize(
    ("joint", "values", "field", "degrees_hint"),
    [
        (1, {"lower": [0.0], "upper": [150.0]}, "chain.joints[1].upper", "2.6180"),
        (0, {"lower": [-180.0, -1.5], "upper": [3.1, 1.5]}, "chain.joints[0].lower", "-3.1416"),
        (1, {"lower": [0.0], "upper": [7.0]}, "chain.joints[1].upper", "0.1222"),
        (1, {"lower": [-1e6], "upper": [1e6]}, "chain.joints[1].lower", None),
    ],
    ids=["revolute-150", "rotational-minus-180", "revolute-7", "revolute-1e6"],
)
def test_a_rotation_limit_beyond_a_full_turn_is_refused_as_degrees(
    client: TestClient,
    joint: int,
    values: dict[str, Any],
    field: str,
    degrees_hint: str | None,
) -> None:
    r = client.post("/v1/sessions", json={"chain": arm_with(joint, **values)})
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["code"] == "invalid_problem" and body["field"] == field, body
    name = EXAMPLE_ARM["joints"][joint]["name"]
    assert repr(name) in body["detail"] and "radians" in body["detail"], body
    if degrees_hint is not None:
        assert f"degrees is {degrees_hint}" in body["detail"], body


@pytest.mark.parametrize("limit", [2 * math.pi, 6.2832])
def test_a_full_turn_is_a_valid_limit(client: TestClient, limit: float) -> None:
    created = create(client, arm_with(1, lower=[-limit], upper=[limit]))
    assert created.body["dof"][2] == {"name": "elbow", "lower": -limit, "upper": limit}


def test_prismatic_limits_are_metres_and_not_checked_as_angles(client: TestClient) -> None:
    chain = arm_with(1, kind="prismatic", lower=[0.0], upper=[150.0])
    created = create(client, chain)
    assert created.body["dof"][2]["upper"] == 150.0


@pytest.mark.parametrize("limit", ["1e16", str(2 * math.pi + 1e-6), "100"])
def test_urdf_limits_are_taken_as_given(client: TestClient, limit: str) -> None:
    """URDF is radians by definition; files in the wild give unlimited joints huge
    limits, which must load."""
    urdf = (
        '<robot name="r"><link name="base"/><link name="l1"/><link name="tip"/>'
        '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>'
        f'<axis xyz="0 0 1"/><limit lower="-{limit}" upper="{limit}" effort="1" velocity="1"/>'
        '</joint><joint name="j2" type="fixed"><parent link="l1"/><child link="tip"/>'
        '<origin xyz="0.5 0 0"/></joint></robot>'
    )
    chain = {"format": "urdf", "urdf": urdf, "base_link": "base", "tip_links": ["tip"]}
    created = create(client, chain)
    assert created.body["dof"][0]["upper"] == float(limit)


# -- 3b. two effectors of one name: the later one is named, with the first ------------------
# (two tip links alike: test_http.py's test of a URDF chain's link names)
@pytest.mark.parametrize(
    ("chain", "field", "words"),
    [
        (
            {**EXAMPLE_ARM, "effectors": [*EXAMPLE_ARM["effectors"], *EXAMPLE_ARM["effectors"]]},
            "chain.effectors[1].name",
            "chain.effectors[0] has it",
        ),
        (
            {**EXAMPLE_BVH_LEG, "effectors": [{"bone": "LeftLeg_end"}] * 2},
            "chain.effectors[1].bone",
            "named after its bone",
        ),
        (
            {
                **EXAMPLE_BVH_LEG,
                "effectors": [
                    {"bone": "LeftLeg_end", "name": "foot"},
                    {"bone": "LeftLeg", "name": "foot"},
                ],
            },
            "chain.effectors[1].name",
            "'foot'",
        ),
    ],
    ids=["json", "bvh-same-bone", "bvh-same-name"],
)
def test_two_effectors_of_one_name_name_the_later(
    client: TestClient, chain: dict[str, Any], field: str, words: str
) -> None:
    r = client.post("/v1/sessions", json={"chain": chain})
    assert r.status_code == 422, r.text
    body = r.json()
    assert (body["code"], body["field"]) == ("invalid_problem", field), body
    assert words in body["detail"], body


# -- 4. JSON bodies end with a newline; WebSocket messages do not ------------------------------
def test_json_responses_end_with_a_newline(client: TestClient, session: Created) -> None:
    responses = [
        client.get("/readyz"),
        client.get("/healthz"),
        client.get(f"/v1/sessions/{session.id}", headers=session.headers),
        client.post(
            f"/v1/sessions/{session.id}/frames", json=hand_frame(1), headers=session.headers
        ),
        client.get("/v1/sessions/nosuchsession", headers=session.headers),  # an error body
        client.post("/v1/sessions", json={}),  # a validation error
    ]
    for r in responses:
        assert r.headers["content-type"] == "application/json", r.url
        assert r.content.endswith(b"}\n"), (r.url, r.content[-20:])
        assert int(r.headers["content-length"]) == len(r.content)
        assert isinstance(r.json(), dict)


def test_websocket_messages_stay_without_a_newline(client: TestClient, session: Created) -> None:
    with client.websocket_connect(f"/v1/sessions/{session.id}/ws", headers=session.headers) as ws:
        ws.send_json({"type": "ping", "id": 1})
        assert ws.receive_text() == '{"id":1,"type":"pong"}'


# -- 5. two more first-minute mistakes ----------------------------------------------------------
def test_a_misspelt_field_is_told_the_near_name(client: TestClient, session: Created) -> None:
    frame = {"targets": [{"effector": "hand", "positon": {"x": 0.3, "y": 0.1, "z": 0.6}}]}
    r = client.post(f"/v1/sessions/{session.id}/frames", json=frame, headers=session.headers)
    assert r.status_code == 422 and r.json()["code"] == "invalid_format", r.text
    assert "did you mean 'position'" in r.json()["detail"][0]["msg"]
    # A name that is nothing like a field keeps pydantic's message.
    frame = {"targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}, "q": 1}]}
    r = client.post(f"/v1/sessions/{session.id}/frames", json=frame, headers=session.headers)
    assert "did you mean" not in r.json()["detail"][0]["msg"], r.text


@pytest.mark.parametrize("binary", [False, True], ids=["json", "msgpack"])
def test_a_misspelt_field_is_told_the_near_name_on_the_websocket_too(
    client: TestClient, session: Created, binary: bool
) -> None:
    """A WebSocket error carries one error: the hinted one, not "targets: Field required"."""
    message = {"type": "frame", "id": 3, "target": hand_frame(None)["targets"]}
    error = ws_exchange(client, session, message, binary=binary)["error"]
    assert error["code"] == "invalid_format", error
    assert error["message"] == "unknown field 'target'; did you mean 'targets'?", error
    assert error["field"] == "frame.target", error


@pytest.mark.parametrize("binary", [False, True], ids=["json", "msgpack"])
def test_an_id_sent_as_a_float_is_told_to_send_the_integer(
    client: TestClient, session: Created, binary: bool
) -> None:
    """Godot's JSON and a C# double write an id as 3.0; the contract's ids are integers."""
    message = {"type": "frame", "id": 3.0, **{"targets": hand_frame(None)["targets"]}}
    error = ws_exchange(client, session, message, binary=binary)["error"]
    assert (error["code"], error["field"]) == ("invalid_format", "frame.id"), error
    assert "got 3.0 (send 3:" in error["message"], error
    message["id"] = 2.5  # not a whole number: nothing to suggest
    error = ws_exchange(client, session, message, binary=binary)["error"]
    assert error["message"].endswith("got 2.5"), error
    # Over HTTP too, for any integer field.
    r = client.patch(f"/v1/sessions/{session.id}", json={"max_iter": 50.0}, headers=session.headers)
    assert r.status_code == 422, r.text
    assert "got 50.0 (send 50:" in r.json()["detail"][0]["msg"], r.text


def test_a_misspelt_field_in_a_batch_entry_is_told_the_near_name(
    client: TestClient, session: Created
) -> None:
    entry = {"session": session.id, "token": session.token, "id": 1, "target": []}
    answer = ws_exchange(client, session, {"type": "batch", "id": 2, "frames": [entry]})
    error = answer["results"][0]["error"]
    assert error["message"] == "unknown field 'target'; did you mean 'targets'?", answer
    assert error["field"] == "frames[0].target", answer


@pytest.mark.parametrize("bad", ["NaN", "Infinity", "1e400"])
def test_a_json_number_orjson_refuses_still_echoes_the_id(
    client: TestClient, session: Created, bad: str
) -> None:
    """NaN, Infinity and 1e400 are not JSON to orjson, but the id beside them is readable."""
    text = (
        '{"type": "frame", "id": 7, "targets": [{"effector": "hand", '
        f'"position": {{"x": {bad}, "y": 0.1, "z": 0.6}}}}]}}'
    )
    answer = ws_exchange(client, session, text)
    assert answer["id"] == 7, answer
    assert answer["error"]["code"] == "invalid_format", answer
    assert answer["error"]["field"] == "frame.targets[0].position.x", answer


def test_an_id_beyond_the_schema_beside_a_nan_is_not_echoed_and_the_socket_stays(
    client: TestClient, session: Created
) -> None:
    """Read leniently, an id can be any integer: one over 64 bits is not echoed (orjson
    could not write it: the socket closed 1011 with a logged traceback)."""
    with client.websocket_connect(f"/v1/sessions/{session.id}/ws", headers=session.headers) as ws:
        ws.send_text('{"id": 100000000000000000000, "type": "ping", "x": NaN}')
        answer = ws.receive_json()
        ws.send_json({"type": "ping", "id": 1})
        pong = ws.receive_json()
    assert answer["id"] is None and answer["error"]["code"] == "invalid_format", answer
    assert pong == {"id": 1, "type": "pong"}


def test_a_batch_entry_with_an_id_beyond_the_schema_is_its_own_error_not_a_500(
    client: TestClient, session: Created
) -> None:
    """An entry's id is echoed in its error only within the schema's range: FastAPI's
    json and pydantic's JSON mode (a NaN elsewhere in a WebSocket batch) keep ints of
    any size, which orjson cannot write (a 500, a 1011 close)."""
    entry = {"session": session.id, "token": session.token, "id": 10**20, "targets": []}
    r = client.post("/v1/batch", json={"frames": [entry]})
    assert r.status_code == 200, r.text
    (result,) = r.json()["results"]
    assert result["id"] is None and result["error"]["code"] == "invalid_format", result
    nan_target = {"effector": "hand", "position": {"x": "NAN", "y": 0, "z": 0}}
    message = {"type": "batch", "id": 2, "frames": [{**entry, "targets": [nan_target]}]}
    text = json.dumps(message).replace('"NAN"', "NaN")  # a NaN: orjson refuses the text
    with client.websocket_connect(f"/v1/sessions/{session.id}/ws", headers=session.headers) as ws:
        ws.send_text(text)
        answer = ws.receive_json()
        ws.send_json({"type": "ping", "id": 3})
        pong = ws.receive_json()
    assert answer["type"] == "batch_result", answer
    assert answer["results"][0]["id"] is None, answer
    assert pong == {"id": 3, "type": "pong"}


def test_an_unknown_type_beside_a_nan_is_told_the_types(
    client: TestClient, session: Created
) -> None:
    answer = ws_exchange(client, session, '{"id": 5, "type": "frme", "x": NaN}')
    assert answer["id"] == 5 and answer["error"]["field"] == "type", answer
    assert 'unknown message type "frme"' in answer["error"]["message"], answer


def test_a_msgpack_map_key_that_is_not_a_string_is_named(
    client: TestClient, session: Created
) -> None:
    """Valid MessagePack that msgpack refuses (an integer key) is told so, with its id."""
    with client.websocket_connect(f"/v1/sessions/{session.id}/ws", headers=session.headers) as ws:
        ws.send_bytes(msgpack.packb({1: "frame", "id": 4}))
        answer = msgpack.unpackb(ws.receive_bytes())
        # Bytes msgpack cannot read at all keep the short answer, with no id.
        ws.send_bytes(b"\xc1")
        garbage = msgpack.unpackb(ws.receive_bytes())
    assert answer["id"] == 4, answer
    assert answer["error"]["message"] == (
        "a MessagePack map key must be a string, and this message has a key of type int"
    ), answer
    assert garbage["id"] is None and garbage["error"]["message"].startswith("not MessagePack")


def test_binary_messages_that_are_not_msgpack_say_what_they_are(
    client: TestClient, session: Created
) -> None:
    """A trial's findings: JSON in a binary frame (C#'s ClientWebSocket sending bytes)
    was told "not MessagePack: ExtraData", cut-off MessagePack "ValueError", and keys
    packed as bin "the message has no type"."""
    ping = {"type": "ping", "id": 6}
    with client.websocket_connect(f"/v1/sessions/{session.id}/ws", headers=session.headers) as ws:
        answers = []
        for data in (
            orjson.dumps(ping),
            msgpack.packb(ping)[:-2],
            msgpack.packb({b"type": "ping", "id": 7}, use_bin_type=True),
        ):
            ws.send_bytes(data)
            answers.append(msgpack.unpackb(ws.receive_bytes()))
        ws.send_bytes(msgpack.packb(ping))  # the socket is still open and answers
        pong = msgpack.unpackb(ws.receive_bytes())
    json_bytes, cut, bin_key = (a["error"]["message"] for a in answers)
    assert json_bytes == (
        "a binary message is read as MessagePack and this one is JSON: send JSON as text"
    )
    assert cut == "not MessagePack: ValueError (Unpack failed: incomplete input)"
    assert "the bin key b'type'" in bin_key and "pack the keys as str" in bin_key
    assert answers[2]["id"] == 7  # its id is under a str key
    assert all(a["error"]["code"] == "invalid_format" for a in answers)
    assert pong == {"id": 6, "type": "pong"}


@pytest.mark.parametrize("scheme", ["", "Token "])
def test_a_token_without_bearer_is_told_the_header_form(
    client: TestClient, session: Created, scheme: str
) -> None:
    headers = {"Authorization": f"{scheme}{session.token}"}
    r = client.get(f"/v1/sessions/{session.id}", headers=headers)
    assert r.status_code == 401 and r.json()["code"] == "unauthorized", r.text
    assert "'Bearer <token>'" in r.json()["detail"]
    assert session.token not in r.text  # the token is never echoed
    assert client.get(f"/v1/sessions/{session.id}", headers=session.headers).status_code == 200


@pytest.mark.parametrize(
    "body",
    [b'{"chain": "\xff\xfe"}', b"[" * 100_000 + b"]" * 100_000],
    ids=["not-utf8", "nested-100000-deep"],
)
def test_a_body_that_cannot_be_decoded_names_the_body(client: TestClient, body: bytes) -> None:
    # FastAPI's own answer had no field and said only "There was an error parsing the body".
    r = client.post("/v1/sessions", content=body, headers={"content-type": "application/json"})
    assert r.status_code == 422, r.text
    error = r.json()
    assert error["code"] == "invalid_format" and error["field"] == "body", error
    assert "not UTF-8" in error["detail"][0]["msg"], error


# -- an engine's own forms of a rotation, a vector and the conventions (Unreal trial) --------
@pytest.mark.parametrize(
    ("field_name", "value", "words", "field"),
    [
        ("orientation", {"pitch": 10, "yaw": 90, "roll": 0}, "Euler angles", ".orientation.w"),
        ("orientation", {"X": 0, "Y": 0, "Z": 0, "W": 1}, "lower case", ".orientation.w"),
        ("position", {"X": 0.3, "Y": 0.1, "Z": 0.6}, "lower case", ".position.x"),
    ],
    ids=["frotator", "upper-case-quaternion", "upper-case-vector"],
)
@pytest.mark.parametrize("transport", ["http", "json", "msgpack"])
def test_an_engines_rotation_or_vector_form_is_told_the_contracts(
    client: TestClient, field_name: str, value: Any, words: str, field: str, transport: str
) -> None:
    pose_arm = copy.deepcopy(EXAMPLE_ARM)
    pose_arm["effectors"] = [{"name": "hand", "link": "hand", "mode": "pose"}]
    s = create(client, pose_arm)
    target = {
        "effector": "hand",
        "position": {"x": 0.3, "y": 0.1, "z": 0.6},
        "orientation": {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0},
        field_name: value,
    }
    if transport == "http":
        r = client.post(
            f"/v1/sessions/{s.id}/frames", json={"targets": [target]}, headers=s.headers
        )
        assert r.status_code == 422 and r.json()["code"] == "invalid_format", r.text
        assert r.json()["field"] == f"frame.targets[0]{field}"
        message = r.json()["detail"][0]["msg"]
    else:
        frame = {"type": "frame", "id": 1, "targets": [target]}
        error = ws_exchange(client, s, frame, binary=transport == "msgpack")["error"]
        assert error["code"] == "invalid_format", error
        message = error["message"]
    assert words in message, message


def test_a_misspelt_upper_case_field_is_told_the_lower_case_name(
    client: TestClient, session: Created
) -> None:
    frame = {"targets": [{"effector": "hand", "Position": {"x": 0.3, "y": 0.1, "z": 0.6}}]}
    r = client.post(f"/v1/sessions/{session.id}/frames", json=frame, headers=session.headers)
    assert r.status_code == 422, r.text
    messages = [e["msg"] for e in r.json()["detail"]]
    assert any("field names are lower case: 'position'" in m for m in messages), messages


@pytest.mark.parametrize(
    ("conventions", "words"),
    [({"unit_m": 0.01}, '"unit": "m" or "cm"'), ("unreal", '{"preset": "unreal"}')],
    ids=["the-answers-unit_m", "a-bare-preset"],
)
def test_conventions_in_the_answers_form_or_bare_are_told_the_requests(
    client: TestClient, conventions: Any, words: str
) -> None:
    body = {"chain": EXAMPLE_ARM, "conventions": conventions}
    r = client.post("/v1/sessions", json=body)
    assert r.status_code == 422 and r.json()["code"] == "invalid_format", r.text
    assert r.json()["field"].startswith("conventions")
    assert words in r.json()["detail"][0]["msg"], r.text


@pytest.mark.parametrize("transport", ["http", "msgpack"])
def test_a_value_where_an_object_belongs_is_told_in_the_wires_terms(
    client: TestClient, session: Created, transport: str
) -> None:
    """pydantic's message named a Python class ("a valid dictionary or instance of
    Target") for a string where a target belongs (game-server trial)."""
    if transport == "http":
        r = client.post(
            f"/v1/sessions/{session.id}/frames",
            json={"targets": ["hand"]},
            headers=session.headers,
        )
        assert r.status_code == 422, r.text
        message = r.json()["detail"][0]["msg"]
    else:
        frame = {"type": "frame", "id": 1, "targets": ["hand"]}
        message = ws_exchange(client, session, frame, binary=True)["error"]["message"]
    assert "instance of" not in message, message
    assert "an object is expected" in message and '"hand"' in message, message


def test_an_array_with_an_integer_beyond_64_bits_is_hinted_not_a_500(
    client: TestClient, session: Created
) -> None:
    """The array hint wrote the client's numbers with orjson, which refuses an integer
    beyond 64 bits: a 500, and in a batch every other character's entry lost (review)."""
    big = [10**30, 0, 0]
    target = {"effector": "hand", "position": big}
    r = client.post(
        f"/v1/sessions/{session.id}/frames", json={"targets": [target]}, headers=session.headers
    )
    assert r.status_code == 422 and r.json()["code"] == "invalid_format", r.text
    assert "1000000000000000000000000000000" in r.json()["detail"][0]["msg"], r.text
    other = create(client)
    entries = [
        {"session": other.id, "token": other.token, "id": 1, **hand_frame(None)},
        {"session": session.id, "token": session.token, "id": 1, "targets": [target]},
    ]
    r = client.post("/v1/batch", json={"frames": entries})
    assert r.status_code == 200, r.text
    good, bad = r.json()["results"]
    assert good["success"] and bad["error"]["code"] == "invalid_format", r.text
    frame = {"type": "frame", "id": 2, "targets": [target]}
    error = ws_exchange(client, session, json.dumps(frame))["error"]
    assert error["code"] == "invalid_format", error


def test_a_422_lists_at_most_50_errors_and_counts_the_rest(
    client: TestClient, session: Created
) -> None:
    """pydantic reports each unknown key: a position with 20,000 of them (a 250 KB body)
    was answered with 2.9 MB listing every one (review)."""
    position = {"x": 0.3, "y": 0.1, "z": 0.6, **{f"k{i}": 0 for i in range(20_000)}}
    r = client.post(
        f"/v1/sessions/{session.id}/frames",
        json={"targets": [{"effector": "hand", "position": position}]},
        headers=session.headers,
    )
    assert r.status_code == 422 and r.json()["code"] == "invalid_format", r.text[:300]
    detail = r.json()["detail"]
    assert len(detail) == 51 and len(r.content) < 50_000, (len(detail), len(r.content))
    assert detail[-1]["type"] == "too_many_errors" and "19950 more errors" in detail[-1]["msg"]
