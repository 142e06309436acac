"""Two in-process workers (TestClient apps) sharing sessions in a real redis-server.

Races are made deterministic by letting worker B write between worker A's steps: a
hook runs B's real request at the point where the race window is open.

Without redis-server these tests skip, except under CI=true, where they fail (.ci/run
installs it with apt-get).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
import math
import os
import shutil
import socket
import threading
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from typing import Any

import msgpack
import numpy as np
import pytest
import redis
from pydantic import SecretStr
from starlette.testclient import TestClient

import schemas as S
from loadtest.cluster import RedisServer
from service import batch, convert
from service.config import Settings
from service.main import create_app
from service.redis_store import RedisSessionStore
from service.sessions import Session
from service.stored_frames import KEPT_ANSWERS, StreamRecord, unpack_stream
from solver.ik import Target
from solver.ik.kinematics import DD_REST
from solver.model.forward import effector_poses

from .helpers import Created, create, hand_frame
from .test_continuity import DIAL


def _need_redis() -> None:
    """Skip without redis-server, except under CI=true, where that fails."""
    if shutil.which("redis-server") is None:
        reason = "redis-server not installed (.ci/run installs it)"
        if os.environ.get("CI") == "true":
            pytest.fail(f"{reason}; CI=true, so this is a failure, not a skip", pytrace=False)
        pytest.skip(reason)


@pytest.fixture(scope="module")
def redis_url() -> Iterator[str]:
    _need_redis()
    server = RedisServer()
    try:
        yield server.url
    finally:
        server.stop()


Workers = Callable[..., list[TestClient]]


@pytest.fixture
def workers(make_client: Callable[..., TestClient], redis_url: str) -> Workers:
    """``n`` apps on the same Redis (workers A, B, ...)."""

    def make(n: int = 2, **settings: Any) -> list[TestClient]:
        s = Settings(redis_url=SecretStr(redis_url), **settings)
        return [make_client(s) for _ in range(n)]

    return make


def _in_redis(workers: Workers, s: Created) -> dict[str, Any]:
    """The session as a worker that never held it loads it from Redis."""
    (fresh,) = workers(1)
    r = fresh.get(f"/v1/sessions/{s.id}", headers=s.headers)
    assert r.status_code == 200, r.text
    body: dict[str, Any] = r.json()
    return body


def _store(client: TestClient) -> RedisSessionStore:
    store = client.app.state.ik.store  # type: ignore[attr-defined]
    assert isinstance(store, RedisSessionStore)
    return store


def _after_first_refresh(client: TestClient, race: Callable[[], None], times: int = 1) -> None:
    """Run ``race`` (another worker's request) right after ``client``'s store reloaded a
    session, the first ``times`` times: the window between the reload and the write."""
    store = _store(client)
    refresh = store.refresh
    raced = 0

    async def refresh_then_race(session: Any) -> None:
        nonlocal raced
        await refresh(session)
        if raced < times:
            raced += 1
            race()  # blocks this loop; worker B runs on its own

    store.refresh = refresh_then_race  # type: ignore[method-assign]


def test_patch_racing_another_worker_is_applied_not_a_500(workers: Workers) -> None:
    a, b = workers()
    s = create(a)
    q = [0.1] * len(s.body["pose"]["q"])
    _after_first_refresh(
        a, lambda: b.put(f"/v1/sessions/{s.id}/pose", json={"q": q}, headers=s.headers)
    )
    r = a.patch(f"/v1/sessions/{s.id}", json={"max_iter": 7}, headers=s.headers)
    assert r.status_code == 200, r.text
    assert r.json()["options"]["max_iter"] == 7
    stored = _in_redis(workers, s)
    assert stored["options"]["max_iter"] == 7
    assert stored["pose"]["q"] == pytest.approx(q)  # B's change is kept too


def test_put_pose_racing_another_worker_is_applied_not_a_500(workers: Workers) -> None:
    a, b = workers()
    s = create(a)
    q = [0.2] * len(s.body["pose"]["q"])
    _after_first_refresh(
        a, lambda: b.patch(f"/v1/sessions/{s.id}", json={"max_iter": 9}, headers=s.headers)
    )
    r = a.put(f"/v1/sessions/{s.id}/pose", json={"q": q}, headers=s.headers)
    assert r.status_code == 200, r.text
    stored = _in_redis(workers, s)
    assert stored["pose"]["q"] == pytest.approx(q)
    assert stored["options"]["max_iter"] == 9  # B's change is kept too


def test_a_change_that_always_loses_the_race_is_a_503_not_a_500(workers: Workers) -> None:
    a, b = workers()
    s = create(a)
    n = len(s.body["pose"]["q"])
    poses = iter([[0.1 * k] * n for k in range(1, 10)])
    _after_first_refresh(
        a,
        lambda: b.put(f"/v1/sessions/{s.id}/pose", json={"q": next(poses)}, headers=s.headers),
        times=100,
    )
    r = a.patch(f"/v1/sessions/{s.id}", json={"max_iter": 7}, headers=s.headers)
    assert r.status_code == 503, r.text
    assert r.json()["code"] == "store_unavailable" and r.headers["retry-after"] == "1"
    assert _in_redis(workers, s)["options"]["max_iter"] != 7


def _entry(s: Created, frame_id: int, y: float) -> dict[str, Any]:
    return {"session": s.id, "token": s.token, **hand_frame(frame_id, y=y)}


def _batch(client: TestClient, entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    r = client.post("/v1/batch", json={"frames": entries})
    assert r.status_code == 200, r.text
    results: list[dict[str, Any]] = r.json()["results"]
    return results


def test_a_batch_is_stored_and_a_resent_batch_gets_its_stored_answers(workers: Workers) -> None:
    a, b = workers()
    s1, s2 = create(a), create(a)
    sent = [_entry(s1, 1, 0.1), _entry(s2, 1, 0.1), _entry(s1, 2, 0.11)]
    first = _batch(a, sent)
    assert all("result" in r for r in first), first
    stored = _in_redis(workers, s1)
    assert stored["counters"]["frames"] == 2
    assert stored["pose"]["q"] == pytest.approx(first[2]["result"]["q"])
    # The same batch to another worker (a client retrying after a failover): the answers
    # stored, not a second solve.
    again = _batch(b, sent)
    assert [r["result"]["q"] for r in again] == [r["result"]["q"] for r in first]
    assert _in_redis(workers, s1)["counters"]["frames"] == 2


def test_a_batch_resent_to_a_worker_holding_an_older_copy_gets_its_stored_answers(
    workers: Workers,
) -> None:
    """A batch answered by worker A whose answer was lost, sent again through a balancer
    to worker B, which holds the session from an earlier frame: B's commit is refused, it
    reloads the session and finds the stored answers, as a frame sent alone does; solving
    again from the reloaded pose would have moved the pose twice and counted the frames
    twice."""
    a, b = workers()
    s1, s2 = create(a), create(a)
    _batch(b, [_entry(s1, 1, 0.1), _entry(s2, 1, 0.1)])  # worker B holds both at frame 1
    sent = [_entry(s1, 2, 0.13), _entry(s2, 2, 0.13), _entry(s1, 3, 0.16)]
    first = _batch(a, sent)  # answered by A, the answer lost on the way
    again = _batch(b, sent)
    assert [r["result"] for r in again] == [r["result"] for r in first]
    stored = _in_redis(workers, s1)
    assert stored["counters"]["frames"] == 3
    assert stored["pose"]["q"] == pytest.approx(first[2]["result"]["q"])
    # The frame path does the same (what the batch path is held to).
    frame = hand_frame(4, y=0.19)
    r = a.post(f"/v1/sessions/{s2.id}/frames", json=frame, headers=s2.headers)
    r_again = b.post(f"/v1/sessions/{s2.id}/frames", json=frame, headers=s2.headers)
    assert r_again.json()["results"] == r.json()["results"]


def test_a_batch_racing_another_worker_is_solved_again_from_its_frame(workers: Workers) -> None:
    a, b = workers()
    s = create(a)
    _batch(a, [_entry(s, 1, 0.1)])  # worker A holds the session
    r = b.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(2, y=0.11), headers=s.headers)
    assert r.status_code == 200, r.text
    (answer,) = _batch(a, [_entry(s, 3, 0.12)])
    assert "result" in answer, answer
    stored = _in_redis(workers, s)
    assert stored["counters"]["frames"] == 3
    assert stored["pose"]["q"] == pytest.approx(answer["result"]["q"])


def _frozen_clock(client: TestClient) -> list[float]:
    """``client``'s store clock (its sessions' rate limits), moved on by hand: now[0]."""
    now = [0.0]
    _store(client).clock = lambda: now[0]
    return now


def _codes(results: list[dict[str, Any]]) -> list[str | None]:
    return [r["error"]["code"] if "error" in r else None for r in results]


def test_a_resent_batch_whose_entry_was_refused_gets_the_others_stored_answers(
    workers: Workers,
) -> None:
    """A batch in which a session's last entry was rate limited (and other entries
    refused: a wrong token, a bad target), sent again once the bucket refilled (its
    answer lost): the entries answered the first time get their stored answers (the
    same server_us: not solved again), the one refused is solved now."""
    (a,) = workers(1, max_frames_per_s=1.0, max_frames_per_request=5)
    now = _frozen_clock(a)
    s, t = create(a), create(a)
    _batch(a, [_entry(s, k, 0.1) for k in (1, 2, 3, 4)])  # s's bucket: 1 frame left
    bad = {**_entry(s, 7, 0.1), "targets": [{"effector": "hand"}]}
    sent = [
        _entry(s, 5, 0.12),
        {**_entry(s, 6, 0.13), "token": "not-the-token"},
        _entry(t, 1, 0.1),
        bad,
        _entry(s, 8, 0.14),
    ]
    first = _batch(a, sent)
    assert _codes(first) == [None, "forbidden", None, "invalid_format", "rate_limited"]
    now[0] += 10.0  # the bucket full again
    again = _batch(a, sent)
    assert _codes(again) == [None, "forbidden", None, "invalid_format", None]
    assert again[:4] == first[:4]
    stored = _in_redis(workers, s)
    assert stored["counters"]["frames"] == 6  # 1 to 5, and 8: none solved twice
    assert stored["pose"]["q"] == pytest.approx(again[4]["result"]["q"])


def test_a_batch_resent_when_its_session_s_bucket_is_short_gets_its_stored_answers(
    workers: Workers,
) -> None:
    """A batch answered whole, sent again when its session has frames for only part of
    it: those entries get their stored answers (each costs a frame, as a frame sent
    again alone), the rest are rate limited; sent once more, all are answered as first."""
    (a,) = workers(1, max_frames_per_s=1.0, max_frames_per_request=3)
    now = _frozen_clock(a)
    s = create(a)
    sent = [_entry(s, 1, 0.1), _entry(s, 2, 0.11), _entry(s, 3, 0.12)]
    first = _batch(a, sent)  # the bucket spent
    now[0] += 1.0  # one frame's worth
    again = _batch(a, sent)
    assert _codes(again) == [None, "rate_limited", "rate_limited"]
    assert again[0] == first[0]
    now[0] += 10.0
    assert _batch(a, sent) == first
    assert _in_redis(workers, s)["counters"]["frames"] == 3


def test_a_partly_answered_batch_resent_to_a_worker_holding_an_older_copy(
    workers: Workers,
) -> None:
    """Worker A answered a batch whose last entry it rate limited; the answer lost, the
    batch goes to worker B, which holds the session from before: B's commit is refused,
    it reloads the session, the entry A answered gets A's stored answer and only the
    other is solved again from there."""
    a, b = workers(max_frames_per_s=1.0, max_frames_per_request=3)
    _frozen_clock(a)
    s = create(a)
    _batch(a, [_entry(s, 1, 0.1), _entry(s, 2, 0.11)])  # A's bucket for s: 1 frame left
    assert b.get(f"/v1/sessions/{s.id}", headers=s.headers).status_code == 200  # B holds s
    sent = [_entry(s, 3, 0.12), _entry(s, 4, 0.13)]
    first = _batch(a, sent)
    assert _codes(first) == [None, "rate_limited"]
    again = _batch(b, sent)
    assert _codes(again) == [None, None]
    assert again[0] == first[0]
    stored = _in_redis(workers, s)
    assert stored["counters"]["frames"] == 4
    assert stored["pose"]["q"] == pytest.approx(again[1]["result"]["q"])


def test_written_behind_a_pose_change_keeps_the_frames_answered(workers: Workers) -> None:
    """Frames answered but not yet flushed (a flush every 60 s) are written before a
    PATCH reloads the session: the pose is the last answer's, not the one in Redis."""
    (a,) = workers(1, redis_write_behind_ms=60_000)
    s = create(a)
    for i, y in enumerate((0.1, 0.11, 0.12)):
        r = a.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(i, y=y), headers=s.headers)
        assert r.status_code == 200, r.text
    last_q = r.json()["results"][0]["q"]
    assert last_q != pytest.approx(s.body["pose"]["q"])
    r = a.patch(f"/v1/sessions/{s.id}", json={"max_iter": 7}, headers=s.headers)
    assert r.status_code == 200, r.text
    assert r.json()["pose"]["q"] == pytest.approx(last_q)
    assert r.json()["counters"]["frames"] == 3
    stored = _in_redis(workers, s)
    assert stored["pose"]["q"] == pytest.approx(last_q)
    assert stored["counters"]["frames"] == 3


def test_written_behind_a_flush_under_way_at_shutdown_is_not_lost(warm_solver: float) -> None:
    """Redis stalls (SIGSTOP) while a flush is under way, a frame is answered, and the
    worker shuts down: the shutdown waits for that flush (Redis answers again within its
    timeout), then writes the last frame."""
    _need_redis()
    server = RedisServer()  # its own: it is paused
    try:
        settings = Settings(
            redis_url=SecretStr(server.url), redis_write_behind_ms=1000, redis_timeout_s=20
        )
        app = create_app(settings, warmup=lambda report: 0.0)
        with TestClient(app) as a:
            assert app.state.ik.runner.warmup.ready.wait(30)
            s = create(a)
            for i, y in enumerate((0.1, 0.11, 0.12)):
                r = a.post(
                    f"/v1/sessions/{s.id}/frames", json=hand_frame(i, y=y), headers=s.headers
                )
                assert r.status_code == 200, r.text
            server.pause()  # before the first flush, 1 s after the first frame
            time.sleep(1.5)  # the flush has started and waits for Redis
            # One more frame, answered meanwhile: the shutdown's flush must follow the
            # one under way (sent beside it, with the same version, it would be refused).
            r = a.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(3, y=0.13), headers=s.headers)
            assert r.status_code == 200, r.text
            # The shutdown (lifespan end, in the with's exit) while Redis still stalls:
            threading.Timer(3.0, server.resume).start()
        with redis.Redis.from_url(server.url) as r:
            state = r.hget(f"ik:s:{s.id}", "state")
        assert isinstance(state, bytes)
        assert unpack_stream(state, len(s.body["pose"]["q"])).frames == 4
    finally:
        server.resume()
        server.stop()


def _stored_stream(redis_url: str, s: Created) -> StreamRecord:
    """The session's stream state as written in Redis (no worker in between)."""
    with redis.Redis.from_url(redis_url) as r:
        state = r.hget(f"ik:s:{s.id}", "state")
    assert isinstance(state, bytes)
    return unpack_stream(state, len(s.body["pose"]["q"]))


def frame_targets(session: Session, frame: dict[str, Any]) -> Sequence[Target]:
    """A frame's targets as the solver takes them, for the session's chain."""
    return convert.targets(S.Frame(**frame).targets, session.view, "targets")


def _post_frame(client: TestClient, frame: dict[str, Any], *, s: Created) -> dict[str, Any]:
    """One frame of session ``s`` through ``client`` (a worker): its result."""
    r = client.post(f"/v1/sessions/{s.id}/frames", json=frame, headers=s.headers)
    assert r.status_code == 200, r.text
    result: dict[str, Any] = r.json()["results"][0]
    return result


def _frame_q(client: TestClient, s: Created, frame_id: int, y: float) -> list[float]:
    r = client.post(
        f"/v1/sessions/{s.id}/frames", json=hand_frame(frame_id, y=y), headers=s.headers
    )
    assert r.status_code == 200, r.text
    q: list[float] = r.json()["results"][0]["q"]
    return q


def test_written_behind_a_flush_during_a_pooled_solve_stores_the_last_answered_pose(
    workers: Workers, redis_url: str
) -> None:
    """A flush that runs while a frame thread is between moving the pose and counting
    the frame writes the state as it was when the last frame was answered: the pose of
    the frames counted, not the pose of a frame still being solved."""
    # inline_budget_us=0: every frame is solved on a frame thread, the loop stays free.
    (a,) = workers(1, redis_write_behind_ms=60_000, inline_budget_us=0)
    s = create(a)
    behind = _store(a).behind
    assert behind is not None
    store = _store(a)
    answered = _frame_q(a, s, 0, 0.1)  # answered, queued for the next flush
    session = a.portal.call(store.get, s.id)
    assert session is not None
    track = session.solver.track

    def track_then_flush(*args: Any, **kwargs: Any) -> Any:
        result = track(*args, **kwargs)  # the pose has moved, the frame is not counted
        a.portal.call(behind.flush)  # the flush, on the loop, at this very moment
        return result

    session.solver.track = track_then_flush  # type: ignore[method-assign]
    _frame_q(a, s, 1, 0.14)
    stored = _stored_stream(redis_url, s)
    assert stored.frames == 1
    assert stored.q.tolist() == pytest.approx(answered, abs=0)


def _cancelled_mid_solve(
    client: TestClient, held: Session, work: Callable[[], Awaitable[Any]]
) -> None:
    """Start ``work`` (frames solved on a frame thread), cancel it while the thread is
    inside ``held``'s ``track``, let the thread finish, and wait
    until it has released ``held``'s lock. Asserts the thread did solve."""
    track = held.solver.track
    solving, go_on, solved = threading.Event(), threading.Event(), threading.Event()

    def held_track(*args: Any, **kwargs: Any) -> Any:
        solving.set()
        go_on.wait(10)
        result = track(*args, **kwargs)
        solved.set()
        return result

    async def cancel_mid_solve() -> None:
        task = asyncio.create_task(work())
        assert await asyncio.to_thread(solving.wait, 10)
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        go_on.set()
        async with held.lock:  # the thread's end releases it
            pass

    held.solver.track = held_track  # type: ignore[method-assign]
    try:
        client.portal.call(cancel_mid_solve)
    finally:
        held.solver.track = track  # type: ignore[method-assign]
    assert solved.is_set()  # the thread did solve the frame (and moved the pose)


def _two_stores(
    workers: Workers, make_client: Callable[..., TestClient], shared: bool
) -> TestClient:
    """A worker that solves every frame on a frame thread, with Redis or in memory."""
    settings = {"inline_budget_us": 0}
    return workers(1, **settings)[0] if shared else make_client(Settings(**settings))


@pytest.mark.parametrize("shared", [True, False], ids=["redis", "memory"])
def test_a_frame_cancelled_while_its_thread_solves_leaves_no_trace(
    workers: Workers, make_client: Callable[..., TestClient], redis_url: str, shared: bool
) -> None:
    """A frame whose request is cancelled while a frame thread solves it (uvicorn
    cancels what still runs at the end of a graceful shutdown) is answered to nobody
    and never committed. The thread solves on; its end puts the session back where it
    stood: otherwise the worker's copy was ahead of Redis at the same version, and the
    next frame or a GET started from a pose no answer and no other worker knew (in
    memory: a resend started from the answer it never got)."""
    a = _two_stores(workers, make_client, shared)
    s = create(a)
    store = a.app.state.ik.store  # type: ignore[attr-defined]
    answered = _frame_q(a, s, 0, 0.1)
    session = a.portal.call(store.get, s.id)
    assert session is not None
    runner = a.app.state.ik.runner  # type: ignore[attr-defined]
    targets = frame_targets(session, hand_frame(1, y=0.16))
    _cancelled_mid_solve(
        a,
        session,
        lambda: runner.session_frames(
            session, store, [(1, targets, None)], time.perf_counter(), "http"
        ),
    )
    assert (session.frames, session.solver.q.tolist()) == (1, pytest.approx(answered, abs=0))
    r = a.get(f"/v1/sessions/{s.id}", headers=s.headers)
    assert r.status_code == 200, r.text
    assert r.json()["pose"]["q"] == pytest.approx(answered, abs=0)
    # The frame sent again is solved from where it started, and committed.
    again = _frame_q(a, s, 1, 0.16)
    assert again != pytest.approx(answered)
    if shared:
        stored = _stored_stream(redis_url, s)
        assert (stored.frames, stored.q.tolist()) == (2, pytest.approx(again, abs=0))


@pytest.mark.parametrize("shared", [True, False], ids=["redis", "memory"])
def test_a_batch_cancelled_while_its_thread_solves_leaves_no_trace(
    workers: Workers, make_client: Callable[..., TestClient], shared: bool
) -> None:
    """The same for a batch: every session of it is put back where it stood, the ones
    the thread had solved before the cancel and the one it was solving."""
    a = _two_stores(workers, make_client, shared)
    store = a.app.state.ik.store  # type: ignore[attr-defined]
    runner = a.app.state.ik.runner  # type: ignore[attr-defined]
    made = [create(a) for _ in range(2)]
    answered = [_frame_q(a, s, 0, 0.1) for s in made]
    sessions = [a.portal.call(store.get, s.id) for s in made]
    entries = [
        batch.Entry(session, 1, frame_targets(session, hand_frame(1, y=0.16)))
        for session in sessions
    ]
    _cancelled_mid_solve(
        a,
        sessions[1],  # entries are solved in order: the first one is solved by then
        lambda: batch.solve(runner, store, entries, time.perf_counter(), "ws", "tester"),
    )
    for session, q in zip(sessions, answered, strict=True):
        assert (session.frames, session.solver.q.tolist()) == (1, pytest.approx(q, abs=0))


def test_a_cancelled_load_leaves_the_other_waiters_their_session(workers: Workers) -> None:
    """Two requests of a session this worker does not hold: the first (which loads it
    from Redis) is cancelled mid-load (its client went away); the second still gets it."""
    a, b = workers()
    s = create(a)
    store = _store(b)

    async def second_load_after_the_first_is_cancelled() -> Session | None:
        first = asyncio.create_task(store.get(s.id))
        await asyncio.sleep(0)  # the first load waits for Redis
        second = asyncio.create_task(store.get(s.id))
        await asyncio.sleep(0)  # the second waits for the first's load
        first.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await first
        return await second

    session = b.portal.call(second_load_after_the_first_is_cancelled)
    assert session is not None and session.id == s.id
    assert b.portal.call(store.get, s.id) is session  # loaded once, kept


def _ws_batch(ws: Any, msg_id: int, entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    ws.send_text(json.dumps({"type": "batch", "id": msg_id, "frames": entries}))
    reply = ws.receive_json()
    assert reply["type"] == "batch_result", reply
    results: list[dict[str, Any]] = reply["results"]
    assert all(r["success"] for r in results), results
    return results


def test_a_session_forgotten_while_a_websocket_batch_holds_it_stays_one_session(
    workers: Workers, redis_url: str
) -> None:
    """A WebSocket's batches keep a session open (the connection remembers it). When the
    worker forgets it as idle and an HTTP request brings it back from Redis, both use
    one session: the pose PUT over HTTP is where the socket's next frame starts, and
    every frame answered is stored (written behind: two copies in one worker would
    each flush with their own version, and one copy's frames would be refused)."""
    (a,) = workers(1, redis_write_behind_ms=60_000)
    via, s = create(a), create(a)
    store = _store(a)
    with a.websocket_connect(f"/v1/sessions/{via.id}/ws", headers=via.headers) as ws:
        _ws_batch(ws, 1, [_entry(s, 1, 0.1)])
        held = a.portal.call(store.get, s.id)
        assert held is not None
        held.last_seen -= 2 * store.ttl_s  # idle for two TTLs in this worker...
        a.portal.call(store.expire)  # ...so the sweep forgets it (Redis keeps it)
        pose = [0.05] * len(s.body["pose"]["q"])
        r = a.put(f"/v1/sessions/{s.id}/pose", json={"q": pose}, headers=s.headers)
        assert r.status_code == 200, r.text
        (second,) = _ws_batch(ws, 2, [_entry(s, 2, 0.1)])
        again = a.portal.call(store.get, s.id)
    assert store.behind is not None
    a.portal.call(store.behind.flush)
    stored = _stored_stream(redis_url, s)
    assert stored.frames == 2
    assert stored.q.tolist() == pytest.approx(second["result"]["q"], abs=0)
    # The frame started from the pose PUT: its step is measured from there.
    start = np.array(pose)
    largest = float(np.max(np.abs(np.array(second["result"]["q"]) - start)))
    assert second["result"]["largest_step_rad"] == pytest.approx(largest)
    assert again is held  # one object for the session in this worker


def test_ws_batch_is_stored_and_a_resent_batch_gets_its_stored_answers(
    workers: Workers,
) -> None:
    """A WebSocket ``batch`` with sessions in Redis, JSON and MessagePack: each entry is
    committed before the answer, and the same batch sent again on another worker (a
    client resending after a failover) gets the stored answers, not a second solve."""
    a, b = workers()
    via, s1, s2 = create(a), create(a), create(a)
    sent = [_entry(s1, 1, 0.1), _entry(s2, 1, 0.12), _entry(s1, 2, 0.11)]
    with a.websocket_connect(f"/v1/sessions/{via.id}/ws", headers=via.headers) as ws:
        first = _ws_batch(ws, 1, sent)
        ws.send_bytes(msgpack.packb({"type": "batch", "id": 2, "frames": [_entry(s2, 2, 0.13)]}))
        packed = msgpack.unpackb(ws.receive_bytes())
    assert packed["type"] == "batch_result" and packed["results"][0]["success"], packed
    assert [(r["session"], r["id"]) for r in first] == [(s1.id, 1), (s2.id, 1), (s1.id, 2)]
    stored = _in_redis(workers, s1)
    assert stored["counters"]["frames"] == 2
    assert stored["pose"]["q"] == pytest.approx(first[2]["result"]["q"], abs=0)
    stored = _in_redis(workers, s2)
    assert stored["counters"]["frames"] == 2
    assert stored["pose"]["q"] == pytest.approx(packed["results"][0]["result"]["q"], abs=0)
    with b.websocket_connect(f"/v1/sessions/{via.id}/ws", headers=via.headers) as ws:
        again = _ws_batch(ws, 1, sent)
    assert [r["result"]["q"] for r in again] == [r["result"]["q"] for r in first]
    assert _in_redis(workers, s1)["counters"]["frames"] == 2


@pytest.fixture(scope="module")
def guarded_redis() -> Iterator[RedisServer]:
    """A redis-server that requires a password."""
    _need_redis()
    server = RedisServer(password="s3cret-pw")
    try:
        yield server
    finally:
        server.stop()


def _readyz_and_create(client: TestClient) -> tuple[dict[str, Any], dict[str, Any]]:
    """/readyz's 503 body and a session create's 503 body, both ``store_unavailable``
    with ``Retry-After``."""
    ready = client.get("/readyz")
    created = client.post(
        "/v1/sessions", json={"chain": {"format": "example", "name": "panda_arm"}}
    )
    for r in (ready, created):
        assert r.status_code == 503, r.text
        assert r.json()["code"] == "store_unavailable" and r.headers["retry-after"] == "1"
    return ready.json(), created.json()


def test_readyz_says_redis_refuses_a_wrong_password_and_the_right_one_is_ready(
    make_client: Callable[..., TestClient], guarded_redis: RedisServer
) -> None:
    """A configuration error is not an outage: /readyz tells the operator what to fix
    (without the password), a client still gets the plain 503 it retries."""
    wrong = guarded_redis.url.replace("s3cret-pw", "not-the-pw")
    ready, created = _readyz_and_create(make_client(Settings(redis_url=SecretStr(wrong))))
    assert "Redis refuses this worker (AuthenticationError" in ready["detail"], ready
    assert "IK_REDIS_URL" in ready["detail"]
    assert "not-the-pw" not in ready["detail"] and "s3cret" not in ready["detail"]
    assert created["detail"].startswith("the session store (Redis) failed the request")
    none = guarded_redis.url.replace(":s3cret-pw@", "")
    ready, _ = _readyz_and_create(make_client(Settings(redis_url=SecretStr(none))))
    assert "Redis refuses this worker (AuthenticationError" in ready["detail"], ready
    right = make_client(Settings(redis_url=SecretStr(guarded_redis.url)))
    assert right.get("/readyz").status_code == 200
    assert (
        right.post(
            "/v1/sessions", json={"chain": {"format": "example", "name": "panda_arm"}}
        ).status_code
        == 201
    )


def test_a_refusal_is_logged_once_at_error_not_at_every_probe(
    make_client: Callable[..., TestClient],
    guarded_redis: RedisServer,
    caplog: pytest.LogCaptureFixture,
) -> None:
    wrong = guarded_redis.url.replace("s3cret-pw", "not-the-pw")
    client = make_client(Settings(redis_url=SecretStr(wrong)))
    with caplog.at_level(logging.WARNING, logger="service"):
        for _ in range(3):
            assert client.get("/readyz").status_code == 503
    refusals = [r for r in caplog.records if "refuses this worker" in r.getMessage()]
    assert [r.levelno for r in refusals] == [logging.ERROR], caplog.text
    assert "not-the-pw" not in caplog.text
    (line,) = [r.getMessage() for r in refusals]
    assert f"(at 127.0.0.1:{guarded_redis.port}" in line, line  # where it tried
    assert line.count("invalid username-password pair") == 1, line  # said once


def test_an_outage_is_logged_with_where_and_the_recovery_once(
    make_client: Callable[..., TestClient], caplog: pytest.LogCaptureFixture
) -> None:
    """A paused Redis: one WARNING naming the address, 503s, then one INFO line when
    it answers again (the operator sees the outage end in the log, too)."""
    server = RedisServer()
    try:
        client = make_client(Settings(redis_url=SecretStr(server.url), redis_timeout_s=0.2))
        assert client.get("/readyz").status_code == 200
        with caplog.at_level(logging.INFO, logger="service"):
            server.pause()
            try:
                for _ in range(2):
                    assert client.get("/readyz").status_code == 503
            finally:
                server.resume()
            for _ in range(2):
                assert client.get("/readyz").status_code == 200
    finally:
        server.stop()
    lines = [r.getMessage() for r in caplog.records if r.name == "service"]
    outages = [m for m in lines if m.startswith("not ready: Redis did not answer")]
    assert len(outages) == 1 and f"(at 127.0.0.1:{server.port}" in outages[0], lines
    assert lines.count(f"ready: Redis at 127.0.0.1:{server.port} answers again") == 1, lines


def test_frames_failed_in_an_outage_are_summed_up_when_redis_answers_again(
    make_client: Callable[..., TestClient], caplog: pytest.LogCaptureFixture
) -> None:
    """Frames against a paused Redis: one WARNING, then, at the first frame stored
    after it answers again, one line saying so with the failures not logged."""
    server = RedisServer()
    try:
        client = make_client(Settings(redis_url=SecretStr(server.url), redis_timeout_s=0.2))
        s = create(client)
        url = f"/v1/sessions/{s.id}/frames"
        with caplog.at_level(logging.INFO, logger="service"):
            server.pause()
            try:
                for i in range(4):
                    r = client.post(url, json=hand_frame(i), headers=s.headers)
                    assert r.status_code == 503, r.text
            finally:
                server.resume()
            for i in range(4, 6):
                r = client.post(url, json=hand_frame(i), headers=s.headers)
                assert r.status_code == 200, r.text
    finally:
        server.stop()
    lines = [r.getMessage() for r in caplog.records if r.name == "service"]
    failed = [m for m in lines if m.startswith("a request failed: Redis did not answer")]
    back = [m for m in lines if m.startswith("Redis answers again")]
    assert len(failed) == 1 and len(back) == 1, lines
    # The first failure was logged; the other frames' (their reloads' too) were not.
    left_out = int(back[0].split("); ")[1].split()[0])
    assert left_out >= 3, back
    assert lines.index(back[0]) > lines.index(failed[0])


def test_commits_redis_refuses_are_failures_not_its_recovery(
    make_client: Callable[..., TestClient], caplog: pytest.LogCaptureFixture
) -> None:
    """Redis out of memory (maxmemory, noeviction) refuses every write with an error
    reply in the pipeline's results (READONLY, MISCONF the same) while it still answers
    PING and reads: each refused frame is a failure, one WARNING for them all, and
    neither a frame's reply nor /readyz's PING is Redis answering again. The line comes
    with the first frame stored."""
    server = RedisServer()
    try:
        client = make_client(Settings(redis_url=SecretStr(server.url), redis_timeout_s=0.5))
        s = create(client)
        url = f"/v1/sessions/{s.id}/frames"
        control = redis.Redis.from_url(server.url)
        with caplog.at_level(logging.INFO, logger="service"):
            control.config_set("maxmemory", "1")
            try:
                for i in range(6):
                    r = client.post(url, json=hand_frame(i), headers=s.headers)
                    assert r.status_code == 503, r.text
                    assert client.get("/readyz").status_code == 200
                during = [r.getMessage() for r in caplog.records if r.name == "service"]
            finally:
                control.config_set("maxmemory", "0")
            r = client.post(url, json=hand_frame(6), headers=s.headers)
            assert r.status_code == 200, r.text
        control.close()
    finally:
        server.stop()
    assert [m for m in during if not m.startswith("a request failed")] == [], during
    (failed,) = during  # one WARNING for the six frames
    assert failed.startswith("a request failed: Redis refuses writes (OutOfMemoryError: "), failed
    lines = [r.getMessage() for r in caplog.records if r.name == "service"]
    (back,) = lines[1:]
    assert back.startswith("Redis answers again (requests failed for "), lines
    assert back.endswith("); 5 failed request(s) not logged since the last warning"), lines


def test_a_flush_redis_refuses_is_logged_and_its_sessions_reload_written_behind(
    make_client: Callable[..., TestClient], caplog: pytest.LogCaptureFixture
) -> None:
    """Written behind, a flush Redis refuses (out of memory) is logged as a failure
    (once): it only marked its sessions for a reload, and nothing said that the frames
    answered were not stored (a review of the operator fixes). Redis still answers, so
    no session of the worker is refused: each next frame reloads the stored state and
    is answered from it (docs/operations.md, "Written behind instead"); two sessions,
    so that one session's refused flush cannot turn the other's frames into 503s."""
    server = RedisServer()
    try:
        settings = Settings(redis_url=SecretStr(server.url), redis_write_behind_ms=10)
        client = make_client(settings)
        sessions = [create(client), create(client)]
        control = redis.Redis.from_url(server.url)
        statuses = []
        with caplog.at_level(logging.WARNING, logger="service"):
            control.config_set("maxmemory", "1")
            try:
                for i in range(8):
                    s = sessions[i % 2]
                    url = f"/v1/sessions/{s.id}/frames"
                    r = client.post(url, json=hand_frame(i), headers=s.headers)
                    statuses.append(r.status_code)
                    time.sleep(0.03)  # the flush (every 10 ms) goes in between
            finally:
                control.config_set("maxmemory", "0")
        control.close()
    finally:
        server.stop()
    assert statuses == [200] * 8, statuses
    warned = [r.getMessage() for r in caplog.records if r.name == "service"]
    (line,) = warned  # once for every flush refused
    assert line.startswith("a request failed: Redis refuses writes (OutOfMemoryError"), line


def test_readyz_says_a_database_number_redis_lacks_and_a_port_nobody_serves(
    make_client: Callable[..., TestClient], redis_url: str
) -> None:
    ready, _ = _readyz_and_create(
        make_client(Settings(redis_url=SecretStr(redis_url.removesuffix("/0") + "/99")))
    )
    assert "Redis refuses this worker (ResponseError: DB index is out of range)" in ready["detail"]
    with socket.socket() as unused:  # bound, never listening: connections are refused
        unused.bind(("127.0.0.1", 0))
        port = unused.getsockname()[1]
        closed = f"redis://127.0.0.1:{port}/0"
        ready, _ = _readyz_and_create(make_client(Settings(redis_url=SecretStr(closed))))
    assert ready["detail"].startswith("Redis cannot be reached (ConnectionError; "), ready
    assert str(port) not in ready["detail"]  # /readyz may be public: no address in it


def _gauge(client: TestClient, name: str) -> float:
    for line in client.get("/metrics").text.splitlines():
        if line.startswith(name + " "):
            return float(line.split()[1])
    raise AssertionError(f"{name} not in /metrics")


def test_active_sessions_is_the_count_in_redis_on_every_worker(
    workers: Workers, redis_url: str
) -> None:
    """ik_active_sessions with Redis: every worker's sessions, the same figure on each
    worker after its sweep (an operator aggregates it with max, not sum)."""
    a, b = workers()
    for worker in (a, a, b):
        create(worker)
    for w in (a, b):
        w.portal.call(_store(w).expire)
    in_redis = redis.Redis.from_url(redis_url).zcard("ik:all")
    assert in_redis >= 3
    assert _gauge(a, "ik_active_sessions") == _gauge(b, "ik_active_sessions") == in_redis


def _step(client: TestClient, s: Created, frame_id: int, x: float) -> float:
    """The largest joint step of a frame sending the hand to (x, 0.1, 0.6)."""
    r = client.post(
        f"/v1/sessions/{s.id}/frames", json=hand_frame(frame_id, x=x), headers=s.headers
    )
    assert r.status_code == 200, r.text
    step: float = r.json()["results"][0]["largest_step_rad"]
    return step


def test_a_stream_s_first_frame_is_first_on_every_worker(workers: Workers) -> None:
    """Under ``smooth`` a stream's first frame (after the session's creation or a pose
    set) is solved as ``reach`` would: on the worker that loads the session from Redis
    too, not only on the one that set the pose."""
    a, b = workers()
    # A budget no load on the machine exhausts: a first frame cut short would leave the
    # stream unanchored (solved as reach) and frame 2 unlimited.
    s = create(a, options={"time_budget_us": 50_000.0})
    assert _step(b, s, 1, -0.3) > 0.1  # the first frame, on another worker: not limited
    assert _step(a, s, 2, 0.3) <= 0.1 + 1e-9  # a later frame: the step limit
    r = a.put(f"/v1/sessions/{s.id}/pose", json={"q": [0.0, 0.0, 0.0]}, headers=s.headers)
    assert r.status_code == 200, r.text
    assert _step(b, s, 3, -0.3) > 0.1  # first again after the pose set on A


def test_a_smooth_stream_served_by_two_workers_anchors_at_its_tenth_miss(
    workers: Workers,
) -> None:
    """The frames a stream missed before it is anchored are counted in Redis: a stream
    whose frames go to one worker, then the other, anchors at its tenth miss as on one
    worker. (With the count kept in each worker's solver only, it started again at
    every reload, and the frame after ten misses turned the dial 5.9 rad.)"""
    a, b = workers()
    s = create(
        a,
        DIAL,
        options={"max_joint_step_rad": 0.1, "time_budget_us": 50_000.0},
        initial_pose={"q": [1.0]},
    )

    def frame(worker: TestClient, frame_id: int, angle: float) -> dict[str, Any]:
        position = {"x": math.cos(angle), "y": math.sin(angle), "z": 0.0}
        body = {"id": frame_id, "targets": [{"effector": "hand", "position": position}]}
        r = worker.post(f"/v1/sessions/{s.id}/frames", json=body, headers=s.headers)
        assert r.status_code == 200, r.text
        result: dict[str, Any] = r.json()["results"][0]
        return result

    # Angle pi: inside the dial's reach, outside its limits (+-3 rad): missed each time.
    for k in range(10):
        assert not frame((a, b)[k % 2], k + 1, math.pi)["success"]
    far = frame(a, 11, -2.9)  # 5.9 rad from the answer at the limit, 3
    assert far["largest_step_rad"] <= 0.1 + 1e-9 and not far["jumped"]


def test_the_last_64_answered_frames_are_answered_again_and_an_older_one_is_solved(
    workers: Workers,
) -> None:
    """docs/operations.md: a client with at most KEPT_ANSWERS (64) messages unanswered
    at a failover gets each answered exactly once; an older one has left the window."""
    a, b = workers()
    s = create(a)
    sent = [hand_frame(k, x=0.3 + 0.001 * k) for k in range(1, KEPT_ANSWERS + 2)]
    first = []
    for frame in sent:
        r = a.post(f"/v1/sessions/{s.id}/frames", json=frame, headers=s.headers)
        assert r.status_code == 200, r.text
        first.append(r.json()["results"][0])
    frames = len(sent)
    assert _in_redis(workers, s)["counters"]["frames"] == frames
    for frame, answer in zip(sent[1:], first[1:], strict=True):  # the last 64, on B
        r = b.post(f"/v1/sessions/{s.id}/frames", json=frame, headers=s.headers)
        assert r.status_code == 200, r.text
        assert r.json()["results"][0] == answer
    assert _in_redis(workers, s)["counters"]["frames"] == frames
    r = b.post(f"/v1/sessions/{s.id}/frames", json=sent[0], headers=s.headers)
    assert r.status_code == 200, r.text
    assert _in_redis(workers, s)["counters"]["frames"] == frames + 1  # solved again


def test_an_id_sent_again_with_new_targets_keeps_its_answer_as_the_newest(
    workers: Workers,
) -> None:
    """Ids may start again on a new connection: the answer stored under a reused id is
    the newest, so the oldest ids leave the window first, in memory and in Redis (the
    smallest id left first in memory, and Redis's trim could delete the reused id's
    newer answer)."""
    a, b = workers()
    s = create(a)

    post = functools.partial(_post_frame, s=s)

    for k in (1, 2, 3):
        post(a, hand_frame(k, x=0.3 + 0.001 * k))
    again = hand_frame(1, x=0.35)  # id 1 once more, other targets: solved, stored
    answer = post(a, again)
    for k in range(100, 100 + KEPT_ANSWERS - 1):  # the window is now full, ids 2 and 3 out
        post(a, hand_frame(k, x=0.3 + 0.0005 * (k - 100)))
    frames = _in_redis(workers, s)["counters"]["frames"]
    assert post(a, again) == answer  # the worker that holds it
    assert post(b, again) == answer  # a worker that loads it from Redis
    assert _in_redis(workers, s)["counters"]["frames"] == frames  # neither solved it again


def test_get_and_fk_of_the_current_pose_read_the_latest_on_every_worker(
    workers: Workers,
) -> None:
    """Behind a balancer, GET and FK of a session are routed to any worker (an operator
    trial: the creating worker answered the pose and counters it had before the other
    worker's frames). They reload the session first, as a change does."""
    a, b = workers()
    s = create(a)
    before = a.get(f"/v1/sessions/{s.id}", headers=s.headers).json()  # A holds its copy
    assert before["counters"]["frames"] == 0
    for k in range(3):
        r = b.post(
            f"/v1/sessions/{s.id}/frames", json=hand_frame(k, x=0.3 + 0.02 * k), headers=s.headers
        )
        assert r.status_code == 200, r.text
    q_b = r.json()["results"][0]["q"]
    info = a.get(f"/v1/sessions/{s.id}", headers=s.headers).json()
    assert info["counters"]["frames"] == 3
    assert info["pose"]["q"] == pytest.approx(q_b)
    fk = a.post(f"/v1/sessions/{s.id}/fk", json={}, headers=s.headers)
    assert fk.status_code == 200, fk.text
    assert fk.json()["q"] == pytest.approx(q_b)
    hand = fk.json()["effectors"][0]["position"]
    assert [hand["x"], hand["y"], hand["z"]] == pytest.approx([0.34, 0.1, 0.6], abs=1e-3)
    r = b.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(3, x=0.28), headers=s.headers)
    q_b = r.json()["results"][0]["q"]
    with a.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "fk", "id": 1})
        answer = ws.receive_json()
    assert answer["type"] == "fk_result", answer
    assert answer["q"] == pytest.approx(q_b)


def _hgetalls(redis_url: str) -> int:
    """HGETALL calls Redis has run (scripts' calls included): whole-session reads."""
    stats = redis.Redis.from_url(redis_url).info("commandstats")
    return int(stats.get("cmdstat_hgetall", {}).get("calls", 0))


def test_get_and_fk_read_the_session_whole_only_when_another_worker_changed_it(
    workers: Workers, redis_url: str
) -> None:
    """GET and FK compare the version in Redis first: the worker that answered the last
    frames reads no state back (it held the latest), one behind another worker's frames
    reads it whole, in the same one round trip."""
    a, b = workers()
    s = create(a)
    r = a.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(0, x=0.3), headers=s.headers)
    assert r.status_code == 200, r.text
    before = _hgetalls(redis_url)
    assert a.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["counters"]["frames"] == 1
    assert a.post(f"/v1/sessions/{s.id}/fk", json={}, headers=s.headers).status_code == 200
    assert _hgetalls(redis_url) == before  # A holds the latest: nothing read back
    r = b.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(1, x=0.32), headers=s.headers)
    assert r.status_code == 200, r.text
    q_b = r.json()["results"][0]["q"]
    before = _hgetalls(redis_url)
    info = a.get(f"/v1/sessions/{s.id}", headers=s.headers).json()
    assert info["counters"]["frames"] == 2
    assert info["pose"]["q"] == pytest.approx(q_b)
    assert _hgetalls(redis_url) == before + 2  # the session's hash and its answers


def _histogram(text: str, name: str, label: str = "") -> dict[float, float]:
    """A histogram's cumulative counts by upper bound, from /metrics."""
    out = {}
    for line in text.splitlines():
        if line.startswith(f"{name}_bucket{{") and label in line:
            bound = line.split('le="')[1].split('"')[0]
            out[float(bound)] = float(line.rsplit(" ", 1)[1])
    return out


def test_a_slow_redis_shows_in_the_commit_histogram_not_only_to_clients(
    workers: Workers, redis_url: str, make_client: Callable[..., TestClient]
) -> None:
    """An operator trial: Redis pausing writes 300 ms made frames that slow for the
    client, and ik_server_duration_seconds (which ends before the commit) showed none
    of it: no series said Redis was slow."""
    (a,) = workers(1)
    s = create(a)
    assert a.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(1), headers=s.headers).is_success
    redis.Redis.from_url(redis_url).execute_command("CLIENT", "PAUSE", "300", "WRITE")
    started = time.perf_counter()
    r = a.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(2, x=0.31), headers=s.headers)
    assert r.status_code == 200, r.text
    assert time.perf_counter() - started > 0.2  # the client waited for Redis
    text = a.get("/metrics").text
    commits = _histogram(text, "ik_redis_commit_duration_seconds")
    assert commits[math.inf] >= 2  # the session's creation, then its frames
    assert commits[math.inf] - commits[0.1024] >= 1  # the paused one
    server = _histogram(text, "ik_server_duration_seconds", 'transport="http"')
    assert server[math.inf] - server[0.08192] == 0  # blind to it, as documented
    # Without Redis there is no commit, and no such series.
    assert "ik_redis_commit" not in make_client(Settings()).get("/metrics").text


# --- a frame's animated pose (tests/service/test_frame_pose.py) -------------------------
_ANIMATED = [0.4, 0.3, 1.1]


def _posed(session: Session, frame_id: int, pose: list[float], at: list[float]) -> dict[str, Any]:
    """A frame of the example arm starting from ``pose``, its hand's target where the
    hand is at ``at`` (forward kinematics of the session's chain)."""
    x, y, z = effector_poses(session.view.chain, np.array(at))[0][:3, 3]
    frame = hand_frame(frame_id, x=float(x), y=float(y), z=float(z))
    return {**frame, "pose": {"q": pose}}


def test_a_frame_sent_again_with_another_animated_pose_is_solved_again(
    workers: Workers, redis_url: str
) -> None:
    """The stored answer of a frame sent again (same id, same targets) is given only
    when its animated pose is the same too: with another pose it is another frame,
    solved from that pose, and its commit stores the new rest pose."""
    a, b = workers()
    s = create(a)

    post = functools.partial(_post_frame, s=s)

    session = a.portal.call(_store(a).get, s.id)
    assert session is not None
    frame = _posed(session, 1, _ANIMATED, _ANIMATED)
    answer = post(a, frame)
    assert answer["largest_step_rad"] < 1e-6
    assert _stored_stream(redis_url, s).rest.tolist() == pytest.approx(_ANIMATED, abs=0)
    frames = _in_redis(workers, s)["counters"]["frames"]
    assert post(b, frame) == answer  # the same pose: the stored answer, not solved
    assert _in_redis(workers, s)["counters"]["frames"] == frames
    other = [0.5, 0.2, 1.2]
    moved = post(b, {**frame, "pose": {"q": other}})  # the same id and targets
    assert moved["largest_step_rad"] > 0.05  # from the other pose to the target
    assert _in_redis(workers, s)["counters"]["frames"] == frames + 1
    stored = _stored_stream(redis_url, s)
    assert stored.rest.tolist() == pytest.approx(other, abs=0)
    assert stored.q.tolist() == pytest.approx(moved["q"], abs=0)


@pytest.mark.parametrize("shared", [True, False], ids=["redis", "memory"])
def test_a_cancelled_frame_with_an_animated_pose_leaves_the_rest_pose_as_it_was(
    workers: Workers, make_client: Callable[..., TestClient], redis_url: str, shared: bool
) -> None:
    """A frame that carried an animated pose and was cancelled while its thread solved
    it leaves no trace: the pose, the counters and the rest pose (which the pose set)
    are put back, in this worker and in Redis."""
    a = _two_stores(workers, make_client, shared)
    s = create(a)
    rest = [0.1, -0.2, 0.9]
    r = a.put(f"/v1/sessions/{s.id}/pose", json={"q": rest}, headers=s.headers)
    assert r.status_code == 200, r.text
    store = a.app.state.ik.store  # type: ignore[attr-defined]
    answered = _frame_q(a, s, 0, 0.1)
    session = a.portal.call(store.get, s.id)
    assert session is not None
    runner = a.app.state.ik.runner  # type: ignore[attr-defined]
    frame = _posed(session, 1, _ANIMATED, [0.5, 0.2, 1.2])
    pose = convert.frame_pose(S.Frame(**frame).pose, session.view, "pose")
    job = (1, frame_targets(session, frame), pose)
    _cancelled_mid_solve(
        a,
        session,
        lambda: runner.session_frames(session, store, [job], time.perf_counter(), "http"),
    )
    assert (session.frames, session.solver.q.tolist()) == (1, pytest.approx(answered, abs=0))
    assert session.rest is not None and session.rest.tolist() == rest
    # The solver's own rest pose (where the null-space step steers), put back too.
    assert session.solver._dd[DD_REST].tolist() == pytest.approx(rest, abs=0)
    if shared:
        stored = _stored_stream(redis_url, s)
        assert stored.rest is not None and stored.rest.tolist() == rest
        assert (stored.frames, stored.q.tolist()) == (1, pytest.approx(answered, abs=0))
