"""The WebSocket's ``batch`` message, read entry by entry (service/batch.py solves it).

A batch whose envelope (``type``, ``id``, ``frames``) is well formed is not validated as
a whole: each entry is read on its own, so that one bad entry gets its own error. A
well-formed entry whose token opens its session goes the fast way
(``convert.fast_targets``, as a ``frame`` message does); any other entry is validated
by pydantic in the message's encoding, which gives its documented error. As for frames,
the fast way only decides how fast a good entry goes, never what an answer says.
"""

from __future__ import annotations

import contextlib
import functools
from typing import Any, NamedTuple, Protocol

import orjson
from pydantic import TypeAdapter

import schemas as S
from schemas.batch import MAX_SESSION_ID_CHARS, MAX_TOKEN_CHARS
from schemas.solve import HARD_MAX_FRAMES, MAX_FRAME_ID

from .. import batch, convert
from ..dependencies import Services
from ..errors import ServiceError
from ..session_tokens import SessionTokens
from ..sessions import SessionStore
from .ws_messages import batch_result_message

_ENTRY: TypeAdapter[S.BatchFrame | S.InvalidEntry] = TypeAdapter(S.BatchEntry)
# The keys of an entry the fast way takes (one with "bones" goes through pydantic).
_FAST_KEYS = frozenset(("session", "token", "id", "targets"))


class RawBatch(NamedTuple):
    """A ``batch`` message with a well-formed envelope, its entries as decoded."""

    id: int
    frames: list[Any]


def raw_batch(raw: Any) -> RawBatch | None:
    """The envelope of a decoded ``batch`` message as the schema accepts it, else None
    (then pydantic validates the message for the error)."""
    if type(raw) is not dict or len(raw) != 3 or raw.get("type") != "batch":
        return None
    msg_id, frames = raw.get("id"), raw.get("frames")
    if type(msg_id) is not int or not 0 <= msg_id <= MAX_FRAME_ID:
        return None
    if type(frames) is not list or not 0 < len(frames) <= HARD_MAX_FRAMES:
        return None
    return RawBatch(msg_id, frames)


class Connection(Protocol):
    """What a batch needs of its socket (ws.py's ``_Connection``)."""

    svc: Services
    build: convert.ResultBuilder
    backlog: bool
    tokens: SessionTokens

    @property
    def client(self) -> str: ...


async def batch_reply(
    msg: RawBatch | S.BatchMessage,
    binary: bool,
    t0: float,
    conn: Connection,
) -> dict[str, Any]:
    """The ``batch_result`` of a batch: each entry's result or its own error.

    Raises:
        ServiceError: for the whole message (service/batch.py: too many entries, ...).
    """
    svc = conn.svc
    batch.check_length(len(msg.frames), svc.settings.max_frames_per_request)
    ready = await entries(msg, binary, svc.store, conn.tokens)
    outcomes = await batch.solve(
        svc.runner, svc.store, ready, t0, "ws", conn.client, may_inline=not conn.backlog
    )
    count = functools.partial(svc.metrics.error, transport="ws")
    results = batch.render(ready, msg.frames, outcomes, conn.build, count)
    return batch_result_message(msg.id, results)


async def entries(
    msg: RawBatch | S.BatchMessage, binary: bool, store: SessionStore, tokens: SessionTokens
) -> list[batch.Entry | ServiceError]:
    """Each entry of a batch, ready to solve or as its own error, in order."""
    if isinstance(msg, S.BatchMessage):  # validated as a whole by pydantic
        return [await batch.prepare(i, f, store, tokens) for i, f in enumerate(msg.frames)]
    out: list[batch.Entry | ServiceError] = []
    for i, raw in enumerate(msg.frames):
        # No await for a session this socket has opened before (the common case: the
        # same characters every tick), one less coroutine per entry.
        ready = _known_entry(raw, tokens)
        out.append(ready if ready is not None else await _entry(i, raw, binary, store, tokens))
    return out


def _fields(raw: Any) -> tuple[str, str, int | None] | None:
    """An entry's session id, token and frame id if it has the fast way's keys and
    their types and bounds are the schema's, else None."""
    if (
        type(raw) is dict
        and raw.keys() <= _FAST_KEYS
        and type(session_id := raw.get("session")) is str
        and type(token := raw.get("token")) is str
        and 0 < len(session_id) <= MAX_SESSION_ID_CHARS
        and 0 < len(token) <= MAX_TOKEN_CHARS
        and (
            (frame_id := raw.get("id")) is None
            or (type(frame_id) is int and 0 <= frame_id <= MAX_FRAME_ID)
        )
    ):
        return session_id, token, frame_id
    return None


def _known_entry(raw: Any, tokens: SessionTokens) -> batch.Entry | None:
    """A well-formed entry for a session this socket has opened with the same token."""
    if (fields := _fields(raw)) is None:
        return None
    session_id, token, frame_id = fields
    session = tokens.known(session_id, token)
    if session is None:
        return None
    targets = convert.fast_targets(raw.get("targets"), session.view)
    return None if targets is None else batch.new_entry(session, frame_id, targets)


async def _entry(
    index: int, raw: Any, binary: bool, store: SessionStore, tokens: SessionTokens
) -> batch.Entry | ServiceError:
    if (fields := _fields(raw)) is not None:
        session_id, token, frame_id = fields
        # A session the token does not open: the pydantic path says so, after it has
        # checked the entry's format (the order of the errors stays the schema's).
        with contextlib.suppress(ServiceError):
            session = await tokens.open(session_id, token)
            targets = convert.fast_targets(raw.get("targets"), session.view)
            if targets is not None:
                return batch.new_entry(session, frame_id, targets)
    if binary:
        frame = _ENTRY.validate_python(raw)
    else:  # the schema's JSON mode, as for a whole text message (ws.py decode)
        frame = _ENTRY.validate_json(orjson.dumps(raw))
    return await batch.prepare(index, frame, store, tokens)
