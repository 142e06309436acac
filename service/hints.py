"""Messages for the validation errors a newcomer meets first, saying the form expected.

pydantic's own message stays the answer unless a hint here knows better: an array where
a quaternion or vector object belongs, a field name one typo away from a known one, a
WebSocket message without a known ``type``. Only the message changes; the error's code
(``invalid_format``) and its ``type`` and ``loc`` stay pydantic's.

The hints are worked out from an error after the fact, not by validators on the models:
a before-validator on Vec3 and Quaternion cost every valid HTTP frame 1.5 us (3.1 ->
4.5 us for one pose target's validation, measured), a mistake's hint costs nothing.
"""

from __future__ import annotations

import difflib
import functools
import json
import typing
from collections.abc import Mapping
from typing import Any

import orjson
from pydantic import BaseModel

import schemas as S

# Game engines and robotics libraries order a quaternion's array differently, which is
# why the contract has only objects; the hint says so and shows both readings.
QUATERNION_ARRAY = (
    'a quaternion is an object {"w": ..., "x": ..., "y": ..., "z": ...}, not an array: '
    "arrays are ambiguous because engines order them differently (Unity, three.js and "
    "ROS: x, y, z, w; Blender: w, x, y, z)"
)
VECTOR_ARRAY = 'a vector is an object {"x": ..., "y": ..., "z": ...}, not an array'
# Unreal's FRotator (and Euler angles in general) where a quaternion belongs.
EULER_ANGLES = (
    'Euler angles (pitch, yaw, roll) are not taken: a rotation is a quaternion {"w": ..., '
    '"x": ..., "y": ..., "z": ...} (Unreal: FRotator::Quaternion(); Unity: '
    "Quaternion.Euler(...); Godot: Basis.get_rotation_quaternion()), in the frame the "
    "field's description names"
)
_EULER_NAMES = frozenset({"pitch", "yaw", "roll", "heading", "bank", "euler"})
# The answer's form of the conventions (ConventionsOut) sent back in a request.
CONVENTIONS_UNIT = (
    "unknown field 'unit_m' in conventions: a request names the unit, "
    '"unit": "m" or "cm" (unit_m is how the answer reports it)'
)
CONVENTIONS_OBJECT = (
    'conventions is an object, not {}: {{"preset": "unreal"}}, or "up", "handedness", "unit"'
)
# pydantic's error for a non-object where a model belongs: model_type when it validates
# JSON (it names the model in ctx), model_attributes_type for Python objects (FastAPI's
# bodies, MessagePack), which does not.
_NOT_AN_OBJECT = frozenset({"model_type", "model_attributes_type"})

_LONGEST_GUESS = 64
# FastAPI's error type for a body that does not parse as JSON.
JSON_INVALID = "json_invalid"


@functools.cache
def _field_names() -> frozenset[str]:
    """Every field name of the contract's models (what a typo is compared with)."""
    names: set[str] = set()
    todo: list[type[S.StrictModel]] = [S.StrictModel]
    while todo:
        model = todo.pop()
        names.update(model.model_fields)
        todo.extend(model.__subclasses__())
    return frozenset(names)


def _models_in(annotation: Any) -> set[type[BaseModel]]:
    found: set[type[BaseModel]] = set()
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        found.add(annotation)
    for arg in typing.get_args(annotation):
        found |= _models_in(arg)
    return found


@functools.cache
def _object_fields() -> dict[str, str]:
    """Field name -> "Quaternion" or "Vec3", for the names that hold only one of them in
    every model (``orientation``, ``position``, ...): which form an array's field wants."""
    kinds: dict[str, set[str]] = {}
    todo: list[type[S.StrictModel]] = [S.StrictModel]
    while todo:
        model = todo.pop()
        todo.extend(model.__subclasses__())
        for name, field in model.model_fields.items():
            kinds.setdefault(name, set()).update(m.__name__ for m in _models_in(field.annotation))
    wanted = {S.Quaternion.__name__, S.Vec3.__name__}
    return {n: k.pop() for n, k in kinds.items() if len(k) == 1 and k <= wanted}


def _numbers(values: list[Any] | tuple[Any, ...], n: int) -> bool:
    """``n`` JSON numbers (a bool is not one)."""
    return len(values) == n and all(type(v) is int or type(v) is float for v in values)


def _json(value: Any) -> str:
    """``value`` as JSON text; an integer beyond 64 bits (which a client's JSON may hold
    and orjson does not write) through the stdlib's encoder."""
    try:
        return orjson.dumps(value).decode()
    except (TypeError, orjson.JSONEncodeError):
        return json.dumps(value, default=repr)


def _quaternion_array(values: list[Any] | tuple[Any, ...]) -> str:
    if not _numbers(values, 4):
        return QUATERNION_ARRAY
    a, b, c, d = values  # both readings: the client knows which one it meant
    as_wxyz = _json({"w": a, "x": b, "y": c, "z": d})
    as_xyzw = _json({"w": d, "x": a, "y": b, "z": c})
    return f"{QUATERNION_ARRAY}; read as w, x, y, z it is {as_wxyz}, as x, y, z, w {as_xyzw}"


def _vector_array(values: list[Any] | tuple[Any, ...]) -> str:
    if not _numbers(values, 3):
        return VECTOR_ARRAY
    x, y, z = values
    return f"{VECTOR_ARRAY}: {_json({'x': x, 'y': y, 'z': z})}"


def _array_hint(error: Mapping[str, Any], values: list[Any] | tuple[Any, ...]) -> str | None:
    model = (error.get("ctx") or {}).get("class_name")
    if model is None:
        loc = error.get("loc") or ()
        model = _object_fields().get(loc[-1]) if loc and isinstance(loc[-1], str) else None
    if model == S.Quaternion.__name__:
        return _quaternion_array(values)
    if model == S.Vec3.__name__:
        return _vector_array(values)
    return None


def _did_you_mean(name: str, parent: Any = None) -> str | None:
    if parent == "conventions" and name == "unit_m":
        return CONVENTIONS_UNIT
    names = _field_names()
    if name in names or len(name) > _LONGEST_GUESS:  # a real field in the wrong place,
        return None  # or nothing like one (and not echoed back)
    if name.lower() in names:  # Unreal's and C#'s X, Y, Z, W
        return f"unknown field {name!r}; field names are lower case: {name.lower()!r}"
    close = difflib.get_close_matches(name, names, n=1, cutoff=0.8)
    return f"unknown field {name!r}; did you mean {close[0]!r}?" if close else None


def _missing_hint(error: Mapping[str, Any]) -> str | None:
    """A quaternion or vector object missing a component, said in the terms of what it
    holds instead: upper-case keys (``{"X": ..}``), or Euler angles (an FRotator's
    pitch, yaw, roll), which pydantic reports as a missing ``w`` first."""
    loc: tuple[Any, ...] = tuple(error.get("loc") or ())
    given = error.get("input")
    if len(loc) < 2 or not isinstance(given, Mapping) or not isinstance(loc[-2], str):
        return None
    kind = _object_fields().get(loc[-2])
    keys = {k.lower() for k in given if isinstance(k, str)}
    if kind == S.Quaternion.__name__ and keys & _EULER_NAMES:
        return EULER_ANGLES
    wanted = "wxyz" if kind == S.Quaternion.__name__ else "xyz" if kind == S.Vec3.__name__ else ""
    if wanted and set(wanted) <= keys:
        return f"{loc[-1]!r} is missing: field names are lower case ({', '.join(wanted)})"
    return None


def hint(error: Mapping[str, Any]) -> str | None:
    """A message saying what was meant for one pydantic error, or None to keep
    pydantic's message."""
    kind = error.get("type")
    value = error.get("input")
    if kind in _NOT_AN_OBJECT and isinstance(value, list | tuple):
        if (array := _array_hint(error, value)) is not None:
            return array
    if kind == "extra_forbidden":
        loc = error.get("loc") or ()
        if loc and isinstance(loc[-1], str):
            return _did_you_mean(loc[-1], loc[-2] if len(loc) > 1 else None)
    if kind == "missing":
        return _missing_hint(error)
    if kind in _NOT_AN_OBJECT and isinstance(value, str) and _names_conventions(error):
        return CONVENTIONS_OBJECT.format(_shown(value))
    if kind in _NOT_AN_OBJECT and "input" in error:
        # pydantic may name a Python class ("a valid dictionary or instance of Target"),
        # which tells a client nothing: say it in the wire's terms.
        return f"an object is expected (a JSON object, a MessagePack map), got {_shown(value)}"
    if kind == JSON_INVALID:
        return _json_hint(error)
    if kind == "int_type" and type(value) is float:
        return _whole_number_hint(value)
    return None


def _names_conventions(error: Mapping[str, Any]) -> bool:
    loc: tuple[Any, ...] = tuple(error.get("loc") or ())
    named = (error.get("ctx") or {}).get("class_name")
    return named == S.Conventions.__name__ or (bool(loc) and loc[-1] == "conventions")


def _whole_number_hint(value: float) -> str:
    """An id or count sent as a float: engines whose numbers are all floats (Godot's
    JSON, a C# double) write ``3.0``, which the contract refuses as an integer."""
    text = f"a whole number without a decimal point is expected, got {_shown(value)}"
    if value.is_integer() and abs(value) <= 2**53:
        text += f" (send {int(value)}: convert the engine's float to an integer first)"
    return text


def _json_hint(error: Mapping[str, Any]) -> str:
    """FastAPI reports a body that is not JSON with the character offset of the fault
    as the last part of ``loc`` (``["body", 4]``); say it in words."""
    loc = error.get("loc") or ()
    where = f" at character {loc[-1]}" if loc and isinstance(loc[-1], int) else ""
    reason = (error.get("ctx") or {}).get("error")
    because = f" ({reason})" if isinstance(reason, str) and reason else ""
    return f"the body is not valid JSON{where}{because}"


def message_type_hint(raw: Any) -> str:
    """What a WebSocket message without a known ``type`` is told: the types there are
    (``schemas.CLIENT_MESSAGE_TYPES``, read from the message union)."""
    types = S.CLIENT_MESSAGE_TYPES
    listed = ", ".join(f'"{t}"' for t in types)
    if not isinstance(raw, dict):
        return f'a message is a JSON (or MessagePack) object with "type" ({listed}) and "id"'
    if "type" not in raw:
        return f'the message has no "type"; the types are {listed}'
    tag = raw["type"]
    text = f"unknown message type {_shown(tag)}; the types are {listed}"
    if isinstance(tag, str) and (close := difflib.get_close_matches(tag, types, n=1)):
        text += f' (did you mean "{close[0]}"?)'
    return text


def _shown(value: Any, limit: int = 40) -> str:
    """A client's value as it wrote it, cut short (it is echoed into our answer)."""
    try:
        text = _json(value)
    except TypeError:  # MessagePack bytes and the like
        text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}..."
