"""What a shared store keeps of a stream renders and restores as it was: a stored answer
gives the same FrameResult (full and compact) as the solved frame, and a stored stream
state continues the stream exactly where it was."""

from __future__ import annotations

import numpy as np

import schemas as S
from service import convert
from service.config import Settings
from service.convert import SolvedFrame
from service.solving import make_solver
from service.stored_frames import (
    StoredAnswer,
    StreamRecord,
    jobs_digest,
    pack_answer,
    pack_stream,
    unpack_answer,
    unpack_stream,
)
from solver.ik import StreamState, Target

DOWN = {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0}


def _panda() -> convert.ChainView:
    body = S.SessionCreate.model_validate({"chain": {"format": "example", "name": "panda_arm"}})
    return convert.chain_from_spec(body.chain, Settings(), body.conventions, body.bones)


def _targets(view: convert.ChainView, x: float) -> list[Target]:
    frame = S.Target.model_validate(
        {"effector": "tool", "position": {"x": x, "y": 0.1, "z": 0.45}, "orientation": DOWN}
    )
    return convert.targets([frame], view, "targets")


def test_a_stored_answer_renders_as_the_solved_frame() -> None:
    view = _panda()
    solver = make_solver(view, convert.session_defaults(Settings()))
    jobs = [(7, _targets(view, 0.45))]
    solved = [SolvedFrame(7, solver.track(jobs[0][1]), 123.5)]
    stored = unpack_answer(pack_answer(StoredAnswer(jobs_digest(jobs), tuple(solved))))
    assert stored.digest == jobs_digest(jobs)
    (again,) = stored.frames
    for build in (convert.result_dict, convert.compact_result_dict):
        assert build(again.result, 7, again.server_us) == build(solved[0].result, 7, 123.5)


def test_the_digest_tells_other_targets_or_ids_apart() -> None:
    view = _panda()
    a = [(1, _targets(view, 0.45))]
    assert jobs_digest(a) == jobs_digest([(1, _targets(view, 0.45))])
    assert jobs_digest(a) != jobs_digest([(1, _targets(view, 0.46))])
    assert jobs_digest(a) != jobs_digest([(2, _targets(view, 0.45))])


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
