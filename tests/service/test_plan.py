"""Planned clips over HTTP: ``{"frames": [...], "plan": true}``."""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Awaitable, Callable, Coroutine
from typing import Any

import numpy as np
import pytest
from starlette.testclient import TestClient

import schemas as S
from service import convert, solving
from service.config import Settings
from service.errors import ServiceError
from service.metrics import Metrics
from service.sessions import InMemorySessionStore, Session, new_session
from solver.ik import IKSolver
from solver.model.examples import panda_arm
from tests.solver.helpers import joint_stream

from .helpers import ARM, Created, create, hand_frame, panda_target

# Tolerances of the benchmark; a budget no loaded CI machine runs out of.
# REACH: the tracked clip these tests compare plans with jumps (a smooth one lags).
TIGHT = {
    "position_tolerance_m": 1e-5,
    "rotation_tolerance_rad": 1e-4,
    "time_budget_us": 50_000,
    "continuity": "reach",
}


def _panda_session(client: TestClient, q0: np.ndarray) -> Created:
    return create(
        client,
        {"format": "example", "name": "panda_arm"},
        options=TIGHT,
        initial_pose={"q": q0.tolist()},
    )


def _clip(path: np.ndarray, plan: bool) -> dict[str, Any]:
    frames = [{"id": i, "targets": [panda_target(q)]} for i, q in enumerate(path)]
    return {"frames": frames, "plan": plan}


def _steps(start: list[float], results: list[dict[str, Any]]) -> float:
    qs = np.array([start] + [r["q"] for r in results])
    return float(np.abs(np.diff(qs, axis=0)).max())


def test_a_planned_clip_crosses_smoothly_where_the_tracked_clip_jumps(
    make_client: Callable[..., TestClient],
) -> None:
    # The Panda stream of tests/solver/test_path.py whose tracker steps 0.11 rad (6.4x
    # the reference's) near frame 78 (radians before frames in the limit band were
    # solved on the exact task).
    # 90 frames x 50 ms at worst: over the default IK_MAX_REQUEST_WORK_S.
    client = make_client(Settings(max_frames_per_request=600, max_request_work_s=5.0))
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
    assert body.plan.tracked_largest_step_rad > 5 * ref
    assert body.plan.candidates > 90 and body.plan.plan_us > 0

    tracked = _panda_session(client, path[0])
    r = client.post(
        f"/v1/sessions/{tracked.id}/frames", json=_clip(path, False), headers=tracked.headers
    )
    assert r.status_code == 200 and "plan" not in r.json()
    assert _steps(path[0].tolist(), r.json()["results"]) > 5 * ref


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
    real = solving.plan_path

    def spy(*args: Any, **kwargs: Any) -> Any:
        threads.append(threading.current_thread().name)
        return real(*args, **kwargs)

    monkeypatch.setattr(solving, "plan_path", spy)
    r = client.post(
        f"/v1/sessions/{session.id}/frames",
        json={"frames": [hand_frame(1), hand_frame(2, y=0.11)], "plan": True},
        headers=session.headers,
    )
    assert r.status_code == 200, r.text
    assert len(threads) == 1 and threads[0].startswith("ik-plan")


class _HeldPlans:
    """A Runner on the example arm whose sessions' plans wait for ``release``: what
    the plan-queue tests drive. ``ran`` names the sessions whose plan started."""

    def __init__(self, max_queued_plans: int, real_plan: Callable[..., Any]) -> None:
        self.real_plan = real_plan
        settings = Settings(
            inline_budget_us=0.0,
            solver_threads=1,
            max_frames_per_request=10,
            max_frames_per_s=0.0,
            max_queued_plans=max_queued_plans,
        )
        self.view = convert.chain_from_spec(S.HierarchyChain.model_validate(ARM), settings)
        self.options = convert.session_defaults(settings)
        self.release = threading.Event()
        self.ran: list[str] = []
        self.names: dict[int, str] = {}  # id of a session's solver -> session name
        warm = solving.Warmup(lambda _report: 0.0)
        warm._run()
        self.runner = solving.Runner(settings, metrics=Metrics(lambda: 1), warmup=warm)
        self.store = InMemorySessionStore(max_sessions=10, ttl_s=60.0)
        frame = S.Frame.model_validate(hand_frame(1))
        self.jobs = [(1, convert.targets(frame.targets, self.view, "t"), None)]

    async def session(self, name: str, owner: str | None = None) -> Session:
        session, _ = new_session(
            self.view,
            IKSolver(self.view.chain, self.options),
            self.options,
            now=self.store.clock(),
            owner=owner,
        )
        await self.store.add(session)
        self.names[id(session.solver)] = name
        return session

    def held_plan(self, solver: IKSolver, *args: Any, **kwargs: Any) -> Any:
        """``plan_path`` for the service, waiting for ``release`` first."""
        self.ran.append(self.names[id(solver)])
        self.release.wait(timeout=30)
        return self.real_plan(solver, *args, **kwargs)

    def plan(self, session: Session) -> Coroutine[Any, Any, Any]:
        return self.runner.session_plan(session, self.store, self.jobs, 0.0, "http")

    def start(self, session: Session) -> asyncio.Task[Any]:
        return asyncio.create_task(self.plan(session))

    async def refused(self, session: Session) -> ServiceError:
        """The error ``session``'s plan gets, at once (a wait would be a queue, which
        is what the limits prevent)."""
        with pytest.raises(ServiceError) as e:
            await asyncio.wait_for(self.plan(session), timeout=2.0)
        return e.value

    async def settled(self) -> None:
        """Every place given back once the plans are done."""
        for _ in range(100):
            if self.runner.plans_in_flight == 0:
                break
            await asyncio.sleep(0.05)
        assert self.runner.plans_in_flight == 0 and self.runner.plans_by_client == {}

    def close(self) -> None:
        self.release.set()
        self.runner.shutdown()


def _with_held_plans(max_queued_plans: int, body: Callable[[_HeldPlans], Awaitable[None]]) -> None:
    real = solving.plan_path
    holder: list[_HeldPlans] = []

    async def scenario() -> None:
        held = _HeldPlans(max_queued_plans, real)
        holder.append(held)
        try:
            await body(held)
        finally:
            held.close()

    with pytest.MonkeyPatch.context() as patch:
        # The service plans through solving.plan_path: each session's plan waits.
        patch.setattr(solving, "plan_path", lambda *a, **k: holder[0].held_plan(*a, **k))
        asyncio.run(scenario())


def test_plans_beyond_the_queue_limit_are_refused_at_once(warm_solver: float) -> None:
    # Two plans in flight (one running, blocked here; one queued behind it) fill a
    # queue of two: a third is refused with 503 plans_busy at once, and once both are
    # done the count is back to 0, also for the one whose caller went away.
    async def body(h: _HeldPlans) -> None:
        sessions = [await h.session(name) for name in ("first", "second", "third")]
        first, second = h.start(sessions[0]), h.start(sessions[1])
        await asyncio.sleep(0.2)
        assert h.runner.plans_in_flight == 2
        error = await h.refused(sessions[2])
        assert (error.code, error.status_code) == ("plans_busy", 503)
        second.cancel()  # its caller goes away: the plan still counts until it is done
        with contextlib.suppress(asyncio.CancelledError):
            await second
        assert h.runner.plans_in_flight == 2
        assert (await h.refused(sessions[2])).code == "plans_busy"
        h.release.set()
        out, plan = await first
        assert out[0].result.success and plan.success
        await h.settled()
        # The cancelled request's plan did run, and left no trace (Session.rewind).
        assert "second" in h.ran and (sessions[1].frames, sessions[0].frames) == (0, 1)
        # A plan refused before it reaches the thread gives its place back.
        sessions[2].closed = True
        with pytest.raises(ServiceError, match="no such session"):
            await h.plan(sessions[2])
        await h.settled()

    _with_held_plans(2, body)


def test_one_client_holds_at_most_half_the_plan_places(warm_solver: float) -> None:
    # A queue of four: one API key (two of its sessions) holds two places, and its
    # third plan is refused with 429 too_many_plans while places are free; another
    # key, and a session created without keys (its own client), still get theirs;
    # past four, 503 plans_busy. When all are done nothing is left counted.
    async def body(h: _HeldPlans) -> None:
        owners = {"a1": "key-a", "a2": "key-a", "b": "key-b", "c": None, "d": None}
        s = {name: await h.session(name, owner) for name, owner in owners.items()}
        running = [h.start(s["a1"]), h.start(s["a2"])]
        await asyncio.sleep(0.1)
        error = await h.refused(s["a1"])
        assert (error.code, error.status_code) == ("too_many_plans", 429)
        assert error.retry_after_s is not None
        assert h.runner.plans_in_flight == 2
        running += [h.start(s["b"]), h.start(s["c"])]
        await asyncio.sleep(0.1)
        assert h.runner.plans_in_flight == 4
        error = await h.refused(s["d"])
        assert (error.code, error.status_code) == ("plans_busy", 503)
        h.release.set()
        for task in running:
            out, _ = await task
            assert out[0].result.success
        await h.settled()

    _with_held_plans(4, body)


def test_a_plan_whose_session_is_deleted_while_queued_does_not_run(warm_solver: float) -> None:
    async def body(h: _HeldPlans) -> None:
        running, queued = await h.session("running"), await h.session("queued")
        tasks = [h.start(running), h.start(queued)]
        await asyncio.sleep(0.2)
        assert h.ran == ["running"] and h.runner.plans_in_flight == 2
        await h.store.remove(queued.id)  # deleted while its plan waits
        h.release.set()
        out, _ = await tasks[0]
        assert out[0].result.success
        with pytest.raises(ServiceError) as refused:
            await tasks[1]
        assert refused.value.code == "not_found"
        assert h.ran == ["running"] and queued.frames == 0
        await h.settled()

    _with_held_plans(4, body)
