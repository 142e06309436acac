"""A session's WebSocket as a stream of frames: ids, pipelining, encodings, reconnects.

The stream numbers its messages itself (0, 1, 2, ...), so a caller can send many and match
the answers by the id each ``send_*`` returned; the server answers in order. When the
connection drops (or the server closes 1011, 1012 or 1013, or answers ``shutting_down``, or
``not_ready`` after a reconnect), the stream reconnects within its ``Reconnect`` budget
(../reconnect.py: a deadline, backoff with jitter) and sends again, in order, every message
that had no answer yet, under
the id it was first sent with (each connection wants increasing ids; the stream keeps one
counter over every connection, so they still increase). Of what other tasks send to an
``AsyncStream`` while it reconnects, at most ``max_queued`` messages wait for the new
connection (../queued.py: the oldest beyond it are dropped unsent, ``MessageDropped``); the
blocking ``Stream`` reconnects inside the call that met the drop, so nothing waits
behind it. Answers are reported under the id the caller got, and each message gets
exactly one (a dropped one: its ``MessageDropped``). A server that keeps answers (sessions
in Redis, docs/operations.md) answers a message it had solved, and whose answer was lost
in the drop, with that stored answer (on another worker too): it is never solved twice.

The modules, each with one job: ``pipeline`` (ids, encodings, what waits for an
answer), ``recovery`` (which failures a reconnect can mend, and the budget) and
``messages`` (the messages as sent, the checks of their answers) hold all of that
without I/O; ``base`` is what both streams hold; ``async_stream`` (``AsyncStream``,
websockets' asyncio client) and ``sync_stream`` (``Stream``, its threading client) only
move bytes and wait. How a message is written and an answer read: ../encoding.py.
"""

from .async_stream import AsyncStream
from .base import MAX_ANSWER_BYTES, OPEN_TIMEOUT_S, PING_INTERVAL_S, PING_TIMEOUT_S
from .sync_stream import Stream

__all__ = [
    "MAX_ANSWER_BYTES",
    "OPEN_TIMEOUT_S",
    "PING_INTERVAL_S",
    "PING_TIMEOUT_S",
    "AsyncStream",
    "Stream",
]
