"""A batch entry's own errors: the ``invalid_format`` of an entry that failed the
schema, and the session and frame id its error echoes (service/batch.py answers them).

An entry's validation errors come without the value at fault (schemas.batch keeps
pydantic's ``input`` out of them: it may be a whole entry). The hints a frame sent alone
gets (service.hints: an array where a vector or quaternion object belongs, a whole
number sent as ``3.0``) are worked out from that value, so it is read back here from
the entry as sent, by the error's ``loc``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from starlette import status

import schemas as S
from schemas import ErrorCode

from .errors import ServiceError, echoable_id, field_path, most_helpful

_MISSING = object()


def invalid_entry(index: int, entry: S.InvalidEntry) -> ServiceError:
    """An entry that failed validation, as its ``invalid_format`` error (the field is
    the entry's, ``frames[<index>].<loc>``, as a whole message's validation names it),
    with the hint the same mistake in a frame sent alone gets."""
    errors = [_with_input(e, entry.raw) for e in entry.errors]
    first = most_helpful(errors)
    field = field_path(["frames", index, *first["loc"]])
    return ServiceError(
        ErrorCode.INVALID_FORMAT,
        str(first["msg"]),
        status_code=status.HTTP_422_UNPROCESSABLE_CONTENT,
        field=field,
    )


def _with_input(error: dict[str, Any], raw: Any) -> dict[str, Any]:
    """The error with its ``input``, the value at its ``loc`` in the entry as sent (when
    the error has none and the path leads to one); for a missing field, the object it is
    missing from, as pydantic gives it (the hint for an Euler rotation reads its keys)."""
    if "input" in error:
        return error
    loc = tuple(error.get("loc") or ())
    value = _at(raw, loc[:-1] if error.get("type") == "missing" else loc)
    return error if value is _MISSING else {**error, "input": value}


def _at(raw: Any, loc: Sequence[Any]) -> Any:
    for part in loc:
        if type(raw) is dict and part in raw:
            raw = raw[part]
        elif type(raw) is list and type(part) is int and 0 <= part < len(raw):
            raw = raw[part]
        else:
            return _MISSING
    return raw


def raw_ids(raw: Any) -> tuple[str | None, int | None]:
    """An entry's session id and frame id as sent, each if usable (echoed in its error)."""
    if isinstance(raw, S.BatchFrame):
        return raw.session, raw.id
    if isinstance(raw, S.InvalidEntry):
        raw = raw.raw
    if not isinstance(raw, dict):
        return None, None
    session, frame_id = raw.get("session"), raw.get("id")
    return (
        session if isinstance(session, str) else None,
        echoable_id(frame_id),
    )
