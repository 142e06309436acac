"""The JSON contract: finite floats, no unknown fields, quaternion norms, round trips,
and Literals that stay equal to the solver's enums."""

from __future__ import annotations

import json
import math
from typing import Any, get_args

import msgpack
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import TypeAdapter, ValidationError

import schemas as S
from schemas.chain import EXAMPLE_ARM, EffectorModeName, ExampleName, JointKindName
from schemas.results import IKStatusName, TerminationName
from solver.ik import IKStatus
from solver.model import EffectorMode, JointKind
from solver.model.examples import EXAMPLES
from solver.optim import Termination

CLIENT: TypeAdapter[Any] = TypeAdapter(S.ClientMessage)
FRAMES: TypeAdapter[Any] = TypeAdapter(S.FramesBody)
TARGET = {"effector": "hand", "position": {"x": 0.1, "y": 0.2, "z": 0.3}}


def test_literals_match_the_solver_enums() -> None:
    assert set(get_args(JointKindName)) == {k.value for k in JointKind}
    assert set(get_args(EffectorModeName)) == {m.value for m in EffectorMode}
    assert set(get_args(IKStatusName)) == {s.value for s in IKStatus}
    assert set(get_args(TerminationName)) == {t.value for t in Termination}
    assert set(get_args(ExampleName)) == set(EXAMPLES)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_floats_rejected(bad: float) -> None:
    with pytest.raises(ValidationError):
        S.Vec3(x=bad, y=0.0, z=0.0)
    with pytest.raises(ValidationError):
        S.OptionsPatch(time_budget_us=bad)
    with pytest.raises(ValidationError):
        S.PoseIn(q=[0.0, bad])
    # MessagePack can carry NaN, JSON from Python's json module too.
    raw = {
        "type": "frame",
        "id": 1,
        "targets": [{**TARGET, "position": {"x": bad, "y": 0, "z": 0}}],
    }
    with pytest.raises(ValidationError):
        CLIENT.validate_python(msgpack.unpackb(msgpack.packb(raw)))
    with pytest.raises(ValidationError):
        CLIENT.validate_json(json.dumps(raw))


@pytest.mark.parametrize(
    ("model", "data"),
    [
        (S.Vec3, {"x": 0, "y": 0, "z": 0, "w": 0}),
        (S.Target, {**TARGET, "rotation": [1, 0, 0, 0]}),
        (S.Frame, {"targets": [TARGET], "time": 1}),
        (S.SessionCreate, {"chain": EXAMPLE_ARM, "token": "x"}),
        (S.OptionsPatch, {"gtol": 1e-9}),
        (S.HierarchyChain, {**EXAMPLE_ARM, "name": "arm"}),
    ],
)
def test_unknown_fields_rejected(model: type[S.StrictModel], data: dict[str, Any]) -> None:
    with pytest.raises(ValidationError) as info:
        model.model_validate(data)
    assert any(e["type"] == "extra_forbidden" for e in info.value.errors())


def test_quaternion_must_be_unit_within_tolerance() -> None:
    S.Quaternion(w=1.0005, x=0.0, y=0.0, z=0.0)
    with pytest.raises(ValidationError):
        S.Quaternion(w=0.0, x=0.0, y=0.0, z=0.0)
    with pytest.raises(ValidationError):
        S.Quaternion(w=1.0, x=1.0, y=0.0, z=0.0)


def test_quaternion_is_an_object_not_an_array() -> None:
    with pytest.raises(ValidationError):
        S.Target.model_validate({**TARGET, "orientation": [1, 0, 0, 0]})


def test_target_needs_something() -> None:
    with pytest.raises(ValidationError):
        S.Target(effector="hand")


def test_pose_needs_exactly_one_form() -> None:
    with pytest.raises(ValidationError):
        S.PoseIn()
    with pytest.raises(ValidationError):
        S.PoseIn(q=[0.0], joints={"a": 0.0})


def test_frames_body_is_a_frame_or_a_clip() -> None:
    assert isinstance(FRAMES.validate_python({"targets": [TARGET]}), S.Frame)
    clip = FRAMES.validate_python(
        {"frames": [{"targets": [TARGET]}, {"id": 2, "targets": [TARGET]}]}
    )
    assert isinstance(clip, S.ClipRequest) and [f.id for f in clip.frames] == [None, 2]
    with pytest.raises(ValidationError):
        FRAMES.validate_python({"frames": [], "targets": [TARGET]})


def test_frame_ids_are_non_negative_and_js_safe() -> None:
    with pytest.raises(ValidationError):
        S.Frame(id=-1, targets=[S.Target.model_validate(TARGET)])
    with pytest.raises(ValidationError):
        S.Frame(id=2**53, targets=[S.Target.model_validate(TARGET)])


def test_chain_formats_discriminated_by_format() -> None:
    adapter: TypeAdapter[Any] = TypeAdapter(S.ChainSpec)
    assert isinstance(adapter.validate_python(EXAMPLE_ARM), S.HierarchyChain)
    assert isinstance(
        adapter.validate_python({"format": "example", "name": "tail"}), S.ExampleChain
    )
    with pytest.raises(ValidationError):
        adapter.validate_python({"format": "sdf", "text": ""})
    with pytest.raises(ValidationError):
        adapter.validate_python({"format": "example", "name": "octopus"})


def test_ws_messages_discriminated_by_type() -> None:
    frame = CLIENT.validate_json(json.dumps({"type": "frame", "id": 3, "targets": [TARGET]}))
    assert isinstance(frame, S.FrameMessage) and frame.id == 3
    assert isinstance(CLIENT.validate_python({"type": "ping", "id": 4}), S.PingMessage)
    with pytest.raises(ValidationError):
        CLIENT.validate_python({"type": "ping"})


finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)


@given(x=finite, y=finite, z=finite, fid=st.integers(min_value=0, max_value=2**53 - 1))
def test_frame_json_and_msgpack_round_trip(x: float, y: float, z: float, fid: int) -> None:
    msg = S.FrameMessage(
        type="frame",
        id=fid,
        targets=[S.Target(effector="e", position=S.Vec3(x=x, y=y, z=z))],
    )
    assert CLIENT.validate_json(msg.model_dump_json()) == msg
    packed = msgpack.packb(msg.model_dump(mode="json"))
    assert CLIENT.validate_python(msgpack.unpackb(packed)) == msg


def test_example_arm_is_a_valid_hierarchy_and_round_trips() -> None:
    chain = S.HierarchyChain.model_validate(EXAMPLE_ARM)
    again = S.HierarchyChain.model_validate_json(chain.model_dump_json())
    assert again == chain


def test_openapi_schemas_carry_descriptions_and_examples() -> None:
    schema = S.SessionCreate.model_json_schema()
    assert schema["examples"]
    target = S.Target.model_json_schema()
    # A target's unit is the session's (its conventions), not always metres.
    assert "[session unit]" in target["properties"]["position"].get("description", "")
