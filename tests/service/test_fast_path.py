"""The per-frame fast path (convert.fast_frame) against pydantic + convert.targets.

The fast path may only decline: whatever it accepts, the pydantic path must accept too
and turn into the same solver targets; whatever it declines goes through pydantic, so
error answers cannot differ. Over the WebSocket, a connection with the fast path and one
without it must give the same answers to the same messages.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Iterator
from typing import Any

import msgpack
import orjson
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import TypeAdapter, ValidationError
from starlette.testclient import TestClient

import schemas as S
from service import convert
from service.convert.conventions import Z_UP_METRES, Convention, frame_of
from service.errors import ServiceError
from solver.ik import Target, TargetRows
from solver.model import EffectorMode
from solver.model.examples import panda_arm, two_arm_torso

from .helpers import Created, create

CLIENT_MESSAGE: TypeAdapter[Any] = TypeAdapter(S.ClientMessage)


def _in_convention(view: convert.ChainView, preset: str) -> convert.ChainView:
    """The view of a session whose client speaks ``preset``'s conventions."""
    client = frame_of(S.Conventions(preset=preset), Z_UP_METRES)  # type: ignore[arg-type]
    return dataclasses.replace(view, convention=Convention.between(client, Z_UP_METRES))


VIEWS = {
    "position": convert.ChainView.of(panda_arm(EffectorMode.POSITION)),
    "pose": convert.ChainView.of(panda_arm(EffectorMode.POSE)),
    "aim": convert.ChainView.of(panda_arm(EffectorMode.AIM)),
    "two": convert.ChainView.of(two_arm_torso()),
}
# Sessions in another convention: both paths must convert targets the same way.
VIEWS["pose_unreal"] = _in_convention(VIEWS["pose"], "unreal")
VIEWS["aim_unity"] = _in_convention(VIEWS["aim"], "unity")
P = {"x": 0.4, "y": 0.1, "z": 0.5}
Q = {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0}
GOOD: dict[str, list[dict[str, Any]]] = {
    "position": [
        {"effector": "tool", "position": P},
        {"effector": "tool", "position": P, "position_weight": 0.5},
    ],
    "pose": [
        {"effector": "tool", "position": P, "orientation": Q},
        {
            "effector": "tool",
            "position": P,
            "orientation": Q,
            "rotation_weight": 0,
            "position_weight": 1,
        },
        {"effector": "tool", "orientation": {"w": 0.5, "x": 0.5, "y": -0.5, "z": 0.5}},
        {"effector": "tool", "position": None, "orientation": Q, "direction": None},
    ],
    "aim": [
        {"effector": "tool", "direction": {"x": 0, "y": 0, "z": -2}},
        {"effector": "tool", "position": P, "direction": {"x": 1e-3, "y": 0.0, "z": 0.0}},
    ],
    "two": [
        {"effector": "left_hand", "position": P},
        {"effector": "right_hand", "position": {"x": -0.3, "y": 1, "z": 0}},
    ],
}
GOOD["pose_unreal"] = GOOD["pose"]
GOOD["aim_unity"] = GOOD["aim"]
# Leaf replacements: wrong types, bounds, non-finite numbers, ints for floats.
ODD_VALUES: list[Any] = [
    None, True, False, 0, 1, -1, 2, 1.0, 0.5, -0.0, "0.3", "NaN", "", "tool", [], {},
    [0.1, 0.2, 0.3], [1, 0, 0, 0], [0, 0, 0, 1], {"x": 0}, 1e6, -1e6, 1e6 + 1, 1000001, -1e7,
    2**53 - 1, 2**53, 1e300, 1.0004, 0.9991, 0.998, 1e-10, 5e-324, "x" * 129, float("nan"),
    float("inf"),
]  # fmt: skip


def slow_path(raw: Any, view: convert.ChainView) -> tuple[str, Any]:
    """What the WebSocket handler's pydantic path decides for a decoded message."""
    try:
        msg = CLIENT_MESSAGE.validate_python(raw)
    except ValidationError as e:
        return "invalid_format", e.errors(include_url=False, include_input=False)
    if isinstance(msg, S.PingMessage):
        return "ping", msg.id
    try:
        targets = convert.targets(msg.targets, view, "targets")
    except ServiceError as e:
        return e.code, (e.detail, e.field)
    return "frame", (msg.id, targets)


def same_targets(a: list[Target], b: list[Target]) -> bool:
    return len(a) == len(b) and all(
        x.effector == y.effector
        and x.given == y.given
        and x.packed.tobytes() == y.packed.tobytes()
        and (x.position_weight, x.rotation_weight, x.pole)
        == (y.position_weight, y.rotation_weight, y.pole)
        for x, y in zip(a, b, strict=True)
    )


def test_a_target_with_a_pole_takes_the_pydantic_path() -> None:
    pole = {"position": P}
    raw = frame([{"effector": "tool", "position": P, "pole": pole}])
    assert convert.fast_frame(raw, VIEWS["position"]) is None
    kind, (_, targets) = slow_path(raw, VIEWS["position"])
    assert kind == "frame" and targets[0].pole is not None


def check(raw: Any, view: convert.ChainView) -> bool:
    """The fast path agrees with the slow one on ``raw`` (decoded) and on its JSON text;
    returns whether the fast path took it."""
    fast = convert.fast_frame(raw, view)
    kind, slow = slow_path(raw, view)
    if fast is not None:
        assert kind == "frame", (raw, kind, slow)
        assert fast[0] == slow[0]
        assert same_targets(fast[1], slow[1]), raw
    try:
        text = orjson.dumps(raw)
    except TypeError:
        return fast is not None
    fast_json = convert.fast_frame(orjson.loads(text), view)  # what a text frame gives
    if fast_json is not None:
        msg = CLIENT_MESSAGE.validate_json(text)  # must not raise
        assert isinstance(msg, S.FrameMessage)
        assert fast_json[0] == msg.id
        assert same_targets(fast_json[1], convert.targets(msg.targets, view, "targets"))
    # Through MessagePack and back: what a binary frame gives the handler.
    packed = msgpack.unpackb(msgpack.packb(raw), raw=False, strict_map_key=True)
    assert (convert.fast_frame(packed, view) is None) == (fast is None)
    return fast is not None


def frame(targets: list[dict[str, Any]], frame_id: Any = 7) -> dict[str, Any]:
    return {"type": "frame", "id": frame_id, "targets": targets}


def _paths(value: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    yield path
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, (*path, i))


def _set(value: Any, path: tuple[Any, ...], new: Any) -> Any:
    out = copy.deepcopy(value)
    if not path:
        return new
    node = out
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = new
    return out


def _delete(value: Any, path: tuple[Any, ...]) -> Any:
    out = copy.deepcopy(value)
    node = out
    for k in path[:-1]:
        node = node[k]
    del node[path[-1]]
    return out


def corpus(base: dict[str, Any]) -> Iterator[Any]:
    """``base`` and its mutations: every node replaced, deleted or given an extra key."""
    yield base
    for path in _paths(base):
        for v in ODD_VALUES:
            yield _set(base, path, v)
        if path:
            yield _delete(base, path)
        node = base
        for k in path:
            node = node[k]
        if isinstance(node, dict):
            yield _set(base, path, {**node, "extra": 1})
            yield _set(base, (*path, "x"), 2.0) if "x" in node else _set(base, path, node)
    yield {**base, "type": "ping"}
    yield {"type": "ping", "id": 3}
    yield {**base, "targets": base["targets"] * 2}  # two targets for one effector
    yield {**base, "targets": base["targets"] * 257}
    yield {**base, "targets": []}
    yield {**base, "targets": [{**base["targets"][0], "effector": "claw"}]}
    yield [base]
    yield "frame"


@pytest.mark.parametrize("mode", sorted(GOOD))
def test_well_formed_frames_take_the_fast_path_with_the_same_targets(mode: str) -> None:
    view = VIEWS[mode]
    for t in GOOD[mode]:
        assert check(frame([t]), view), t
    if mode == "two":
        assert check(frame(GOOD[mode]), view)


@pytest.mark.parametrize("mode", sorted(GOOD))
def test_malformed_frames_fall_back_to_the_pydantic_path(mode: str) -> None:
    view = VIEWS[mode]
    taken = 0
    n = 0
    for t in GOOD[mode]:
        for raw in corpus(frame([t])):
            n += 1
            taken += check(raw, view)
    assert n > 300
    assert 0 < taken < n  # some mutations are still good frames (1 for 1.0, ...)


def test_rotation_rows_are_the_slow_paths_bit_for_bit() -> None:
    view = VIEWS["pose"]
    for q in (
        {"w": 0.15210539318641714, "x": -0.8882612448470046, "y": -0.4191930835074414, "z": 0.1},
        {"w": 1.0004, "x": 0, "y": 0, "z": 0},
        {"w": math.sqrt(0.5), "x": 0, "y": 0, "z": math.sqrt(0.5)},
    ):
        raw = frame([{"effector": "tool", "orientation": q}])
        assert check(raw, view) == (abs(math.hypot(*q.values()) - 1.0) <= 1e-3)


_number = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-2.0, max_value=2.0),
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.booleans(),
    st.none(),
    st.text(max_size=3),
)
_vec = st.dictionaries(st.sampled_from(["x", "y", "z", "w", "q"]), _number, max_size=5)
_target = st.dictionaries(
    st.sampled_from(["effector", "position", "orientation", "direction", "extra"]),
    st.one_of(_vec, st.sampled_from(["tool", "left_hand", "right_hand", "claw", ""]), _number),
    max_size=5,
)
_message = st.fixed_dictionaries(
    {"type": st.sampled_from(["frame", "ping", "frames"]), "id": _number},
    optional={"targets": st.lists(_target, max_size=3), "extra": _number},
)


@given(raw=_message, mode=st.sampled_from(sorted(GOOD)))
def test_generated_messages_agree(raw: dict[str, Any], mode: str) -> None:
    check(raw, VIEWS[mode])


@given(
    p=st.tuples(*[st.floats(min_value=-1e6, max_value=1e6)] * 3),
    q=st.tuples(*[st.floats(min_value=-1.0, max_value=1.0)] * 4),
)
def test_generated_good_numbers_give_identical_targets(
    p: tuple[float, float, float], q: tuple[float, float, float, float]
) -> None:
    n = math.hypot(*q)
    quat = dict(zip("wxyz", (v / n for v in q), strict=True)) if n > 0.1 else Q
    raw = frame(
        [{"effector": "tool", "position": dict(zip("xyz", p, strict=True)), "orientation": quat}]
    )
    assert check(raw, VIEWS["pose"])


# --- over the WebSocket: the same answers with and without the fast path ---------------
def _answers(
    client: TestClient, session: Created, messages: list[Any], binary: bool
) -> list[dict[str, Any]]:
    out = []
    with client.websocket_connect(f"/v1/sessions/{session.id}/ws", headers=session.headers) as ws:
        for m in messages:
            if binary:
                ws.send_bytes(msgpack.packb(m))
                a = msgpack.unpackb(ws.receive_bytes())
            else:
                ws.send_text(m if isinstance(m, str) else orjson.dumps(m).decode())
                a = ws.receive_json()
            if "result" in a:  # a solve: its numbers depend on timing, not on the path
                a["result"] = {"id": a["result"]["id"]}
                a.pop("success")
            out.append(a)
    return out


@pytest.mark.parametrize("binary", [False, True], ids=["json", "msgpack"])
def test_websocket_answers_are_the_same_without_the_fast_path(
    client: TestClient, monkeypatch: pytest.MonkeyPatch, binary: bool
) -> None:
    base = frame([{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}], 1)
    messages: list[Any] = []
    for i, m in enumerate(corpus(base)):
        if isinstance(m, dict) and m.get("id") == 1:
            m = {**m, "id": 10 * i + 10}  # increasing ids, so good frames are solved
        if not binary:
            try:
                orjson.dumps(m)
            except TypeError:
                continue
        messages.append(m)
    if not binary:
        messages += ["{", '{"type": "frame", "id": NaN}', '{"type":"frame","id":1e400}', "[]"]
    fast_session = create(client)
    slow_session = create(client)
    fast = _answers(client, fast_session, messages, binary)
    monkeypatch.setattr(convert, "fast_frame", lambda raw, view: None)
    slow = _answers(client, slow_session, messages, binary)
    assert len(fast) == len(messages)
    for m, a, b in zip(messages, fast, slow, strict=True):
        assert a == b, m
    assert sum("result" in a for a in fast) >= 5


def test_plain_targets_come_as_packed_rows_weighted_ones_as_targets() -> None:
    """The fast path hands a frame of plain targets to the solver as one packed array
    (``TargetRows``: no Target built per target); a frame with a weight, as Targets.
    Either reads as the slow path's targets (``check``)."""
    view = VIEWS["two"]
    plain = frame(GOOD["two"])
    fast = convert.fast_frame(plain, view)
    assert fast is not None and isinstance(fast[1], TargetRows)
    assert fast[1].rows.shape == (2, 15) and check(plain, view)
    weighted = frame([GOOD["two"][0], {**GOOD["two"][1], "position_weight": 0.5}])
    fast = convert.fast_frame(weighted, view)
    assert fast is not None and type(fast[1]) is list
    assert [t.position_weight for t in fast[1]] == [1.0, 0.5] and check(weighted, view)
