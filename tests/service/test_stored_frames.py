"""What a shared store keeps of a stream renders and restores as it was: a stored answer
gives the same FrameResult (full and compact) as the solved frame, and a stored stream
state continues the stream exactly where it was."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

import schemas as S
from service import convert
from service.config import Settings
from service.convert import SolvedFrame
from service.solving import make_solver
from service.stored_frames import (
    KEPT_ANSWERS,
    StoredAnswer,
    StreamRecord,
    answered_among,
    jobs_digest,
    oldest_first,
    pack_answer,
    pack_stream,
    unpack_answer,
    unpack_stream,
)
from service.write_behind import Pending, WriteBehind
from solver.ik import StreamState, Target
from solver.model.forward import link_poses

PANDA_URDF = (Path(__file__).resolve().parents[1] / "solver/data/panda_kinematic.urdf").read_text()
FINGERS = ["panda_leftfinger", "panda_rightfinger"]

DOWN = {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0}


def _panda() -> convert.ChainView:
    body = S.SessionCreate.model_validate({"chain": {"format": "example", "name": "panda_arm"}})
    return convert.chain_from_spec(body.chain, Settings(), body.conventions, body.bones)


def _targets(view: convert.ChainView, x: float, **extra: Any) -> list[Target]:
    position = {"x": x, "y": 0.1, "z": 0.45}
    frame = S.Target.model_validate(
        {"effector": "tool", "position": position, "orientation": DOWN, **extra}
    )
    return convert.targets([frame], view, "targets")


def _gripper() -> convert.ChainView:
    """The Panda with its fingers: one mimic joint (panda_finger_joint2)."""
    chain = {
        "format": "urdf",
        "urdf": PANDA_URDF,
        "base_link": "panda_link0",
        "tip_links": [*FINGERS, "panda_hand_tcp"],
        "mode": "position",
    }
    body = S.SessionCreate.model_validate({"chain": chain})
    return convert.chain_from_spec(body.chain, Settings(), body.conventions, body.bones)


def _positions(view: convert.ChainView, q: np.ndarray) -> list[Target]:
    poses = link_poses(view.chain, q)
    frame = [
        S.Target.model_validate(
            {
                "effector": link,
                "position": dict(zip("xyz", poses[link][:3, 3].tolist(), strict=True)),
            }
        )
        for link in [*FINGERS, "panda_hand_tcp"]
    ]
    return convert.targets(frame, view, "targets")


def test_a_stored_answer_renders_as_the_solved_frame() -> None:
    """With everything a tracked frame's answer has: its step from the previous answer
    (largest_step_rad, jumped) and the mimic joints' values by name."""
    view = _gripper()
    followers = view.chain.followers
    assert followers.names  # the case under test: a chain with mimic joints
    solver = make_solver(view, convert.session_defaults(Settings()))
    middle = (view.chain.lower + view.chain.upper) / 2
    solver.track(_positions(view, middle))
    jobs = [(7, _positions(view, middle + 0.05), None)]
    tracked = solver.track(jobs[0][1])
    solved = [SolvedFrame(7, tracked, 123.5, solver.last_step)]
    assert solver.last_step.largest_rad > 0
    packed = pack_answer(StoredAnswer(jobs_digest(jobs), tuple(solved)))
    stored = unpack_answer(packed, followers)
    assert stored.digest == jobs_digest(jobs)
    (again,) = stored.frames
    for build in (convert.result_dict, convert.compact_result_dict):
        expected = build(tracked, 7, 123.5, solved[0].step)
        assert build(again.result, 7, again.server_us, again.step) == expected
    full = convert.result_dict(again.result, 7, again.server_us, again.step)
    assert set(followers.names) <= set(full["joints"])
    assert full["largest_step_rad"] == solver.last_step.largest_rad


def test_the_digest_tells_other_targets_or_ids_apart() -> None:
    view = _panda()
    a = [(1, _targets(view, 0.45), None)]
    assert jobs_digest(a) == jobs_digest([(1, _targets(view, 0.45), None)])
    assert jobs_digest(a) != jobs_digest([(1, _targets(view, 0.46), None)])
    assert jobs_digest(a) != jobs_digest([(2, _targets(view, 0.45), None)])


def test_the_digest_tells_other_animated_poses_apart() -> None:
    """A frame's animated pose is part of the frame: the same id and targets from
    another pose (or from none) is another frame; a partial pose's left-out DOFs (NaN)
    hash alike every time."""
    view = _panda()
    n = view.chain.n_dof
    targets = _targets(view, 0.45)
    partial = np.full(n, np.nan)
    partial[1] = 0.3

    def digest(pose: np.ndarray | None) -> bytes:
        return jobs_digest([(1, targets, pose)])

    digests = [digest(None), digest(np.zeros(n)), digest(np.full(n, 0.1)), digest(partial)]
    assert len(set(digests)) == 4
    assert digest(partial.copy()) == digests[3]
    assert digest(np.zeros(n)) == digests[1]


def test_the_digest_tells_other_weights_or_poles_apart() -> None:
    """The same id and position with another blend weight or pole is another frame
    (weights and poles are not in the packed target row)."""
    view = _panda()

    def digest(**extra: Any) -> bytes:
        return jobs_digest([(1, _targets(view, 0.45, **extra), None)])

    plain = digest()
    assert digest(position_weight=1.0) == plain
    variants = [
        digest(position_weight=0.5),
        digest(rotation_weight=0.5),
        digest(pole={"position": {"x": 0.3, "y": 0.0, "z": 0.8}}),
        digest(pole={"position": {"x": 0.3, "y": 0.2, "z": 0.8}}),
        digest(pole={"position": {"x": 0.3, "y": 0.0, "z": 0.8}, "bone": "link3"}),
    ]
    assert len({plain, *variants}) == 1 + len(variants)


def test_a_batch_sent_again_finds_each_stored_answer_among_its_entries() -> None:
    """``answered_among``: each stored answer (frames under their last id) is found among
    a session's entries of a batch sent again, in order, also with entries between or
    after them that were not stored (refused then); an answer whose frames are not all
    there, or whose targets differ, is not used."""
    view = _panda()
    solver = make_solver(view, convert.session_defaults(Settings()))
    jobs = [(k, _targets(view, 0.40 + 0.01 * k), None) for k in range(1, 7)]
    frames = {k: SolvedFrame(k, solver.track(t), float(k), solver.last_step) for k, t, _ in jobs}

    def stored(*ids: int) -> StoredAnswer:
        picked = [jobs[k - 1] for k in ids]
        return StoredAnswer(jobs_digest(picked), tuple(frames[k] for k in ids))

    # Answered before: 1 and 3 in one request (2 failed then), 4 alone; 5 and 6 not.
    answers = {3: stored(1, 3), 4: stored(4)}
    found = answered_among(answers, jobs)
    assert {i: f.frame_id for i, f in found.items()} == {0: 1, 2: 3, 3: 4}
    assert all(found[i] is frames[i + 1] for i in found)
    # Sent again without 1 (1 and 3 were one answer): only 4 is found.
    assert {f.frame_id for f in answered_among(answers, jobs[1:]).values()} == {4}
    # 3 with other targets: its answer is not used.
    moved = [*jobs[:2], (3, _targets(view, 0.5), None), *jobs[3:]]
    assert {f.frame_id for f in answered_among(answers, moved).values()} == {4}
    assert answered_among({}, jobs) == {}
    assert answered_among(answers, [(None, jobs[0][1], None)]) == {}


def test_a_stored_stream_state_continues_the_stream_exactly() -> None:
    view = _panda()
    options = convert.session_defaults(Settings())
    first = make_solver(view, options)
    for x in (0.45, 0.46, 0.47):
        first.track(_targets(view, x))
    state = first.stream_state()
    record = unpack_stream(pack_stream(StreamRecord(state.q, state.inverse_hessian, None, 3, 3)), 7)
    second = make_solver(view, options)
    second.restore(StreamState(record.q, record.inverse_hessian))
    next_targets = _targets(view, 0.48)
    np.testing.assert_array_equal(second.track(next_targets).q, first.track(next_targets).q)
    assert (record.frames, record.solved, record.rest) == (3, 3, None)


def test_a_stream_record_keeps_whether_a_frame_was_answered() -> None:
    """A record says whether the next frame is a stream's first (``answered`` False after
    a pose set); one written before the flag was stored holds five values and reads as
    answered (a rolling deploy reads the old workers' records)."""
    q = np.arange(3, dtype=np.float64)
    fresh = unpack_stream(pack_stream(StreamRecord(q, None, None, 0, 0, False)), 3)
    assert fresh.anchored is False and np.array_equal(fresh.q, q)
    old = msgpack.packb([q.tobytes(), None, None, 4, 4])
    assert unpack_stream(old, 3).anchored is True


def test_a_stream_record_keeps_the_frames_missed_before_the_stream_anchored() -> None:
    """The misses count (StreamState.misses) goes with the record, so that a stream
    served by another worker still anchors at its tenth miss; a record of six values
    (an older worker's) reads as none missed."""
    q = np.arange(3, dtype=np.float64)
    record = unpack_stream(pack_stream(StreamRecord(q, None, None, 4, 0, False, 4)), 3)
    assert (record.anchored, record.misses) == (False, 4)
    six = msgpack.packb([q.tobytes(), None, None, 4, 0, False])
    assert unpack_stream(six, 3).misses == 0


def test_an_id_listed_twice_is_as_old_as_its_last_place() -> None:
    """An order list written before the commit script moved a reused id to the end may
    hold it twice: it is restored as the newest, not evicted first."""
    answers = {b"1": b"new", b"2": b"b", b"3": b"c"}
    restored = oldest_first([b"1", b"2", b"3", b"1", b"9"], answers)
    assert list(restored.items()) == [(b"2", b"b"), (b"3", b"c"), (b"1", b"new")]


def test_written_behind_a_flush_holds_at_most_the_kept_answers_each_id_once() -> None:
    """A long interval (or no frame-rate limit) queues many frames: one flush writes
    what Redis would keep of them, each id with its newest answer."""
    session: Any = type("S", (), {"id": "s1"})()
    record: Any = None
    written: list[list[Pending]] = []

    async def write(batch: list[Pending]) -> None:
        written.append(batch)

    async def run() -> Pending | None:
        behind = WriteBehind(3600.0, write)
        behind.queue(session, record, [1, b"old"])
        for frame_id in range(2, KEPT_ANSWERS + 10):
            behind.queue(session, record, [frame_id, b"a"])
        behind.queue(session, record, [KEPT_ANSWERS + 5, b"again"])
        pending = behind.take("s1")
        await behind.close()
        return pending

    pending = asyncio.run(run())
    assert pending is not None and written == []
    ids, answers = pending.pairs[::2], pending.pairs[1::2]
    assert len(ids) == len(set(ids)) == KEPT_ANSWERS
    assert ids[-1] == KEPT_ANSWERS + 5 and answers[-1] == b"again"  # moved to the end
    assert 1 not in ids  # the oldest left
