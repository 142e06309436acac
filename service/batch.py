"""Batches: one frame for each of several sessions in one message, one answer holding
each result (``POST /v1/batch`` and the WebSocket's ``batch`` message, schemas/batch.py).

An entry is answered on its own: an entry that fails validation, whose token does not
open its session, whose targets do not fit its chain, or whose session is over its rate
limit gets its own error, and the other entries are solved. The limits are those of a
frame sent alone: each session's rate limit (an entry refused before it is solved costs
no frame of it), and for the whole batch, as for a clip,
IK_MAX_FRAMES_PER_REQUEST entries and, when it goes to the frame threads, the client's
share of them (service/work.py). Each session's entries are solved in the order given,
each from the previous answer, under the session's lock.

With a shared store (IK_REDIS_URL) each session's entries are committed as one request
of frames is (service/redis_store.py): stored before they are answered, solved again when
another worker committed the session first; an entry sent again (id and targets) gets its
stored answer, also when another entry of its session failed then or fails now.

Codes, per entry: invalid_format, unauthorized, forbidden, not_found, invalid_problem,
rate_limited, store_unavailable. For the whole batch: invalid_problem (``frames``: too
many entries, or more work than IK_MAX_REQUEST_WORK_S), not_ready, server_busy,
too_much_work.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

import schemas as S
from schemas import ErrorCode
from solver.errors import IKError
from solver.ik import IKStatus
from solver.ik import Target as SolverTarget

from . import convert, stored_frames
from .batch_errors import invalid_entry, raw_ids
from .errors import (
    ServiceError,
    invalid_problem,
    not_found,
    solver_error,
    store_unavailable,
)
from .session_tokens import SessionTokens
from .sessions import STALE_RETRIES, Session, SessionStore, StaleSession, StreamMark
from .solving import Runner, rate_limited
from .work import WorkClass


class Entry(NamedTuple):
    """A batch entry ready to solve: its session, its frame, its bone output and the
    animated pose it starts from (``convert.frame_pose``; None: the previous answer).

    A NamedTuple, not a frozen dataclass: one is built per character of every batch
    message, and the dataclass's ``__init__`` (``object.__setattr__`` per field) cost
    ~0.4 us more per entry (``new_entry`` builds one without the Python ``__new__``).
    """

    session: Session
    frame_id: int | None
    targets: Sequence[SolverTarget]
    bones: S.BoneOutput | None = None
    pose: np.ndarray | None = None


_tuple_new = tuple.__new__


def new_entry(session: Session, frame_id: int | None, targets: Sequence[SolverTarget]) -> Entry:
    """``Entry(session, frame_id, targets)`` (no bone output), built as the tuple it is."""
    return _tuple_new(Entry, (session, frame_id, targets, None, None))


# What each entry comes to: its solved frame, or its own error.
Outcome = convert.SolvedFrame | ServiceError
SolvedFrame = convert.SolvedFrame
_SOLVED = IKStatus.SOLVED


def check_length(n_entries: int, limit: int) -> None:
    """Raises ``invalid_problem`` (``frames``) over IK_MAX_FRAMES_PER_REQUEST entries."""
    if n_entries > limit:
        raise invalid_problem(
            f"at most {limit} entries per batch (IK_MAX_FRAMES_PER_REQUEST)", "frames"
        )


async def prepare(
    index: int,
    frame: S.BatchFrame | S.InvalidEntry,
    store: SessionStore,
    tokens: SessionTokens,
) -> Entry | ServiceError:
    """A validated entry checked against its session: its token, its targets, its
    bone output and its pose (errors name ``frames[index].targets[j]...``)."""
    if isinstance(frame, S.InvalidEntry):
        return invalid_entry(index, frame)
    try:
        session = await tokens.open(frame.session, frame.token)
        view = session.view
        targets = convert.targets(frame.targets, view, f"frames[{index}].targets")
        if frame.bones is not None:
            convert.check_bone_output(frame.bones, view.skeleton, f"frames[{index}].bones")
        pose = convert.frame_pose(frame.pose, view, f"frames[{index}].pose")
    except ServiceError as e:
        return e
    return Entry(session, frame.id, targets, frame.bones, pose)


async def solve(
    runner: Runner,
    store: SessionStore,
    entries: Sequence[Entry | ServiceError],
    t0: float,
    transport: str,
    client: str,
    *,
    may_inline: bool = True,
) -> list[Outcome]:
    """Solve the entries that are ready; each comes back as its solved frame or its
    error, in order.

    On the event loop when ``may_inline`` and no entry's time budget is over
    IK_INLINE_BUDGET_US (in slices: ``_solve_in_slices``); else on the frame threads,
    counted against ``client``'s share, as a clip. The sessions' locks are taken in the
    order of their ids (two batches that share sessions cannot wait for each other) and
    held until the last frame is solved.

    Raises:
        ServiceError: for the whole batch: not_ready, invalid_problem (work over
            IK_MAX_REQUEST_WORK_S), server_busy, too_much_work.
    """
    runner.check_ready()
    now = store.clock()
    rate, burst = runner.max_frames_per_s, runner.burst
    outcomes: list[Outcome | None] = [None] * len(entries)
    admitted: list[tuple[int, Entry]] = []
    by_id: dict[str, Session] = {}  # the admitted entries' sessions
    seen_before: dict[str, float] = {}  # their last use before this batch (a refusal restores it)
    for k, entry in enumerate(entries):
        if isinstance(entry, ServiceError):
            outcomes[k] = entry
            continue
        session = entry.session
        wait_s = session.take_frames(1, now=now, rate_per_s=rate, burst=burst)
        if wait_s > 0:
            outcomes[k] = rate_limited(wait_s, rate)
        else:
            admitted.append((k, entry))
            if session.id not in by_id:
                seen_before[session.id] = session.last_seen
            by_id[session.id] = session
            # In use from now on: the expiry sweep must not take it while the batch
            # waits for its lock or is solved (it would answer, then be gone).
            store.touch(session)
    sessions = sorted(by_id.values(), key=_by_id)
    locked: list[Session] = []
    marks: list[tuple[Session, StreamMark]] = []  # where each stood (Session.rewind)
    handed_over = False  # the locks went to a solving thread (the caller was cancelled)
    try:
        for session in sessions:
            await session.lock.acquire()
            locked.append(session)
            marks.append((session, session.mark()))
        live: list[tuple[int, Entry]] = []
        for k, entry in admitted:
            if entry.session.closed:  # deleted while the batch waited for its lock
                outcomes[k] = not_found()
            else:
                live.append((k, entry))
        # A shared store (IK_REDIS_URL): a session's entries sent again (same ids, same
        # targets) get the answers stored for them, as frames sent alone do.
        shared = store.commits_frames
        if shared:
            prepared = _prepared_groups(entries, live)
            live = _replay(prepared, live, outcomes)
        work = [e for _, e in live]
        inline_us = runner.inline_budget_us
        if not work:
            solved: list[Outcome] = []
        elif may_inline and all(_budget_us(e.session) <= inline_us for e in work):
            solved = await _solve_in_slices(work, t0, runner.metrics.frames, transport, inline_us)
        else:
            budget_us = sum(_budget_us(e.session) for e in work)
            cost_s = budget_us * 1e-6
            pool = runner.pools[WorkClass.FRAMES]
            shares = runner.frame_shares
            try:
                if cost_s > runner.max_request_work_s:
                    raise invalid_problem(
                        f"the batch is {cost_s:.3g} s of solving at worst (the sum of its "
                        f"frames' time_budget_us), over IK_MAX_REQUEST_WORK_S "
                        f"({runner.max_request_work_s:g} s): send fewer entries",
                        "frames",
                    )
                pool.admit()
                shares.take(client, cost_s)
            except ServiceError:
                # Refused whole, nothing solved or answered: the entries cost no frames
                # of their sessions' rate limits, nor count as a use of their sessions
                # (as a frame refused alone): a game server whose batches are refused
                # does not keep its characters from expiring.
                for _, entry in admitted:
                    entry.session.give_back_frames(1)
                for session in sessions:
                    session.last_seen = seen_before[session.id]
                raise
            loop = asyncio.get_running_loop()
            metrics = runner.metrics

            def record(batch: list[convert.SolvedFrame], transport: str) -> None:
                with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                    loop.call_soon_threadsafe(metrics.frames, batch, transport)

            fut = pool.submit(_solve_entries, work, t0, record, transport)
            fut.add_done_callback(lambda _: shares.give_back(client, cost_s))
            try:
                solved = await asyncio.shield(fut)
            except asyncio.CancelledError:
                if not fut.done():  # the thread still solves: its end rewinds, releases
                    held = list(locked)
                    fut.add_done_callback(lambda _: _rewind(marks))
                    fut.add_done_callback(lambda _: _release(held))
                    handed_over = True
                raise
        for (k, _), outcome in zip(live, solved, strict=True):
            outcomes[k] = outcome
        # Stored before answered, each session's entries in one commit, under its lock
        # (with sessions in this process's memory there is nothing to commit).
        if shared:
            record = runner.metrics.frames
            await asyncio.gather(
                *(
                    _commit(store, g, prepared[g[0][1].session.id], outcomes, t0, record, transport)
                    for g in _by_session(live)
                )
            )
    except asyncio.CancelledError:
        # Cancelled (between slices, or while a thread solved; uvicorn cancels what still
        # runs at the end of a graceful shutdown): the frames were answered to nobody, so
        # they leave no trace (Session.rewind).
        if not handed_over:
            _rewind(marks)
        raise
    finally:
        if not handed_over:
            _release(locked)
    for session in sessions:
        store.touch(session)
    return [o for o in outcomes if o is not None]


def _release(sessions: Sequence[Session]) -> None:
    for session in sessions:
        session.lock.release()


def _rewind(marks: Sequence[tuple[Session, StreamMark]]) -> None:
    for session, mark in marks:
        session.rewind(mark)


def _by_session(entries: Sequence[tuple[int, Entry]]) -> list[list[tuple[int, Entry]]]:
    """The entries grouped by session, each group in the order given."""
    groups: dict[str, list[tuple[int, Entry]]] = {}
    for k, entry in entries:
        groups.setdefault(entry.session.id, []).append((k, entry))
    return list(groups.values())


def _jobs(group: Sequence[tuple[int, Entry]]) -> list[convert.FrameJob]:
    return [(entry.frame_id, entry.targets, entry.pose) for _, entry in group]


def _prepared_groups(
    entries: Sequence[Entry | ServiceError], live: Sequence[tuple[int, Entry]]
) -> dict[str, list[tuple[int, Entry]]]:
    """Each live session's entries that are ready, rate limited ones included, in the
    order given: what was sent for it, against which its stored answers are matched (an
    entry rate limited now may be in the same stored answer as one answered now)."""
    sessions = {e.session.id for _, e in live}
    groups: dict[str, list[tuple[int, Entry]]] = {sid: [] for sid in sessions}
    for k, entry in enumerate(entries):
        if isinstance(entry, Entry) and entry.session.id in sessions:
            groups[entry.session.id].append((k, entry))
    return groups


def _answered(group: Sequence[tuple[int, Entry]]) -> dict[int, convert.SolvedFrame]:
    """A session's entries answered before (the same ids and targets, in any of its
    stored answers), by their place in the batch."""
    stored = stored_frames.answered_among(group[0][1].session.answers, _jobs(group))
    return {group[i][0]: frame for i, frame in stored.items()}


def _replay(
    prepared: dict[str, list[tuple[int, Entry]]],
    live: Sequence[tuple[int, Entry]],
    outcomes: list[Outcome | None],
) -> list[tuple[int, Entry]]:
    """The live entries still to solve; each one answered before gets its stored answer
    in ``outcomes`` (per entry: also when another entry of its session was refused or
    failed, then or now)."""
    answered = {k: frame for group in prepared.values() for k, frame in _answered(group).items()}
    for k, frame in answered.items():
        if outcomes[k] is None:  # a live entry (not one refused now)
            outcomes[k] = frame
    return [(k, e) for k, e in live if k not in answered]


async def _commit(
    store: SessionStore,
    group: Sequence[tuple[int, Entry]],
    prepared: Sequence[tuple[int, Entry]],
    outcomes: list[Outcome | None],
    t0: float,
    record: Callable[[list[convert.SolvedFrame], str], None],
    transport: str,
) -> None:
    """Commit one session's solved entries (``store.commit``, as for frames sent alone).
    When another worker committed the session first, it has been reloaded: the entries
    that worker answered (a batch sent again: ``prepared``, the session's entries of the
    batch, are matched against its stored answers) get those answers, the others are
    solved again from there (on the loop: a rare case), up to ``STALE_RETRIES`` times; a
    store error becomes each solved entry's own error."""
    session = group[0][1].session
    pending = list(group)  # solved here, not yet stored
    for _ in range(STALE_RETRIES):
        solved = [(k, e) for k, e in pending if isinstance(outcomes[k], convert.SolvedFrame)]
        frames = [o for k, _ in solved if isinstance(o := outcomes[k], convert.SolvedFrame)]
        if not solved:
            return
        try:
            await store.commit(session, _jobs(solved), frames)
            return
        except StaleSession:
            if session.closed:
                break
            # Reloaded: the entries may be a batch sent again whose answers another
            # worker stored after this worker's copy was taken (a client resending
            # through a balancer); they get those answers, as frames sent alone do
            # (solving._solve_and_commit), not a second solve that moves the pose again.
            answered = _answered(prepared)
            for k, _ in pending:
                if k in answered:
                    outcomes[k] = answered[k]
            pending = [(k, e) for k, e in pending if k not in answered]
            if not pending:
                return
            again = _solve_entries([e for _, e in pending], t0, record, transport)
            for (k, _), outcome in zip(pending, again, strict=True):
                outcomes[k] = outcome
        except ServiceError as e:
            for k, _ in solved:
                outcomes[k] = e
            return
    error = not_found() if session.closed else store_unavailable()
    for k, _ in pending:
        if isinstance(outcomes[k], convert.SolvedFrame):
            outcomes[k] = error


def _by_id(session: Session) -> str:
    return session.id


def _budget_us(session: Session) -> float:
    budget = session.options.time_budget_us
    return math.inf if budget is None else budget


async def _solve_in_slices(
    entries: Sequence[Entry],
    t0: float,
    record: Callable[[list[convert.SolvedFrame], str], None],
    transport: str,
    slice_us: float,
) -> list[Outcome]:
    """Solve on the event loop, letting the other connections take their turn after
    each ``slice_us`` of solving (IK_INLINE_BUDGET_US): the loop is held at most a slice
    plus one frame's time budget, as by one frame sent alone.

    Why not the frame threads: a batch's entries are frames of a few microseconds each,
    and with 50 of them handed to a thread the server spent 1-4 us more CPU per
    character than this (loadtest.cost --characters 50, same run: bench/RESULTS.md);
    the thread also contends with the loop for the GIL.
    """
    out: list[Outcome] = []
    while True:
        until = time.perf_counter() + slice_us * 1e-6
        out += _solve_entries(entries[len(out) :], t0, record, transport, until)
        if len(out) == len(entries):
            return out
        await asyncio.sleep(0)


def _solve_entries(
    entries: Sequence[Entry],
    t0: float,
    record: Callable[[list[convert.SolvedFrame], str], None],
    transport: str,
    until: float = math.inf,
) -> list[Outcome]:
    """Track each entry's frame on its session's solver, in order (under the sessions'
    locks, inline or on a frame thread), stopping after the first frame that ends past
    ``until`` (a ``time.perf_counter()`` value); a solver error is that entry's own."""
    out: list[Outcome] = []
    solved: list[convert.SolvedFrame] = []
    clock = time.perf_counter
    now = -math.inf  # when the last frame ended (``clock()``)
    try:
        for session, frame_id, targets, _, pose in entries:
            if now > until:
                break
            solver = session.solver
            try:
                if pose is not None:  # as PUT pose, then the frame
                    session.start_at(pose)
                r = solver.track(targets, options=session.options)
            except IKError as e:
                out.append(solver_error(e))
                now = clock()
                continue
            now = clock()
            # tuple.__new__: the NamedTuple's own __new__ is Python code (per entry).
            frame = _tuple_new(SolvedFrame, (frame_id, r, (now - t0) * 1e6, solver.last_step))
            out.append(frame)
            solved.append(frame)
            session.frames += 1
            session.solved += r.status is _SOLVED  # IKResult.success, without its property
    finally:
        record(solved, transport)
    return out


def render(
    entries: Sequence[Entry | ServiceError],
    sent: Sequence[Any],
    outcomes: Sequence[Outcome],
    build: convert.ResultBuilder,
    count_error: Callable[[ErrorCode], None],
) -> list[dict[str, Any]]:
    """Each entry's answer, in order: ``{session, id, success, result}`` or
    ``{session, id, success: false, error}`` (schemas ``BatchEntryResult`` /
    ``BatchEntryError``). ``sent``: the entries as sent (decoded or validated), whose
    session and frame id an error echoes (``raw_ids``)."""
    out: list[dict[str, Any]] = []
    for entry, raw, outcome in zip(entries, sent, outcomes, strict=True):
        if isinstance(outcome, ServiceError):
            count_error(outcome.code)
            session_id, frame_id = raw_ids(raw)
            error: dict[str, Any] = {"code": outcome.code.value, "message": outcome.detail}
            if outcome.field is not None:
                error["field"] = outcome.field
            if outcome.retry_after_s is not None:
                error["retry_after_s"] = outcome.retry_after_s
            out.append({"session": session_id, "id": frame_id, "success": False, "error": error})
            continue
        assert isinstance(entry, Entry)
        session, _, _, bones, _ = entry
        frame_id, r, server_us, step = outcome
        result = build(r, frame_id, server_us, step)
        view = session.view
        chosen = view.bone_output if bones is None else bones
        if chosen is not None and convert.wants_bones(chosen):
            result["bones"] = convert.bones_dict(view, r.q, chosen)
        success = result["success"]
        out.append({"session": session.id, "id": frame_id, "success": success, "result": result})
    return out
