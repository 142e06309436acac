"""Several workers behind a real HAProxy (deploy/haproxy.cfg), sessions in a real
redis-server: a killed worker loses no frame and answers none twice, every worker
restarted keeps the sessions, Redis gone gives 503s / WebSocket errors and comes back
by itself.

Without redis-server or haproxy these tests skip, except under CI=true, where they fail
(.ci/run installs both with apt-get).
"""

from __future__ import annotations

import asyncio
import math
import os
import time
from collections.abc import Iterator
from typing import Any

import httpx
import numpy as np
import pytest
from ik_client import AsyncClient, Client, FrameAnswer, Reconnect, ServiceError, StreamClosed
from ik_client.types import Session as SessionRef

from loadtest.cluster import HAPROXY_CFG, Cluster, balancer_config, missing_programs

pytestmark = [pytest.mark.live, pytest.mark.timeout(240)]

WORKERS = 3
CHAIN = {"format": "example", "name": "panda_arm"}
DOWN = {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0}  # the tool pointing down
# A start away from the middle of the limits: the stream then tracks the circle in an
# arm configuration 2.2 rad (joint 1) from the one a solve from the middle finds, so a
# worker that lost the pose and started from the middle would show as a jump.
BRANCH = [2.2, 0.3, -2.2, -2.0, 0.5, 2.2, 0.0]
# Largest joint change between two consecutive frames of the smooth path below: the
# warm-started stream moves ~0.05 rad per frame; a restart from another pose (a lost
# pose after the failover) jumps by far more.
MAX_STEP_RAD = 0.3


def _targets(k: int) -> list[dict[str, Any]]:
    """Frame ``k`` of a slow circle of the tool, pointing down."""
    a = 2 * math.pi * k / 200
    position = {"x": 0.45 + 0.08 * math.cos(a), "y": 0.08 * math.sin(a), "z": 0.45}
    return [{"effector": "tool", "position": position, "orientation": DOWN}]


def _need_programs() -> None:
    """Skip without redis-server or haproxy, except under CI=true, where that fails."""
    missing = missing_programs()
    if missing:
        reason = f"{', '.join(missing)} not installed (.ci/run installs them)"
        if os.environ.get("CI") == "true":
            pytest.fail(f"{reason}; CI=true, so this is a failure, not a skip", pytrace=False)
        pytest.skip(reason)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cluster]:
    _need_programs()
    with Cluster(WORKERS, log_dir=tmp_path_factory.mktemp("cluster")) as c:
        yield c


def _serving_ws(cluster: Cluster) -> int:
    """The index of the worker that holds an open WebSocket (ik_websockets gauge)."""
    for i, w in enumerate(cluster.workers):
        text = httpx.get(f"{w.base}/metrics", timeout=5).text
        for line in text.splitlines():
            if line.startswith("ik_websockets ") and float(line.split()[1]) >= 1:
                return i
    raise AssertionError("no worker holds the stream's WebSocket")


def _worker_index(cluster: Cluster, served_by: str) -> int:
    """HAProxy's server name (w0, w1, ...) -> the worker's index."""
    return int(served_by.removeprefix("w"))


def _post_frame(base: str, session: dict[str, Any], frame_id: int, k: int) -> httpx.Response:
    return httpx.post(
        f"{base}/v1/sessions/{session['id']}/frames",
        json={"id": frame_id, "targets": _targets(k)},
        headers={"Authorization": f"Bearer {session['token']}"},
        timeout=10,
    )


def _frame_until_answered(base: str, session: dict[str, Any], frame_id: int, k: int) -> Any:
    """A client following the protocol: the same frame, same id, until it is answered."""
    deadline = time.monotonic() + 30
    while True:
        try:
            r = _post_frame(base, session, frame_id, k)
            if r.status_code == 200:
                return r
            assert r.status_code in (502, 503), r.text
        except httpx.TransportError:
            pass
        assert time.monotonic() < deadline, f"frame {frame_id} never answered"
        time.sleep(0.1)


def _session(cluster: Cluster) -> dict[str, Any]:
    """A new session through the balancer; ``created_on``: the worker's index."""
    request = {"chain": CHAIN, "initial_pose": {"q": BRANCH}}
    r = httpx.post(f"{cluster.base}/v1/sessions", json=request, timeout=10)
    assert r.status_code == 201, r.text
    body: dict[str, Any] = r.json()
    body["created_on"] = _worker_index(cluster, r.headers["x-served-by"])
    return body


def _counters(cluster: Cluster, session: dict[str, Any]) -> dict[str, int]:
    """The session's counters (after a restart, once the balancer sees a worker up)."""
    deadline = time.monotonic() + 15
    while True:
        r = httpx.get(
            f"{cluster.base}/v1/sessions/{session['id']}",
            headers={"Authorization": f"Bearer {session['token']}"},
            timeout=10,
        )
        if r.status_code != 503 or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert r.status_code == 200, r.text
    counters: dict[str, int] = r.json()["counters"]
    return counters


def _largest_step(poses: list[list[float]]) -> float:
    q = np.array(poses)
    return float(np.abs(np.diff(q, axis=0)).max())


def test_a_killed_worker_loses_no_frame_and_answers_none_twice(cluster: Cluster) -> None:
    session = _session(cluster)
    poses: list[list[float]] = []
    answered: dict[int, int] = {}
    n_ws, kill_at, in_flight = 60, 20, 4
    handle = SessionRef.from_json(session)

    async def stream() -> int:
        async with AsyncClient(cluster.base) as client:
            reconnect = Reconnect(attempts=10, initial_delay_s=0.1, max_delay_s=1.0)
            async with client.stream(handle, reconnect=reconnect) as s:
                sent = 0
                killed = -1
                while len(answered) < n_ws:
                    while sent < n_ws and sent - len(answered) < in_flight:
                        await s.send_frame(_targets(sent))
                        sent += 1
                    answer = await s.receive()
                    assert isinstance(answer, FrameAnswer)
                    answered[answer.id] = answered.get(answer.id, 0) + 1
                    poses.append(list(answer.result.q))
                    if len(answered) == kill_at:  # frames still in flight on the worker
                        killed = _serving_ws(cluster)
                        cluster.kill(killed)
                assert s.reconnects >= 1
                return killed

    killed = asyncio.run(asyncio.wait_for(stream(), 120))
    assert sorted(answered) == list(range(n_ws)), "a frame lost"
    assert set(answered.values()) == {1}, "a frame answered twice"
    assert _largest_step(poses) < MAX_STEP_RAD, "the pose jumped across the failover"

    # HTTP frames of the same session: through the balancer (routed by session id) and
    # straight to each live worker, so they land on different workers.
    live = [i for i in range(WORKERS) if i != killed]
    served: set[str] = set()
    for j in range(20):
        k = n_ws + j
        base = cluster.base if j % 2 == 0 else cluster.workers[live[j // 2 % len(live)]].base
        r = _frame_until_answered(base, session, 1000 + j, k)
        served.add(r.headers.get("x-served-by", base))
        poses.append(r.json()["results"][0]["q"])
    assert len(served) >= 2, served

    # Kill the worker the balancer routes the session's HTTP frames to, mid-stream: the
    # same frame id sent again is answered once, from the stored answer or a solve.
    r = _frame_until_answered(cluster.base, session, 2000, n_ws + 20)
    target = _worker_index(cluster, r.headers["x-served-by"])
    cluster.kill(target)
    # Our client does that itself: a frame with an id that got no answer (a dropped
    # connection, the balancer's 502 / 503) is sent again under its id.
    patient = Reconnect(attempts=20, initial_delay_s=0.1, max_delay_s=1.0)
    with Client(cluster.base, reconnect=patient, timeout_s=10) as client:
        for j in range(1, 10):
            answer = client.frame(handle, _targets(n_ws + 20 + j), id=2000 + j)
            poses.append(list(answer.q))
    # And one frame sent twice (a client that lost the first answer): answered as before.
    first = _frame_until_answered(cluster.base, session, 3000, n_ws + 30).json()
    again = _frame_until_answered(cluster.base, session, 3000, n_ws + 30).json()
    assert again == first
    assert _largest_step(poses) < MAX_STEP_RAD, "the pose jumped across the failover"
    # Solved exactly once each: 60 WebSocket frames, 20 + 10 + 1 HTTP frames.
    assert _counters(cluster, session)["frames"] == n_ws + 31

    for i in (killed, target):
        if cluster.workers[i].proc.poll() is not None:
            cluster.restart(i)


def test_sessions_survive_a_restart_of_every_worker(cluster: Cluster) -> None:
    session = _session(cluster)
    before = [_frame_until_answered(cluster.base, session, i, i).json() for i in range(5)]
    for i in range(WORKERS):
        cluster.kill(i)
    for i in range(WORKERS):
        cluster.restart(i)
    after = _frame_until_answered(cluster.base, session, 5, 5).json()
    q0, q1 = before[-1]["results"][0]["q"], after["results"][0]["q"]
    assert _largest_step([q0, q1]) < MAX_STEP_RAD
    assert _counters(cluster, session)["frames"] == 6


def test_redis_down_gives_503_and_errors_then_recovers(cluster: Cluster) -> None:
    session = _session(cluster)
    worker = cluster.workers[0]
    _frame_until_answered(worker.base, session, 0, 0)  # the worker holds the session
    cluster.redis.pause()
    try:
        r = _post_frame(worker.base, session, 1, 1)
        assert r.status_code == 503, r.text
        assert r.json()["code"] == "store_unavailable"
        assert r.headers["retry-after"] == "1"
        ready = httpx.get(f"{worker.base}/readyz", timeout=5)
        assert ready.status_code == 503 and ready.json()["code"] == "store_unavailable"
        # Through the balancer: every worker's /readyz fails, HAProxy answers 503 itself.
        deadline = time.monotonic() + 10
        while _post_frame(cluster.base, session, 1, 1).status_code != 503:
            assert time.monotonic() < deadline
            time.sleep(0.2)
        ws_error = asyncio.run(asyncio.wait_for(_ws_frame_error(worker.base, session), 20))
        assert ws_error == "store_unavailable"
        # A worker that does not hold the session cannot load it: the socket closes 1013.
        stranger = next(i for i in range(WORKERS) if i not in (0, session["created_on"]))
        refused = _ws_frame_error(cluster.workers[stranger].base, session)
        assert asyncio.run(asyncio.wait_for(refused, 20)) == "close 1013 store_unavailable"
    finally:
        cluster.redis.resume()
    r = _frame_until_answered(cluster.base, session, 2, 2)
    assert r.status_code == 200
    assert _frame_until_answered(worker.base, session, 3, 3).status_code == 200


def test_sessions_survive_a_restart_of_redis(cluster: Cluster) -> None:
    """Redis runs with its append-only file, as the shipped compose file and manifests
    run it: restarted, it comes back with the session, which goes on from its pose."""
    session = _session(cluster)
    before = [_frame_until_answered(cluster.base, session, i, i).json() for i in range(3)]
    cluster.redis.restart()
    after = _frame_until_answered(cluster.base, session, 3, 3).json()
    q0, q1 = before[-1]["results"][0]["q"], after["results"][0]["q"]
    assert _largest_step([q0, q1]) < MAX_STEP_RAD
    assert _counters(cluster, session)["frames"] == 4


async def _ws_frame_error(base: str, session: dict[str, Any]) -> str:
    """The error code of one WebSocket frame sent to ``base`` (no reconnects), or the
    close code and reason when the socket is closed instead."""
    async with AsyncClient(base) as client:
        handle = SessionRef.from_json(session)
        async with client.stream(handle, reconnect=Reconnect(attempts=0)) as s:
            try:
                await s.frame(_targets(1))
            except ServiceError as e:
                return str(e.code)
            except StreamClosed as e:
                return f"close {e.close_code} {e.reason}"
    return "answered"


def test_the_balancer_runs_the_shipped_configuration() -> None:
    """The tests' HAProxy config is deploy/haproxy.cfg but for the server lines (and
    Docker's DNS resolvers section, which the loopback servers do not use)."""
    shipped = HAPROXY_CFG.read_text().splitlines()
    ran = balancer_config([1, 2]).splitlines()
    only_shipped = {line.strip() for line in set(shipped) - set(ran)}
    only_ran = {line.strip() for line in set(ran) - set(shipped)}
    resolvers = {"resolvers docker", "nameserver dns 127.0.0.11:53"}
    resolvers |= {"accepted_payload_size 8192", "hold valid 5s"}
    templates = {line for line in only_shipped if line.startswith("server-template ")}
    assert only_shipped - templates == resolvers
    assert templates == {"server-template ik 4 service:8000 resolvers docker"}
    assert sum(line.strip() in templates for line in shipped) == 2  # http and ws
    assert only_ran == {"server w0 127.0.0.1:1", "server w1 127.0.0.1:2"}


def test_metrics_are_read_on_each_worker_not_through_the_balancer(cluster: Cluster) -> None:
    """An operator trial: through the balancer /metrics answered the one worker its path
    hashes to (a third of the figures, to anyone); the shipped file refuses it, also
    percent-encoded (uvicorn decodes the path), and each worker serves its own."""
    for path in ("/metrics", "/%6detrics", "/metrics?name=ik_websockets"):
        r = httpx.get(httpx.URL(cluster.base + path), timeout=5)
        assert r.status_code == 404, (path, r.text)
        assert r.json()["code"] == "not_found"
        assert "scrape each worker" in r.json()["detail"]
    for w in cluster.workers:
        r = httpx.get(f"{w.base}/metrics", timeout=5)
        assert r.status_code == 200 and "ik_websockets " in r.text
    assert httpx.get(f"{cluster.base}/readyz", timeout=5).status_code == 200


@pytest.fixture(scope="module")
def behind(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cluster]:
    """Two workers writing behind (IK_REDIS_WRITE_BEHIND_MS)."""
    _need_programs()
    env = {"IK_REDIS_WRITE_BEHIND_MS": "300"}
    with Cluster(2, log_dir=tmp_path_factory.mktemp("behind"), env=env) as c:
        yield c


def test_written_behind_a_killed_worker_still_answers_every_frame_once(behind: Cluster) -> None:
    """Written behind, a worker's death may lose the last flush interval of poses, never
    an answer: each frame is answered once, none is counted twice, the pose goes on."""
    session = _session(behind)
    answered: dict[int, int] = {}
    poses: list[list[float]] = []
    n, kill_at = 40, 15

    async def stream() -> None:
        async with AsyncClient(behind.base) as client:
            reconnect = Reconnect(attempts=10, initial_delay_s=0.1, max_delay_s=1.0)
            handle = SessionRef.from_json(session)
            async with client.stream(handle, reconnect=reconnect) as s:
                for k in range(n):
                    await s.send_frame(_targets(k))
                    answer = await s.receive()
                    assert isinstance(answer, FrameAnswer)
                    answered[answer.id] = answered.get(answer.id, 0) + 1
                    poses.append(list(answer.result.q))
                    if k == kill_at:
                        behind.kill(_serving_ws(behind))

    asyncio.run(asyncio.wait_for(stream(), 120))
    assert sorted(answered) == list(range(n)) and set(answered.values()) == {1}
    assert _largest_step(poses) < MAX_STEP_RAD
    assert _counters(behind, session)["frames"] <= n
    for i in range(2):
        if behind.workers[i].proc.poll() is not None:
            behind.restart(i)


def test_written_behind_a_graceful_restart_loses_nothing(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """SIGTERM flushes what is written behind: with a flush every 60 s, the frames are in
    Redis after the worker's restart only because its shutdown wrote them."""
    _need_programs()
    env = {"IK_REDIS_WRITE_BEHIND_MS": "60000"}
    with Cluster(1, log_dir=tmp_path_factory.mktemp("flush"), env=env) as c:
        session = _session(c)
        for i in range(10):
            _frame_until_answered(c.base, session, i, i)
        c.workers[0].stop()  # SIGTERM: drain, flush, exit
        c.restart(0)
        assert _counters(c, session)["frames"] == 10
