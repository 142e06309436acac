"""Planned clips over HTTP: ``{"frames": [...], "plan": true}``."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from starlette.testclient import TestClient

import schemas as S
from service import convert, solving
from service.config import Settings
from service.errors import ServiceError
from service.metrics import Metrics
from service.sessions import InMemorySessionStore, new_session
from solver.examples import panda_arm
from solver.ik import IKSolver
from tests.solver.test_path import joint_stream

from .helpers import ARM, Created, create, hand_frame
from .test_http import _panda_target

# Tolerances of the benchmark; a budget no loaded CI machine runs out of.
TIGHT = {"position_tolerance_m": 1e-5, "rotation_tolerance_rad": 1e-4, "time_budget_us": 50_000}


def _panda_session(client: TestClient, q0: np.ndarray) -> Created:
    return create(
        client,
        {"format": "example", "name": "panda_arm"},
        options=TIGHT,
        initial_pose={"q": q0.tolist()},
    )


def _clip(path: np.ndarray, plan: bool) -> dict[str, Any]:
    frames = [{"id": i, "targets": [_panda_target(q)]} for i, q in enumerate(path)]
    return {"frames": frames, "plan": plan}


def _steps(start: list[float], results: list[dict[str, Any]]) -> float:
    qs = np.array([start] + [r["q"] for r in results])
    return float(np.abs(np.diff(qs, axis=0)).max())


def test_a_planned_clip_crosses_smoothly_where_the_tracked_clip_jumps(
    make_client: Callable[..., TestClient],
) -> None:
    # The Panda stream of tests/solver/test_path.py whose tracker jumps at frame 78.
    client = make_client(Settings(max_frames_per_request=600))
    path = joint_stream(panda_arm(), 4, 90)
    ref = float(np.abs(np.diff(path, axis=0)).max())
    planned = _panda_session(client, path[0])
    r = client.post(
        f"/v1/sessions/{planned.id}/frames", json=_clip(path, True), headers=planned.headers
    )
    assert r.status_code == 200, r.text
    body = S.FrameResults.model_validate(r.json())
    assert body.plan is not None
    assert [x.id for x in body.results] == list(range(90))
    assert all(x.success and x.status == "solved" for x in body.results)
    results = r.json()["results"]
    assert _steps(path[0].tolist(), results) <= 2 * ref
    assert body.plan.largest_step_rad == _steps(path[0].tolist(), results)
    assert body.plan.tracked_largest_step_rad > 10 * ref
    assert body.plan.candidates > 90 and body.plan.plan_us > 0

    tracked = _panda_session(client, path[0])
    r = client.post(
        f"/v1/sessions/{tracked.id}/frames", json=_clip(path, False), headers=tracked.headers
    )
    assert r.status_code == 200 and "plan" not in r.json()
    assert _steps(path[0].tolist(), r.json()["results"]) > 10 * ref


def test_a_planned_clip_counts_its_frames_and_moves_the_session(
    client: TestClient, session: Created
) -> None:
    frames = [hand_frame(i, y=0.1 + 0.01 * i) for i in range(5)]
    r = client.post(
        f"/v1/sessions/{session.id}/frames?results=compact",
        json={"frames": frames, "plan": True},
        headers=session.headers,
    )
    assert r.status_code == 200, r.text
    body = S.CompactFrameResults.model_validate(r.json())
    assert body.plan is not None and all(x.success for x in body.results)
    info = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()
    assert info["counters"] == {"frames": 5, "solved": 5, "not_solved": 0}
    assert info["pose"]["q"] == body.results[-1].q
    metrics = client.get("/metrics").text
    assert 'ik_frames_total{success="true",termination="goal_reached"} 5.0' in metrics


def test_a_planned_clip_is_checked_whole_before_it_is_planned(
    client: TestClient, session: Created
) -> None:
    before = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()
    frames = [
        hand_frame(1),
        {"targets": [{"effector": "nope", "position": {"x": 0, "y": 0, "z": 0}}]},
    ]
    r = client.post(
        f"/v1/sessions/{session.id}/frames",
        json={"frames": frames, "plan": True},
        headers=session.headers,
    )
    assert r.status_code == 422 and r.json()["field"] == "frames[1].targets[0].effector"
    after = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()
    assert after["pose"] == before["pose"]
    assert after["counters"]["frames"] == 0


def test_plan_must_be_a_boolean(client: TestClient, session: Created) -> None:
    r = client.post(
        f"/v1/sessions/{session.id}/frames",
        json={"frames": [hand_frame(1)], "plan": "yes please"},
        headers=session.headers,
    )
    assert r.status_code == 422 and r.json()["code"] == "invalid_format"
    assert [e["loc"] for e in r.json()["detail"]] == [["body", "clip", "plan"]]


def test_a_planned_clip_keeps_the_frame_limit(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_frames_per_request=3))
    s = create(client)
    r = client.post(
        f"/v1/sessions/{s.id}/frames",
        json={"frames": [hand_frame(i) for i in range(4)], "plan": True},
        headers=s.headers,
    )
    assert r.status_code == 422 and r.json()["field"] == "frames"


def test_a_planned_clip_runs_on_the_planning_thread(
    client: TestClient, session: Created, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Plans take seconds: they must not occupy the pool that serves frames and solves.
    threads: list[str] = []
    real = IKSolver.plan

    def spy(self: IKSolver, *args: Any, **kwargs: Any) -> Any:
        threads.append(threading.current_thread().name)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(IKSolver, "plan", spy)
    r = client.post(
        f"/v1/sessions/{session.id}/frames",
        json={"frames": [hand_frame(1), hand_frame(2, y=0.11)], "plan": True},
        headers=session.headers,
    )
    assert r.status_code == 200, r.text
    assert len(threads) == 1 and threads[0].startswith("ik-plan")


def test_plans_beyond_the_queue_limit_are_refused_at_once(warm_solver: float) -> None:
    # Two plans in flight (one running, blocked here; one queued behind it) fill a
    # queue of two: a third is refused with 503 plans_busy at once, and once both are
    # done the count is back to 0, also for the one whose caller went away.
    settings = Settings()
    view = convert.chain_from_spec(S.HierarchyChain.model_validate(ARM), settings)
    options = convert.session_defaults(settings)
    release = threading.Event()

    async def scenario() -> None:
        warm = solving.Warmup(lambda: 0.0)
        warm._run()
        runner = solving.Runner(
            inline_budget_us=0.0,
            threads=1,
            metrics=Metrics(lambda: 1),
            warmup=warm,
            max_frames_per_request=10,
            max_queued_plans=2,
        )
        store = InMemorySessionStore(max_sessions=3, ttl_s=60.0)
        sessions = []
        for _ in range(3):
            session, _ = new_session(
                view, IKSolver(view.chain, options), options, now=store.clock()
            )
            await store.add(session)
            real = session.solver.plan

            def blocked(*args: Any, real: Any = real, **kwargs: Any) -> Any:
                release.wait(timeout=30)
                return real(*args, **kwargs)

            session.solver.plan = blocked  # type: ignore[method-assign]
            sessions.append(session)
        target = convert.targets(S.Frame.model_validate(hand_frame(1)).targets, view, "t")
        jobs = [(1, target)]
        try:
            first = asyncio.create_task(runner.session_plan(sessions[0], store, jobs, 0.0, "http"))
            second = asyncio.create_task(runner.session_plan(sessions[1], store, jobs, 0.0, "http"))
            await asyncio.sleep(0.2)
            assert runner.plans_in_flight == 2

            async def third() -> None:
                # At once: a wait here would be a queue, which is what the limit prevents.
                with pytest.raises(ServiceError) as refused:
                    await asyncio.wait_for(
                        runner.session_plan(sessions[2], store, jobs, 0.0, "http"), timeout=2.0
                    )
                assert refused.value.code == "plans_busy" and refused.value.status_code == 503

            await third()
            second.cancel()  # its caller goes away: the plan still counts until it is done
            with contextlib.suppress(asyncio.CancelledError):
                await second
            assert runner.plans_in_flight == 2
            await third()
            release.set()
            out, plan = await first
            assert out[0]["success"] and plan.success
            for _ in range(100):
                if runner.plans_in_flight == 0:
                    break
                await asyncio.sleep(0.05)
            assert runner.plans_in_flight == 0
            assert sessions[1].frames == 1  # the cancelled request's plan did run
            # A plan refused before it reaches the thread gives its place back.
            sessions[2].closed = True
            with pytest.raises(ServiceError, match="no such session"):
                await runner.session_plan(sessions[2], store, jobs, 0.0, "http")
            assert runner.plans_in_flight == 0 and runner.plans_by_client == {}
        finally:
            release.set()
            runner.shutdown()

    asyncio.run(scenario())


def test_one_client_holds_at_most_half_the_plan_places(warm_solver: float) -> None:
    # A queue of four: one API key (two of its sessions) holds two places, and its
    # third plan is refused with 429 too_many_plans while places are free; another
    # key, and a session created without keys (its own client), still get theirs;
    # past four, 503 plans_busy. When all are done nothing is left counted.
    settings = Settings()
    view = convert.chain_from_spec(S.HierarchyChain.model_validate(ARM), settings)
    options = convert.session_defaults(settings)
    release = threading.Event()

    async def scenario() -> None:
        warm = solving.Warmup(lambda: 0.0)
        warm._run()
        runner = solving.Runner(
            inline_budget_us=0.0,
            threads=1,
            metrics=Metrics(lambda: 1),
            warmup=warm,
            max_frames_per_request=10,
            max_queued_plans=4,
        )
        store = InMemorySessionStore(max_sessions=10, ttl_s=60.0)

        async def session_of(owner: str | None) -> Any:
            session, _ = new_session(
                view, IKSolver(view.chain, options), options, now=store.clock(), owner=owner
            )
            await store.add(session)
            real = session.solver.plan

            def blocked(*args: Any, real: Any = real, **kwargs: Any) -> Any:
                release.wait(timeout=30)
                return real(*args, **kwargs)

            session.solver.plan = blocked  # type: ignore[method-assign]
            return session

        a1, a2, b, c, d = [await session_of(o) for o in ("key-a", "key-a", "key-b", None, None)]
        target = convert.targets(S.Frame.model_validate(hand_frame(1)).targets, view, "t")
        jobs = [(1, target)]

        def plan(session: Any) -> asyncio.Task[Any]:
            return asyncio.create_task(runner.session_plan(session, store, jobs, 0.0, "http"))

        async def refused(session: Any) -> ServiceError:
            with pytest.raises(ServiceError) as e:
                await asyncio.wait_for(
                    runner.session_plan(session, store, jobs, 0.0, "http"), timeout=2.0
                )
            return e.value

        try:
            running = [plan(a1), plan(a2)]
            await asyncio.sleep(0.1)
            error = await refused(a1)
            assert (error.code, error.status_code) == ("too_many_plans", 429)
            assert error.retry_after_s is not None
            assert runner.plans_in_flight == 2
            running += [plan(b), plan(c)]
            await asyncio.sleep(0.1)
            assert runner.plans_in_flight == 4
            error = await refused(d)
            assert (error.code, error.status_code) == ("plans_busy", 503)
            release.set()
            for task in running:
                out, _ = await task
                assert out[0]["success"]
            for _ in range(100):
                if runner.plans_in_flight == 0:
                    break
                await asyncio.sleep(0.05)
            assert runner.plans_in_flight == 0 and runner.plans_by_client == {}
        finally:
            release.set()
            runner.shutdown()

    asyncio.run(scenario())


def test_a_plan_whose_session_is_deleted_while_queued_does_not_run(warm_solver: float) -> None:
    settings = Settings()
    view = convert.chain_from_spec(S.HierarchyChain.model_validate(ARM), settings)
    options = convert.session_defaults(settings)
    release = threading.Event()
    ran: list[str] = []

    async def scenario() -> None:
        warm = solving.Warmup(lambda: 0.0)
        warm._run()
        runner = solving.Runner(
            inline_budget_us=0.0,
            threads=1,
            metrics=Metrics(lambda: 1),
            warmup=warm,
            max_frames_per_request=10,
            max_queued_plans=4,
        )
        store = InMemorySessionStore(max_sessions=10, ttl_s=60.0)
        sessions = []
        for name in ("running", "queued"):
            session, _ = new_session(
                view, IKSolver(view.chain, options), options, now=store.clock()
            )
            await store.add(session)
            real = session.solver.plan

            def recorded(*args: Any, real: Any = real, name: str = name, **kwargs: Any) -> Any:
                ran.append(name)
                release.wait(timeout=30)
                return real(*args, **kwargs)

            session.solver.plan = recorded  # type: ignore[method-assign]
            sessions.append(session)
        target = convert.targets(S.Frame.model_validate(hand_frame(1)).targets, view, "t")
        jobs = [(1, target)]
        try:
            tasks = [
                asyncio.create_task(runner.session_plan(s, store, jobs, 0.0, "http"))
                for s in sessions
            ]
            await asyncio.sleep(0.2)
            assert ran == ["running"] and runner.plans_in_flight == 2
            await store.remove(sessions[1].id)  # deleted while its plan waits
            release.set()
            out, _ = await tasks[0]
            assert out[0]["success"]
            with pytest.raises(ServiceError) as refused:
                await tasks[1]
            assert refused.value.code == "not_found"
            assert ran == ["running"] and sessions[1].frames == 0
            for _ in range(100):
                if runner.plans_in_flight == 0:
                    break
                await asyncio.sleep(0.05)
            assert runner.plans_in_flight == 0 and runner.plans_by_client == {}
        finally:
            release.set()
            runner.shutdown()

    asyncio.run(scenario())
