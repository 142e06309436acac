"""What a shared store keeps of a session's stream, as bytes: its state and its answers.

The stream state is what the next frame starts from (pose, carried BFGS matrix, rest
pose, counters); a stored answer is one solved frame, kept so that a frame sent again
under the same id (a client resending after a failover) gets the answer it was given
instead of a second solve. Both are MessagePack of plain numbers: nothing here runs code
from the store (no pickle), so a store that is read by someone else grants nothing.

A retried frame is recognised by its id *and* a digest of its targets: a client that
starts its ids again at 0 on a new connection (allowed by the protocol: ids increase
per connection) sends different targets and is solved as before.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import msgpack
import numpy as np

from solver.ik import FrameStep, IKResult, IKStatus
from solver.ik.result import ResultLayout
from solver.model.mimic import Followers
from solver.optim import Termination

from .convert import FrameJob, SolvedFrame

# Answers kept per session: more than a client has in flight when its connection drops
# (our clients pipeline at most a few dozen frames).
KEPT_ANSWERS = 64


def jobs_digest(jobs: Sequence[FrameJob]) -> bytes:
    """16 bytes that change when any frame's id, targets or animated pose change: each
    target's parts (the packed row), its blend weights and its pole (which the row does
    not hold), and the frame's pose (a frame without one hashes as before poses were)."""
    h = hashlib.blake2b(digest_size=16)
    for frame_id, targets, pose in jobs:
        h.update(str(frame_id).encode())
        if pose is not None:
            h.update(b"\x02" + pose.tobytes())
        for t in targets:
            h.update(t.effector.encode("utf-8", "surrogatepass"))
            h.update(t.given.to_bytes(2, "little"))
            h.update(t.packed.tobytes())
            h.update(np.array([t.position_weight, t.rotation_weight]).tobytes())
            if t.pole is None:
                h.update(b"\x00")
            else:
                h.update(b"\x01" + np.asarray(t.pole.point, dtype=np.float64).tobytes())
                link = t.pole.link
                h.update(
                    b"\x00" if link is None else b"\x01" + link.encode("utf-8", "surrogatepass")
                )
    return h.digest()


def oldest_first(order: list[bytes], answers: dict[bytes, bytes]) -> dict[bytes, bytes]:
    """A session's stored answers (Redis's hash) in its order list's order, oldest
    first, as ``commit`` evicts them. An id the list holds twice (a list written before
    the commit script moved a reused id to the end) is as old as its last place."""
    ordered: dict[bytes, bytes] = {}
    for key in order:
        if key in answers:
            ordered.pop(key, None)
            ordered[key] = answers[key]
    return ordered


@dataclass(frozen=True, slots=True)
class StoredAnswer:
    """A request's solved frames, as given to the client, and the digest of its jobs."""

    digest: bytes
    frames: tuple[SolvedFrame, ...]


@dataclass(slots=True)
class StreamRecord:
    """The part of a session that changes with every frame."""

    q: np.ndarray
    inverse_hessian: np.ndarray | None
    rest: np.ndarray | None  # None: the middle of the limits
    frames: int
    solved: int
    # The stream has an answer to stay near (solver.ik.StreamState.anchored).
    anchored: bool = True
    # Frames missed while not anchored (StreamState.misses): the tenth anchors the
    # stream on whichever worker solves it.
    misses: int = 0


def _array(a: np.ndarray | None) -> bytes | None:
    return None if a is None else np.ascontiguousarray(a, dtype=np.float64).tobytes()


def _unarray(b: bytes | None, shape: tuple[int, ...]) -> np.ndarray | None:
    if b is None:
        return None
    return np.frombuffer(b, dtype=np.float64).reshape(shape).copy()


def pack_stream(record: StreamRecord) -> bytes:
    return bytes(
        msgpack.packb(
            [
                _array(record.q),
                _array(record.inverse_hessian),
                _array(record.rest),
                record.frames,
                record.solved,
                record.anchored,
                record.misses,
            ]
        )
    )


def unpack_stream(data: bytes, n_dof: int) -> StreamRecord:
    values = msgpack.unpackb(data)
    q, h, rest, frames, solved = values[:5]
    # A record written before the sixth value was stored holds five, before the
    # seventh six (a worker of an older release reads the first six and ignores it).
    anchored = bool(values[5]) if len(values) > 5 else True
    misses = int(values[6]) if len(values) > 6 else 0
    q_arr = _unarray(q, (n_dof,))
    assert q_arr is not None
    h_arr, rest_arr = _unarray(h, (n_dof, n_dof)), _unarray(rest, (n_dof,))
    return StreamRecord(q_arr, h_arr, rest_arr, frames, solved, anchored, misses)


def _pack_frame(f: SolvedFrame) -> list[Any]:
    r = f.result
    lay = r.layout
    # Only the errors part of the output block: what the answers are rendered from.
    errors = r.raw[: lay.hessian_start]
    return [
        f.frame_id,
        f.server_us,
        _array(r.q),
        r.status.value,
        r.termination.value,
        r.iterations,
        r.function_evals,
        r.passes,
        r.restarts,
        r.solve_us,
        _array(errors),
        list(lay.dof_names),
        list(lay.effector_names),
        list(lay.tolerances),
        None if f.step is None else [f.step.largest_rad, f.step.jumped],
    ]


def _unpack_frame(row: list[Any], followers: Followers) -> SolvedFrame:
    (fid, server_us, q, status, term, iters, evals, passes, restarts, solve_us) = row[:10]
    errors, dof_names, effector_names, tolerances = row[10:14]
    step = row[14] if len(row) > 14 else None  # answers stored before steps were
    n, m = len(dof_names), len(effector_names)
    layout = ResultLayout(
        tuple(dof_names), tuple(effector_names), (tolerances[0], tolerances[1]), n, m, followers
    )
    # The output block as long as the layout says; past the errors it is NaN (a stored
    # answer keeps no BFGS matrix or pass log: nothing renders them).
    raw = np.full(layout.log_start, np.nan)
    raw[: 3 * m] = np.frombuffer(errors, dtype=np.float64)
    q_arr = _unarray(q, (n,))
    assert q_arr is not None
    result = IKResult(
        q_arr,
        IKStatus(status),
        Termination(term),
        iters,
        evals,
        passes,
        restarts,
        solve_us,
        raw,
        layout,
    )
    frame_step = None if step is None else FrameStep(float(step[0]), bool(step[1]))
    return SolvedFrame(fid, result, server_us, frame_step)


def pack_answer(answer: StoredAnswer) -> bytes:
    return bytes(msgpack.packb([answer.digest, [_pack_frame(f) for f in answer.frames]]))


def unpack_answer(data: bytes, followers: Followers) -> StoredAnswer:
    """A stored answer; ``followers``: its chain's mimic joints (the chain's, not stored:
    a session's chain never changes), rendered by name with each pose."""
    digest, rows = msgpack.unpackb(data)
    return StoredAnswer(digest, tuple(_unpack_frame(r, followers) for r in rows))


def answer_key(jobs: Sequence[FrameJob]) -> int | None:
    """A request's answers are kept under its last frame's id (None: not kept: a frame
    without an id cannot be sent again as the same frame)."""
    return jobs[-1][0] if jobs else None


def answered_among(
    answers: Mapping[int, StoredAnswer], jobs: Sequence[FrameJob]
) -> dict[int, SolvedFrame]:
    """Which of ``jobs`` (one session's entries of a batch, in order) were answered
    before, by their place in ``jobs``: each stored answer whose frames are among them,
    in order, with the same ids and targets (its digest).

    A batch sent again need not be stored as one answer: an entry rate limited the first
    time, or answered with an error, was not stored with the others, and one rate
    limited now is not solved with them. Each stored answer is looked for on its own,
    from the job under its key (its last frame's id) back.
    """
    found: dict[int, SolvedFrame] = {}
    for end, (frame_id, _, _) in enumerate(jobs):
        answer = None if frame_id is None else answers.get(frame_id)
        if answer is None:
            continue
        places = _places(jobs, end, [f.frame_id for f in answer.frames])
        if places is not None and jobs_digest([jobs[i] for i in places]) == answer.digest:
            found.update(zip(places, answer.frames, strict=True))
    return found


def _places(jobs: Sequence[FrameJob], end: int, ids: list[int | None]) -> list[int] | None:
    """The places of ``ids``, in order, among ``jobs[: end + 1]``, the last at ``end``
    (the nearest before it for each), or None when some are not there."""
    places: list[int] = []
    want = len(ids) - 1
    for i in range(end, -1, -1):
        if want < 0:
            break
        if jobs[i][0] == ids[want]:
            places.append(i)
            want -= 1
    return places[::-1] if want < 0 else None
