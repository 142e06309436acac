"""ik_client against a real `python -m service`: every HTTP call (sync and async), the
stream in both encodings, errors with their code and field, close codes, and a
connection dropped mid-pipeline with no answer lost or repeated."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import datetime
import enum
import json
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import ik_client
import msgpack
import pytest
from ik_client import (
    AsyncClient,
    AuthError,
    BatchAnswer,
    Client,
    ClipAnswer,
    ConnectionLost,
    EncodeError,
    Encoding,
    ErrorCode,
    FrameAnswer,
    FrameResult,
    IKClientError,
    InvalidRequest,
    NoAnswer,
    NotFound,
    Pong,
    Quaternion,
    Reconnect,
    RetryLater,
    Session,
    SessionGone,
    Status,
    StreamAuthError,
    Target,
    Termination,
    TooManyWebSockets,
    UnexpectedAnswer,
)
from websockets.asyncio.server import ServerConnection, serve

from .conftest import Server

pytestmark = pytest.mark.live

PANDA = {"format": "example", "name": "panda_arm"}
DOWN: Quaternion = {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0}


def tool(y: float) -> Target:
    return {"effector": "tool", "position": {"x": 0.4, "y": y, "z": 0.5}, "orientation": DOWN}


@pytest.fixture
def ik(server: Server) -> Iterator[Client]:
    with Client(server.base) as client:
        yield client


@pytest.fixture
def session(ik: Client) -> Session:
    return ik.create_session(PANDA)


def assert_solved(result: FrameResult) -> None:
    assert result.success, result
    assert result.status is Status.SOLVED
    assert result.termination is Termination.GOAL_REACHED


# --- the types against the schema -------------------------------------------------------
def fields_of(cls: type) -> set[str]:
    if dataclasses.is_dataclass(cls):
        return {f.name for f in dataclasses.fields(cls)}
    return set(cls.__required_keys__ | cls.__optional_keys__)  # type: ignore[attr-defined]


# Each client type and the schema components it mirrors (FrameResult holds both kinds).
MIRRORS: list[tuple[type, tuple[str, ...]]] = [
    (ik_client.Vec3, ("Vec3",)),
    (ik_client.Quaternion, ("Quaternion",)),
    (ik_client.Target, ("Target",)),
    (ik_client.Pole, ("Pole",)),
    (ik_client.Frame, ("Frame",)),
    (ik_client.BatchFrame, ("BatchFrame",)),
    (ik_client.BatchEntryResult, ("BatchEntryResult", "BatchEntryError")),
    (ik_client.PoseIn, ("PoseIn",)),
    (ik_client.SolverOptionsPatch, ("OptionsPatch",)),
    (ik_client.EffectorError, ("EffectorErrorOut",)),
    (ik_client.FrameResult, ("FrameResult", "CompactFrameResult")),
    (ik_client.PlanSummary, ("PlanSummary",)),
    (ik_client.ClipResult, ("FrameResults", "CompactFrameResults")),
    (ik_client.Pose, ("Pose",)),
    (ik_client.Dof, ("DofInfo",)),
    (ik_client.Effector, ("EffectorInfo",)),
    (ik_client.Follower, ("FollowerInfo",)),
    (ik_client.ModelWarning, ("ModelWarning",)),
    (ik_client.SolverOptions, ("SolverOptions",)),
    (ik_client.SessionCounters, ("SessionCounters",)),
    (ik_client.Session, ("SessionCreated",)),
    (ik_client.SessionInfo, ("SessionInfo",)),
    (ik_client.ConventionsOut, ("ConventionsOut",)),
    (ik_client.Conventions, ("Conventions",)),
    (ik_client.BoneOutput, ("BoneOutput",)),
    (ik_client.FkResult, ("FkResult",)),
    (ik_client.EffectorPose, ("EffectorPoseOut",)),
]


def test_types_mirror_the_live_openapi_schema(server: Server) -> None:
    components = httpx.get(f"{server.base}/openapi.json", timeout=30.0).json()["components"]
    schemas = components["schemas"]
    for cls, names in MIRRORS:
        properties = set().union(*(schemas[name]["properties"] for name in names))
        assert fields_of(cls) == properties, (cls.__name__, names)
    result = schemas["FrameResult"]["properties"]
    assert {t.value for t in Termination} == set(result["termination"]["enum"])
    assert {s.value for s in Status} == set(result["status"]["enum"])


# --- HTTP --------------------------------------------------------------------------------
def test_session_calls(ik: Client) -> None:
    session = ik.create_session(PANDA, options={"time_budget_us": 5000.0})
    assert session.n_dof == 7 == len(session.dof) == len(session.pose.q)
    assert [e.name for e in session.effectors] == ["tool"]
    assert session.options.time_budget_us == 5000.0

    info = ik.patch_session(session, {"max_restarts": 3})
    assert info.options.max_restarts == 3
    assert info.options.time_budget_us == 5000.0  # left out: unchanged

    first = session.dof[0].name
    pose = ik.set_pose(session, joints={first: 0.25})
    assert pose.joints[first] == pytest.approx(0.25) and pose.clipped == []
    assert ik.set_pose(session, joints={first: 100.0}).clipped == [first]  # past its limit
    inside = [0.3 * d.lower + 0.7 * d.upper for d in session.dof if d.lower and d.upper]
    assert len(inside) == 7
    pose = ik.set_pose(session, q=inside)
    assert pose.q == pytest.approx(inside, rel=0, abs=1e-12)
    assert ik.get_session(session).pose.q == pytest.approx(inside, rel=0, abs=1e-12)

    ik.delete_session(session)
    with pytest.raises(NotFound) as caught:
        ik.get_session(session)
    assert caught.value.code is ErrorCode.NOT_FOUND
    assert caught.value.status_code == 404


def test_frames_clips_and_planned_clips(ik: Client, session: Session) -> None:
    full = ik.frame(session, [tool(0.1)], id=7)
    assert_solved(full)
    assert full.id == 7
    assert full.joints is not None and list(full.joints) == [d.name for d in session.dof]
    assert full.effectors is not None and full.effectors[0].within_tolerance

    compact = ik.frame(session, [tool(0.12)], compact=True)
    assert_solved(compact)
    assert compact.id is None and compact.joints is None and compact.effectors is None

    frames: list[Any] = [{"id": i, "targets": [tool(0.1 + 0.01 * i)]} for i in range(4)]
    clip = ik.clip(session, frames)
    assert clip.success and clip.plan is None
    assert [r.id for r in clip.results] == [0, 1, 2, 3]

    planned = ik.clip(session, frames, plan=True, compact=True)
    assert planned.success and planned.plan is not None
    assert planned.plan.candidates > 0
    assert planned.plan.largest_step_rad <= planned.plan.tracked_largest_step_rad + 1e-9
    assert ik.get_session(session).counters.frames == 2 + 4 + 4


def test_batch_answers_each_entry(ik: Client) -> None:
    """One request for several sessions: each entry's result, or its own error."""
    a, b = ik.create_session(PANDA), ik.create_session(PANDA)
    frames: list[ik_client.BatchFrame] = [
        {"session": a.id, "token": a.token, "id": 1, "targets": [tool(0.1)]},
        {"session": b.id, "token": "not-its-token", "id": 2, "targets": [tool(0.1)]},
        {"session": b.id, "token": b.token, "id": 3, "targets": [tool(0.12)]},
    ]
    first, wrong, third = ik.batch(frames)
    assert (first.session, first.id, third.session, third.id) == (a.id, 1, b.id, 3)
    assert first.result is not None and third.result is not None
    assert_solved(first.result)
    assert_solved(third.result)
    assert wrong.result is None and isinstance(wrong.error, AuthError)
    assert wrong.error.code is ErrorCode.FORBIDDEN and not wrong.success
    assert ik.get_session(a).pose.q == pytest.approx(first.result.q, rel=0, abs=1e-12)


def test_one_shot_solve(ik: Client) -> None:
    result = ik.solve(PANDA, [tool(0.1)], seed={"q": [0.0] * 7}, id=3)
    assert_solved(result)
    assert result.id == 3 and len(result.q) == 7


def test_bones_conventions_and_fk_over_http(ik: Client) -> None:
    """What a game client asks of HTTP: a frame's bone output, a one-shot solve in an
    engine's conventions, and forward kinematics of a pose (docs/engines.md). A point
    FK gives in Unreal's axes and centimetres is solved back to, in the same terms."""
    from schemas.chain import EXAMPLE_GLTF_LEG

    unreal: ik_client.Conventions = {"preset": "unreal"}
    session = ik.create_session(EXAMPLE_GLTF_LEG, conventions=unreal)
    try:
        start = ik.get_session(session).pose.q
        near = ik.fk(session, joints={"hip.x": 0.05, "knee.x": 1.25}, bones={"world": ["ankle"]})
        assert ik.get_session(session).pose.q == start  # FK leaves the pose alone
        assert near.q != start and set(near.bones) == {"world"}
        ankle = near.bones["world"]["ankle"]["position"]
        foot: Target = {"effector": "foot", "position": ankle}
        asked = ik.frame(session, [foot], bones={"world": ["ankle"], "local_rotations": True})
        plain = ik.frame(session, [foot])
        here = ik.fk(session)  # the session's pose, local rotations by default
    finally:
        ik.delete_session(session)
    assert asked.success and plain.bones is None and asked.bones is not None
    got = asked.bones["world"]["ankle"]["position"]
    # Centimetres: the 1e-4 m tolerance is 0.01 of a unit.
    assert [got[k] for k in "xyz"] == pytest.approx([ankle[k] for k in "xyz"], abs=0.02)
    assert set(asked.bones["local"]) >= {"hip", "knee"} and set(here.bones) == {"local"}
    assert here.q == pytest.approx(plain.q, abs=1e-12)
    one_shot = ik.solve(EXAMPLE_GLTF_LEG, [foot], conventions=unreal, bones={"world": ["ankle"]})
    assert one_shot.success and one_shot.bones is not None
    got = one_shot.bones["world"]["ankle"]["position"]
    assert [got[k] for k in "xyz"] == pytest.approx([ankle[k] for k in "xyz"], abs=0.02)


@pytest.mark.parametrize("encoding", list(Encoding))
def test_fk_of_an_arm_gives_its_tool_over_http_and_stream(ik: Client, encoding: Encoding) -> None:
    """A robotics session (no bones): FK answers the tool's world pose, the same over
    HTTP and the stream; a target set to it is where the tool already is; bone data is
    refused, naming the field."""
    session = ik.create_session(PANDA)
    try:
        over_http = ik.fk(session, joints={"joint4": -2.0})
        with ik.stream(session, encoding=encoding) as stream:
            streamed = stream.fk(joints={"joint4": -2.0})
            (pose,) = over_http.effectors
            target: Target = {
                "effector": pose.name,
                "position": pose.position,
                "orientation": pose.orientation,
            }
            solved = stream.frame([target])
            here = stream.fk()
            with pytest.raises(InvalidRequest) as caught:
                stream.fk(bones={"local_rotations": True})
        with pytest.raises(InvalidRequest) as over_http_caught:
            ik.fk(session, bones={"local_rotations": True})
    finally:
        ik.delete_session(session)
    assert over_http.bones is None and streamed == over_http
    assert [e.name for e in over_http.effectors] == ["tool"] and pose.direction is None
    assert solved.success
    reached = here.effectors[0].position
    assert [reached[k] for k in "xyz"] == pytest.approx([pose.position[k] for k in "xyz"], abs=1e-3)
    assert caught.value.field == "bones" and over_http_caught.value.field == "bones"


def test_errors_carry_code_and_field(ik: Client, session: Session) -> None:
    with pytest.raises(InvalidRequest) as schema:
        ik.create_session({"format": "example", "name": "no_such_arm"})
    assert schema.value.code is ErrorCode.INVALID_FORMAT
    assert schema.value.field == "chain.name"
    assert schema.value.status_code == 422

    with pytest.raises(InvalidRequest) as problem:
        ik.frame(session, [{"effector": "claw", "position": {"x": 0.4, "y": 0.1, "z": 0.5}}])
    assert problem.value.code is ErrorCode.INVALID_PROBLEM
    assert problem.value.field == "targets[0].effector"

    stranger = dataclasses.replace(session, token="not-the-token")
    with pytest.raises(AuthError) as auth:
        ik.get_session(stranger)
    assert auth.value.code is ErrorCode.FORBIDDEN and auth.value.status_code == 403


def test_retry_after_from_a_rate_limit(start_server: Callable[..., Server]) -> None:
    # A burst of 3 frames (the clip limit), then 1 frame per second.
    limited = start_server(IK_MAX_FRAMES_PER_S="1", IK_MAX_FRAMES_PER_REQUEST="3")
    with Client(limited.base) as ik:
        session = ik.create_session(PANDA)
        frames: list[Any] = [{"targets": [tool(0.1)]}] * 3
        ik.clip(session, frames)
        with pytest.raises(RetryLater) as caught:
            ik.clip(session, frames)
        with ik.stream(session) as stream, pytest.raises(RetryLater) as over_ws:
            stream.frame([tool(0.1)])
    assert caught.value.code is ErrorCode.RATE_LIMITED and caught.value.status_code == 429
    assert caught.value.retry_after_s is not None and caught.value.retry_after_s >= 1
    assert over_ws.value.code is ErrorCode.RATE_LIMITED and over_ws.value.id == 0
    assert over_ws.value.retry_after_s is not None and over_ws.value.retry_after_s > 0


@pytest.mark.parametrize("encoding", list(Encoding))
def test_frames_and_batch_entries_carry_an_animated_pose(ik: Client, encoding: Encoding) -> None:
    """``pose`` on a frame (HTTP, the stream, sync and async) and on a batch entry: the
    frame starts from it (a target met there: answered as it is, a step of ~0)."""
    session = ik.create_session(PANDA, options={"time_budget_us": 50_000})
    animated = [0.1, -0.2, 0.05, -1.9, 0.1, 1.8, 0.6]
    at = ik.fk(session, q=animated).effectors[0]
    target: Target = {"effector": "tool", "position": at.position, "orientation": at.orientation}
    assert ik.frame(session, [tool(0.1)]).q != pytest.approx(animated, abs=1e-3)

    def from_animated(result: FrameResult) -> None:
        assert result.q == pytest.approx(animated, rel=0, abs=1e-6)
        assert result.largest_step_rad is not None and result.largest_step_rad < 1e-6

    from_animated(ik.frame(session, [target], pose={"q": animated}))
    # joints: the DOF named takes the animated value, the others keep the answer's.
    now = ik.frame(session, [tool(0.1)]).q
    start = [0.5, *now[1:]]
    there = ik.fk(session, q=start).effectors[0]
    near: Target = {
        "effector": "tool",
        "position": there.position,
        "orientation": there.orientation,
    }
    partial = ik.frame(session, [near], pose={"joints": {session.dof[0].name: 0.5}})
    assert partial.q == pytest.approx(start, rel=0, abs=1e-6)
    with ik.stream(session, encoding=encoding) as stream:
        stream.frame([tool(0.1)])
        from_animated(stream.frame([target], pose={"q": animated}))
    ik.frame(session, [tool(0.1)])
    entry: ik_client.BatchFrame = {
        "session": session.id,
        "token": session.token,
        "targets": [target],
        "pose": {"q": animated},
    }
    (answer,) = ik.batch([entry])
    assert answer.result is not None
    from_animated(answer.result)

    async def run() -> list[FrameResult]:
        async with AsyncClient(ik.base_url) as aik:
            await aik.frame(session, [tool(0.1)])
            out = [await aik.frame(session, [target], pose={"q": animated})]
            async with aik.stream(session, encoding=encoding) as stream:
                await stream.frame([tool(0.1)])
                out.append(await stream.frame([target], pose={"q": animated}))
            return out

    for result in asyncio.run(run()):
        from_animated(result)


def test_async_client_calls(server: Server) -> None:
    async def run() -> None:
        async with AsyncClient(server.base) as ik:
            session = await ik.create_session(PANDA)
            assert (await ik.patch_session(session, {"max_iter": 50})).options.max_iter == 50
            first = session.dof[0].name
            assert (await ik.set_pose(session, joints={first: 0.0})).joints[first] == 0.0
            assert_solved(await ik.frame(session, [tool(0.1)]))
            frames: list[Any] = [{"targets": [tool(0.1)]}, {"targets": [tool(0.11)]}]
            assert (await ik.clip(session, frames, plan=True)).plan is not None
            assert_solved(await ik.solve(PANDA, [tool(0.1)]))
            assert (await ik.get_session(session)).counters.frames == 3
            await ik.delete_session(session)
            with pytest.raises(NotFound):
                await ik.get_session(session)

    asyncio.run(run())


# --- the stream ---------------------------------------------------------------------------
@pytest.mark.parametrize("encoding", list(Encoding))
def test_stream_frame_asks_for_bones_per_frame(ik: Client, encoding: Encoding) -> None:
    """``bones`` on one frame overrides the session's bone output (none by default) for
    that frame only (docs/websocket.md, the frame message)."""
    from schemas.chain import EXAMPLE_GLTF_LEG

    session = ik.create_session(EXAMPLE_GLTF_LEG)
    foot: Target = {"effector": "foot", "position": {"x": 0.0, "y": 0.5, "z": 0.1}}
    try:
        with ik.stream(session, encoding=encoding) as stream:
            plain = stream.frame([foot])
            with_bones = stream.frame([foot], bones={"local_rotations": True})
            after = stream.frame([foot])
    finally:
        ik.delete_session(session)
    assert plain.bones is None and after.bones is None
    assert with_bones.bones is not None and "knee" in with_bones.bones["local"]


@pytest.mark.parametrize("encoding", list(Encoding))
def test_stream_fk_is_http_fk_and_leaves_the_pose(ik: Client, encoding: Encoding) -> None:
    """The WebSocket's ``fk`` message answers what ``POST .../fk`` does, in order with
    the frames around it, and does not move the stream."""
    from schemas.chain import EXAMPLE_GLTF_LEG

    session = ik.create_session(EXAMPLE_GLTF_LEG, conventions={"preset": "unity"})
    foot: Target = {"effector": "foot", "position": {"x": 0.0, "y": 0.5, "z": 0.1}}
    asked: ik_client.BoneOutput = {"world": ["ankle"], "local_rotations": True}
    try:
        with ik.stream(session, encoding=encoding) as stream:
            before = stream.frame([foot])
            bent = stream.fk(joints={"knee.x": 0.5}, bones=asked)
            here = stream.fk()
            over_http = ik.fk(session, joints={"knee.x": 0.5}, bones=asked)
            after = stream.frame([foot])
    finally:
        ik.delete_session(session)
    assert bent.q == pytest.approx(over_http.q, abs=1e-12)
    got, want = (
        bent.bones["world"]["ankle"]["position"],
        over_http.bones["world"]["ankle"]["position"],
    )
    assert [got[k] for k in "xyz"] == pytest.approx([want[k] for k in "xyz"], abs=1e-9)
    assert here.q == pytest.approx(before.q, abs=1e-12) and set(here.bones) == {"local"}
    # fk did not move the stream: the next frame starts where the last answer was (a
    # move to the fk pose would step the 0.1 rad limit; the null-space step is 0.005).
    assert after.largest_step_rad is not None and after.largest_step_rad < 0.05


@pytest.mark.parametrize("encoding", list(Encoding))
def test_stream_pipelines_in_order(ik: Client, session: Session, encoding: Encoding) -> None:
    with ik.stream(session, encoding=encoding) as stream:
        ids = [stream.send_frame([tool(0.1 + 0.002 * i)]) for i in range(20)]
        assert ids == list(range(20))
        answers = [stream.receive() for _ in ids]
        assert [a.id for a in answers] == ids
        assert all(isinstance(a, FrameAnswer) and a.result.id == a.id for a in answers)
        # The envelope's success, kept: the frame's own.
        assert all(isinstance(a, FrameAnswer) and a.success == a.result.success for a in answers)
        assert sum(a.result.success for a in answers if isinstance(a, FrameAnswer)) >= 19

        clip_id = stream.send_clip([{"id": 5, "targets": [tool(0.12)]}], plan=True)
        ping_id = stream.send_ping()
        clip, pong = stream.receive(), stream.receive()
        assert isinstance(clip, ClipAnswer) and clip.id == clip_id == 20
        assert clip.clip.plan is not None and clip.clip.results[0].id == 5
        assert isinstance(pong, Pong) and pong.id == ping_id == 21
        assert stream.in_flight == 0


@pytest.mark.parametrize("encoding", list(Encoding))
def test_stream_error_answer_then_next_frame(
    ik: Client, session: Session, encoding: Encoding
) -> None:
    with ik.stream(session, encoding=encoding, compact=True) as stream:
        stream.send_frame([{"effector": "claw", "position": {"x": 0.4, "y": 0.1, "z": 0.5}}])
        stream.send_frame([{"effector": "tool"}])  # type: ignore[typeddict-item]
        with pytest.raises(InvalidRequest) as problem:
            stream.receive()
        assert problem.value.code is ErrorCode.INVALID_PROBLEM
        assert problem.value.field == "targets[0].effector" and problem.value.id == 0
        with pytest.raises(InvalidRequest) as schema:
            stream.receive()
        assert schema.value.code is ErrorCode.INVALID_FORMAT and schema.value.id == 1
        assert schema.value.field == "frame.targets[0]"
        result = stream.frame([tool(0.1)])
        assert_solved(result)
        assert result.id == 2 and result.joints is None  # compact


@pytest.fixture
def nobody_listens() -> str:
    """The URL of a port on 127.0.0.1 nothing listens on (bound, then closed)."""
    with socket.create_server(("127.0.0.1", 0)) as probe:
        port = probe.getsockname()[1]
    return f"http://127.0.0.1:{port}"


def _answer_upgrades_with_502() -> tuple[str, socket.socket]:
    """A server that answers every request, the WebSocket upgrade too, with a 502 (a
    balancer without a live worker)."""
    listener = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = listener.accept()
                with conn:
                    conn.recv(65536)
                    conn.sendall(b"HTTP/1.1 502 Bad Gateway\r\nContent-Length: 0\r\n\r\n")

    threading.Thread(target=serve, daemon=True).start()
    return f"http://127.0.0.1:{listener.getsockname()[1]}", listener


def test_a_stream_that_cannot_open_raises_connection_lost(nobody_listens: str) -> None:
    """Opening a stream to a server that is down (restarting) or behind a balancer that
    refuses the upgrade raises a ``StreamClosed`` (``ConnectionLost``, an
    ``IKClientError``) with the transport's error as its cause, as every other stream
    failure is, not websockets' or the OS's own exception (which a game server catching
    ``IKClientError`` to recreate its stream did not catch)."""
    fake = dataclasses.make_dataclass("Ref", ["id", "token"])("some-session", "t")
    with Client(nobody_listens) as ik, pytest.raises(ConnectionLost) as refused:
        with ik.stream(fake):
            pass
    assert refused.value.close_code == 1006
    assert isinstance(refused.value.__cause__, OSError)
    assert "could not open" in str(refused.value)

    base, listener = _answer_upgrades_with_502()
    try:
        with Client(base) as ik, pytest.raises(ConnectionLost) as bad_gateway:
            with ik.stream(fake):
                pass
        assert "502" in str(bad_gateway.value.__cause__)

        async def open_async(url: str) -> None:
            async with AsyncClient(url) as aik, aik.stream(fake):
                pass

        for url in (nobody_listens, base):
            with pytest.raises(ConnectionLost):
                asyncio.run(open_async(url))
    finally:
        listener.close()


def test_stream_close_codes(ik: Client, session: Session) -> None:
    stranger = dataclasses.replace(session, token="not-the-token")
    with ik.stream(stranger) as stream, pytest.raises(StreamAuthError) as auth:
        stream.ping()
    assert auth.value.close_code == 4403 and "token" in auth.value.meaning
    assert auth.value.reason == ErrorCode.FORBIDDEN

    gone = ik.create_session(PANDA)
    ik.delete_session(gone)
    with ik.stream(gone) as stream, pytest.raises(SessionGone) as missing:
        stream.ping()
    assert missing.value.close_code == 4404 and missing.value.reason == ErrorCode.NOT_FOUND
    # The code a caller matches over HTTP (NotFound.code), on the stream's error too.
    assert missing.value.code == ErrorCode.NOT_FOUND


def test_too_many_websockets_after_bounded_retries(start_server: Callable[..., Server]) -> None:
    small = start_server(IK_MAX_WEBSOCKETS="1")
    with Client(small.base) as ik:
        session = ik.create_session(PANDA)
        retry = Reconnect(attempts=2, initial_delay_s=0.01)
        with ik.stream(session) as first, ik.stream(session, reconnect=retry) as second:
            assert isinstance(first.ping(), Pong)
            with pytest.raises(TooManyWebSockets) as caught:
                second.ping()
            assert caught.value.close_code == 1013
            # Each retry is accepted and closed again (at the resend or at the next read):
            # no more than the two allowed.
            assert second.reconnects <= 2


@pytest.mark.parametrize("encoding", list(Encoding))
def test_stream_batches_pipelined_in_order(ik: Client, encoding: Encoding) -> None:
    """``batch`` messages on one session's socket: one answer per batch, in order, one
    entry per frame, an entry's error in that entry."""
    a, b = ik.create_session(PANDA), ik.create_session(PANDA)

    def entries(k: int) -> list[ik_client.BatchFrame]:
        return [
            {"session": a.id, "token": a.token, "id": k, "targets": [tool(0.1 + 0.002 * k)]},
            {"session": b.id, "token": b.token, "id": k, "targets": [tool(0.12)]},
        ]

    with ik.stream(a, encoding=encoding, compact=True) as stream:
        ids = [stream.send_batch(entries(k)) for k in range(5)]
        answers = [stream.receive() for _ in ids]
        assert [x.id for x in answers] == ids == list(range(5))
        for k, answer in enumerate(answers):
            assert isinstance(answer, BatchAnswer) and len(answer.results) == 2
            # The envelope's success: every entry's.
            assert answer.success == all(
                e.result is not None and e.result.success for e in answer.results
            )
            assert [(e.session, e.id) for e in answer.results] == [(a.id, k), (b.id, k)]
            assert all(e.result is not None and e.result.joints is None for e in answer.results)
        wrong = entries(5)
        wrong[1]["token"] = "not-its-token"
        first, refused = stream.batch(wrong)
        assert first.result is not None and first.error is None
        assert refused.result is None and isinstance(refused.error, AuthError)


def test_async_stream_batch(server: Server) -> None:
    async def run() -> list[ik_client.BatchEntryResult]:
        async with AsyncClient(server.base) as ik:
            a = await ik.create_session(PANDA)
            frame: ik_client.BatchFrame = {
                "session": a.id,
                "token": a.token,
                "targets": [tool(0.1)],
            }
            async with ik.stream(a) as stream:
                return await stream.batch([frame])

    (entry,) = asyncio.run(run())
    assert entry.result is not None
    assert_solved(entry.result)


@pytest.mark.parametrize("codec", ["orjson", "json"])
def test_json_with_or_without_orjson(
    ik: Client, session: Session, codec: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Messages are written and answers read with orjson when it is installed
    (ik-client[fast]), else json: the same typed answers either way, and NaN refused
    before it is sent, counting as nothing sent."""
    if codec == "json":
        monkeypatch.setattr("ik_client.encoding._loads", json.loads)
        monkeypatch.setattr("ik_client.encoding._orjson_dumps", None)
    nan: Target = {"effector": "tool", "position": {"x": float("nan"), "y": 0.1, "z": 0.5}}
    with ik.stream(session) as stream:
        result = stream.frame([tool(0.1)])
        with pytest.raises(ValueError):
            stream.send_frame([nan])
        assert stream.in_flight == 0
        with pytest.raises(InvalidRequest) as error:
            stream.frame([{"effector": "claw", "position": {"x": 0.4, "y": 0.1, "z": 0.5}}])
    assert_solved(result)
    assert result.joints is not None and result.effectors is not None
    assert error.value.code is ErrorCode.INVALID_PROBLEM and error.value.id == 1


@dataclasses.dataclass
class Point:
    x: float
    y: float
    z: float


@pytest.mark.parametrize("codec", ["orjson", "json"])
@pytest.mark.parametrize(
    "position", [Point(0.4, 0.1, 0.5), datetime.datetime(2026, 1, 1)], ids=["dataclass", "datetime"]
)
def test_json_refuses_the_same_with_or_without_orjson(
    ik: Client, session: Session, codec: str, position: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    """orjson writes dataclasses and datetimes, json does not: refused either way
    (TypeError), before anything is sent."""
    if codec == "json":
        monkeypatch.setattr("ik_client.encoding._orjson_dumps", None)
    target: Any = {"effector": "tool", "position": position}
    with ik.stream(session) as stream:
        with pytest.raises(TypeError):
            stream.send_frame([target])
        assert stream.in_flight == 0
        result = stream.frame([tool(0.1)])
    assert_solved(result)
    assert result.id == 0


class Side(enum.Enum):
    TOOL = "tool"


CODECS = ["orjson", "json", "msgpack"]
CYCLE: list[object] = []
CYCLE.append(CYCLE)


def pipeline(codec: str, monkeypatch: pytest.MonkeyPatch) -> ik_client.stream.pipeline.Pipeline:
    """A stream's encoder (no I/O): orjson, json (orjson not installed) or msgpack."""
    if codec == "json":
        monkeypatch.setattr("ik_client.encoding._orjson_dumps", None)
    return ik_client.stream.pipeline.Pipeline(
        Encoding.MSGPACK if codec == "msgpack" else Encoding.JSON
    )


@pytest.mark.parametrize("codec", CODECS)
def test_uuids_and_enums_written_alike(codec: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """orjson writes a UUID as its string and an enum member as its value; json and
    msgpack, which would refuse them, write them so too: one message whichever writes."""
    body = {"type": "frame", "targets": [{"effector": Side.TOOL}], "tag": uuid.UUID(int=7)}
    _, data = pipeline(codec, monkeypatch).add(body)
    decoded = msgpack.unpackb(data) if isinstance(data, bytes) else json.loads(data)
    assert decoded == {
        "type": "frame",
        "targets": [{"effector": "tool"}],
        "tag": "00000000-0000-0000-0000-000000000007",
        "id": 0,
    }


@pytest.mark.parametrize("codec", CODECS)
@pytest.mark.parametrize(
    "value",
    [Point(0.4, 0.1, 0.5), datetime.datetime(2026, 1, 1), CYCLE, float("nan")],
    ids=["dataclass", "datetime", "cycle", "nan"],
)
def test_encode_errors_are_encode_error(
    codec: str, value: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What cannot be written raises EncodeError (an IKClientError, and the ValueError and
    TypeError the encoders raised), the encoder's error as its cause; nothing counted."""
    stream = pipeline(codec, monkeypatch)
    body = {"type": "frame", "targets": [{"effector": "tool", "position_weight": value}]}
    with pytest.raises(EncodeError) as error:
        stream.add(body)
    assert isinstance(error.value, IKClientError) and isinstance(error.value, ValueError)
    assert isinstance(error.value, TypeError)
    if value != value:  # NaN
        assert error.value.field == "targets[0].position_weight"
    else:
        assert error.value.field is None and error.value.__cause__ is not None
    assert stream.in_flight == 0 and stream.add({"type": "ping"})[0] == 0


def test_http_calls_refuse_what_a_stream_refuses(ik: Client, session: Session) -> None:
    """The HTTP calls write their bodies as a stream writes its messages: NaN and
    infinity are an EncodeError naming the field, a value JSON cannot hold one with the
    encoder's error as its cause, raised before anything is sent; the session answers
    the next frame as before."""
    nan: Target = {"effector": "tool", "position": {"x": float("nan"), "y": 0.1, "z": 0.5}}
    with pytest.raises(EncodeError, match=r"^targets\[0\]\.position\.x is nan: ") as error:
        ik.frame(session, [nan])
    assert error.value.field == "targets[0].position.x" and isinstance(error.value, ValueError)
    with pytest.raises(EncodeError, match=r"^seed\.q\[1\] is inf: "):
        ik.solve(PANDA, [tool(0.1)], seed={"q": [0.0, float("inf")] + [0.0] * 5})
    with pytest.raises(EncodeError, match="cannot be written as JSON") as error:
        ik.frame(session, [{**tool(0.1), "position_weight": object()}])  # type: ignore[typeddict-item]
    assert isinstance(error.value.__cause__, TypeError)
    assert_solved(ik.frame(session, [tool(0.1)]))


@pytest.mark.parametrize("encoding", list(Encoding))
def test_non_finite_numbers_refused_alike(ik: Client, session: Session, encoding: Encoding) -> None:
    """NaN and infinity, in a frame or a clip, in any encoding: the same ValueError
    naming the field, before anything is sent (MessagePack could carry them)."""
    far: Target = {**tool(0.1), "position_weight": float("inf")}
    nan: Target = {"effector": "tool", "position": {"x": float("nan"), "y": 0.1, "z": 0.5}}
    with ik.stream(session, encoding=encoding) as stream:
        with pytest.raises(EncodeError, match=r"^targets\[0\]\.position\.x is nan: ") as error:
            stream.send_frame([nan])
        assert error.value.field == "targets[0].position.x"
        assert isinstance(error.value, ValueError)
        with pytest.raises(
            ValueError, match=r"^frames\[1\]\.targets\[0\]\.position_weight is inf: "
        ):
            stream.send_clip([{"targets": [tool(0.1)]}, {"targets": [far]}])
        assert stream.in_flight == 0
        result = stream.frame([tool(0.1)])
    assert_solved(result)
    assert result.id == 0


def test_stream_without_deflate(ik: Client, session: Session) -> None:
    """websockets offers permessage-deflate, which the server accepts; ``deflate=False``
    sends messages as they are."""
    with ik.stream(session) as offered, ik.stream(session, deflate=False) as plain:
        assert [e.name for e in offered.connection.protocol.extensions] == ["permessage-deflate"]
        assert plain.connection.protocol.extensions == []
        assert_solved(plain.frame([tool(0.1)]))


def test_stream_keepalive_pings(ik: Client, session: Session) -> None:
    """``ping_interval_s``: websockets' keepalive pings, whose pongs measure
    ``latency``; None sends none (loadtest's clients), through a reconnect too."""
    with (
        ik.stream(session, ping_interval_s=0.05) as pinging,
        ik.stream(session, ping_interval_s=None) as quiet,
    ):
        deadline = time.monotonic() + 10.0
        while pinging.connection.latency == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert pinging.connection.latency > 0  # a pong came back
        assert quiet.connection.latency == 0  # the same time, and no ping
        quiet.connection.socket.shutdown(socket.SHUT_RDWR)
        assert_solved(quiet.frame([tool(0.1)]))
        assert quiet.reconnects == 1 and quiet.connection.ping_interval is None


def test_async_stream_keepalive_pings(server: Server, session: Session) -> None:
    async def run() -> tuple[float | None, float | None]:
        async with AsyncClient(server.base) as ik:
            async with ik.stream(session, ping_interval_s=None, ping_timeout_s=None) as s:
                return s.connection.ping_interval, s.connection.ping_timeout

    assert asyncio.run(run()) == (None, None)


def sticky_session(server: Server) -> tuple[socket.socket, Session]:
    """A session created on a keep-alive connection, and that connection."""
    sock = socket.create_connection(("127.0.0.1", server.port), timeout=30.0)
    body = b'{"chain": {"format": "example", "name": "panda_arm"}}'
    sock.sendall(
        b"POST /v1/sessions HTTP/1.1\r\nHost: 127.0.0.1\r\ncontent-type: application/json\r\n"
        b"content-length: %d\r\n\r\n%s" % (len(body), body)
    )
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(65536)
    head, _, rest = response.partition(b"\r\n\r\n")
    length = int(
        next(h for h in head.split(b"\r\n") if h.lower().startswith(b"content-length")).split(b":")[
            1
        ]
    )
    while len(rest) < length:
        rest += sock.recv(65536)
    assert head.startswith(b"HTTP/1.1 201")
    return sock, Session.from_json(json.loads(rest))


def test_stream_on_a_given_socket(server: Server, ik: Client) -> None:
    """``sock``: the first handshake goes over the connection given (here the one that
    created the session); a reconnect opens a new one."""
    sock, session = sticky_session(server)
    with ik.stream(session, sock=sock) as stream:
        assert stream.connection.socket is sock
        assert_solved(stream.frame([tool(0.1)]))
        sock.shutdown(socket.SHUT_RDWR)
        assert_solved(stream.frame([tool(0.11)]))
        assert stream.reconnects == 1 and stream.connection.socket is not sock


def test_async_stream_on_a_given_socket(server: Server) -> None:
    sock, session = sticky_session(server)

    async def run() -> FrameResult:
        async with AsyncClient(server.base) as ik:
            async with ik.stream(session, sock=sock, deflate=False) as stream:
                assert (
                    stream.connection.transport.get_extra_info("socket").fileno() == sock.fileno()
                )
                return await stream.frame([tool(0.1)])

    assert_solved(asyncio.run(run()))


def test_answers_the_client_cannot_read() -> None:
    """A server that echoes (loadtest.floors) or answers an id nothing waits for: an
    ``UnexpectedAnswer`` naming the message answered, and the stream goes on."""

    async def echo(ws: ServerConnection) -> None:
        async for message in ws:
            await ws.send(message)  # the frame itself: a type the client does not read
            await ws.send('{"id": 99, "type": "pong"}')  # an id nothing waits for

    async def run() -> tuple[UnexpectedAnswer, UnexpectedAnswer, int]:
        async with serve(echo, "127.0.0.1", 0) as server:
            port = server.sockets[0].getsockname()[1]
            async with AsyncClient(f"http://127.0.0.1:{port}") as ik:
                ref = dataclasses.make_dataclass("Ref", ["id", "token"])("s", "t")
                async with ik.stream(ref, reconnect=Reconnect(attempts=0)) as stream:
                    sent = await stream.send_frame([tool(0.1)])
                    with pytest.raises(UnexpectedAnswer) as echoed:
                        await stream.receive()
                    with pytest.raises(UnexpectedAnswer) as unknown:
                        await stream.receive()
                    assert stream.in_flight == 0
                    return echoed.value, unknown.value, sent

    echoed, unknown, sent = asyncio.run(asyncio.wait_for(run(), 30.0))
    assert echoed.id == sent == 0 and echoed.envelope["type"] == "frame"
    assert unknown.id is None and unknown.envelope == {"id": 99, "type": "pong"}


def test_a_garbled_answer_is_unexpected_and_the_stream_goes_on() -> None:
    """Answers that are not JSON, not an object, not MessagePack: each an
    ``UnexpectedAnswer`` with the data as received; the message still waits for its own."""
    garbled: list[str | bytes] = ["not json{", "[1, 2]", b"\xc1"]  # 0xc1: never MessagePack

    async def answer(ws: ServerConnection) -> None:
        async for _ in ws:
            for data in garbled:
                await ws.send(data)
            await ws.send('{"id": 0, "type": "pong"}')

    async def run() -> tuple[list[UnexpectedAnswer], int]:
        async with serve(answer, "127.0.0.1", 0) as server:
            port = server.sockets[0].getsockname()[1]
            async with AsyncClient(f"http://127.0.0.1:{port}") as ik:
                ref = dataclasses.make_dataclass("Ref", ["id", "token"])("s", "t")
                async with ik.stream(ref, reconnect=Reconnect(attempts=0)) as stream:
                    await stream.send_ping()
                    seen = []
                    for _ in garbled:
                        with pytest.raises(UnexpectedAnswer) as e:
                            await stream.receive()
                        seen.append(e.value)
                    in_flight = stream.in_flight
                    await stream.receive()  # the ping's own answer
                    return seen, in_flight

    seen, in_flight = asyncio.run(asyncio.wait_for(run(), 30.0))
    assert [e.data for e in seen] == garbled
    assert all(e.id is None and e.envelope == {} for e in seen)
    assert in_flight == 1


def frames_on_the_server(ik: Client, session: Session) -> int:
    return ik.get_session(session).counters.frames


@pytest.mark.parametrize("encoding", list(Encoding))
def test_stream_reconnects_mid_pipeline(ik: Client, session: Session, encoding: Encoding) -> None:
    """The socket is cut while answers are in flight: every frame gets one answer."""
    with ik.stream(session, encoding=encoding) as stream:
        sent = [stream.send_frame([tool(0.1 + 0.001 * i)]) for i in range(30)]
        received = [stream.receive().id for _ in range(5)]
        in_flight = stream.in_flight
        stream.connection.socket.shutdown(socket.SHUT_RDWR)  # abrupt: no close frame
        sent += [stream.send_frame([tool(0.13)]) for _ in range(10)]
        received += [stream.receive().id for _ in range(len(sent) - 5)]
        assert stream.in_flight == 0
        assert stream.reconnects == 1
    assert in_flight == 25
    assert received == sent == list(range(40))
    # The server solved every frame at least once; those in flight at the cut may twice.
    assert 40 <= frames_on_the_server(ik, session) <= 40 + in_flight


def test_stream_without_reconnects_raises_the_drop(ik: Client, session: Session) -> None:
    with ik.stream(session, reconnect=Reconnect(attempts=0)) as stream:
        # Cut first: an answer the client had already read would be delivered.
        stream.connection.socket.shutdown(socket.SHUT_RDWR)
        with pytest.raises(ConnectionLost) as caught:
            stream.send_frame([tool(0.1)])  # raises here or at the next read
            stream.receive()
    assert caught.value.close_code == 1006 and "dropped" in caught.value.meaning


def test_async_stream_reconnects_mid_pipeline(server: Server, session: Session) -> None:
    async def run() -> tuple[list[int], list[int], int, int]:
        async with AsyncClient(server.base) as ik:
            async with ik.stream(session, encoding=Encoding.MSGPACK) as stream:
                sent = [await stream.send_frame([tool(0.1 + 0.001 * i)]) for i in range(30)]

                async def receive_all() -> list[int]:
                    return [(await stream.receive()).id for _ in range(40)]

                # A reader task and a sender that cuts the socket while answers arrive.
                reader = asyncio.create_task(receive_all())
                await asyncio.sleep(0)
                in_flight = stream.in_flight
                stream.connection.transport.abort()
                sent += [await stream.send_frame([tool(0.13)]) for _ in range(10)]
                received = await asyncio.wait_for(reader, 60.0)
                return sent, received, stream.reconnects, in_flight

    sent, received, reconnects, in_flight = asyncio.run(run())
    assert in_flight > 0
    assert received == sent == list(range(40))
    assert reconnects == 1


def test_resend_is_the_message_as_first_sent(server: Server, session: Session) -> None:
    """A message resent after a drop is the bytes first sent, not the caller's target
    as it is by then: here changed to NaN, which could not be written again (a
    ValueError out of the reconnect), and would be another frame if it could."""

    async def run() -> tuple[ik_client.Answer, ik_client.Answer, int]:
        async with AsyncClient(server.base) as ik:
            async with ik.stream(session) as stream:
                # A planned clip ahead keeps the frame unanswered until the cut.
                await stream.send_clip([{"targets": [tool(0.1)]}] * 20, plan=True)
                target = tool(0.15)
                sent = await stream.send_frame([target])
                target["position"]["y"] = float("nan")  # the caller reuses its dict
                stream.connection.transport.abort()
                clip, frame = await stream.receive(), await stream.receive()
                assert frame.id == sent
                return clip, frame, stream.reconnects

    clip, frame, reconnects = asyncio.run(asyncio.wait_for(run(), 60.0))
    assert reconnects == 1
    assert isinstance(clip, ClipAnswer) and isinstance(frame, FrameAnswer)
    assert_solved(frame.result)


def test_stream_url_and_token_from_session(server: Server, session: Session) -> None:
    with Client(server.base + "/") as ik:
        url = ik.stream(session, compact=True).url
    assert url == f"ws://127.0.0.1:{server.port}/v1/sessions/{session.id}/ws?results=compact"
    # The token travels in a header, never in the URL (proxies log URLs).
    assert session.token not in url
    assert httpx.URL(url).params.get("token") is None


class _DroppingRelay:
    """A TCP relay on 127.0.0.1 in front of the server that closes the next ``drops``
    connections once a request has arrived on them, unanswered (what a client sees of a
    worker killed mid-request behind a balancer), answers the next ``busy`` with a
    balancer's 503 and ``Retry-After: retry_after``, and relays the others."""

    def __init__(self, upstream: str, drops: int) -> None:
        url = httpx.URL(upstream)
        self._upstream = (url.host, url.port)
        self.drops = drops
        self.dropped = 0
        self.busy = 0
        self.retry_after = 0
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.base = f"http://127.0.0.1:{self._listener.getsockname()[1]}"
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                conn, _ = self._listener.accept()
            except OSError:  # closed
                return
            if self.drops > 0:
                self.drops -= 1
                self.dropped += 1  # before the close the client reacts to
                with conn:
                    conn.recv(65536)  # the request, never answered
                continue
            if self.busy > 0:
                self.busy -= 1
                self.dropped += 1
                with conn:
                    conn.recv(65536)
                    conn.sendall(
                        b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\n"
                        b"Retry-After: %d\r\nConnection: close\r\n\r\n" % self.retry_after
                    )
                continue
            threading.Thread(target=self._relay, args=(conn,), daemon=True).start()

    def _relay(self, conn: socket.socket) -> None:
        with conn, socket.create_connection(self._upstream) as upstream:
            back = threading.Thread(target=self._pump, args=(upstream, conn))
            back.start()
            self._pump(conn, upstream)
            back.join()

    @staticmethod
    def _pump(source: socket.socket, sink: socket.socket) -> None:
        with contextlib.suppress(OSError):
            while data := source.recv(65536):
                sink.sendall(data)
        with contextlib.suppress(OSError):
            sink.shutdown(socket.SHUT_WR)

    def close(self) -> None:
        self._listener.close()


def test_a_frame_with_an_id_is_sent_again_after_a_dropped_connection(
    ik: Client, session: Session
) -> None:
    quick = Reconnect(attempts=3, initial_delay_s=0.01)
    relay = _DroppingRelay(ik.base_url, drops=2)
    try:
        with Client(relay.base, reconnect=quick) as through:
            result = through.frame(session, [tool(0.1)], id=7)
        assert relay.dropped == 2 and result.id == 7
        assert ik.get_session(session).counters.frames == 1  # the server saw it once

        async def run() -> FrameResult:
            async with AsyncClient(relay.base, reconnect=quick) as through:
                return await through.frame(session, [tool(0.11)], id=8)

        relay.drops = 1
        assert asyncio.run(run()).id == 8 and relay.dropped == 3

        # Without an id a frame is not sent again (a server could solve it twice), nor
        # with reconnecting off; neither reached the server.
        for client, kwargs in (
            (Client(relay.base, reconnect=quick), {}),
            (Client(relay.base, reconnect=Reconnect(attempts=0)), {"id": 9}),
        ):
            relay.drops = 1
            with client, pytest.raises(NoAnswer):
                client.frame(session, [tool(0.12)], **kwargs)
        assert relay.dropped == 5
        # More drops than attempts: the last error is raised.
        relay.drops = 4
        with Client(relay.base, reconnect=quick) as through, pytest.raises(NoAnswer) as lost:
            through.frame(session, [tool(0.12)], id=10)
        assert relay.dropped == 9
        # One of the client's errors (it was httpx's own), the transport's as its cause.
        assert not lost.value.timed_out and isinstance(lost.value.__cause__, httpx.TransportError)
        # A balancer's 503: sent again after its Retry-After, unless that is longer than
        # the client waits (the caller gets the error at once).
        relay.busy = 2
        with Client(relay.base, reconnect=quick) as through:
            assert through.frame(session, [tool(0.13)], id=11).id == 11
        relay.busy, relay.retry_after = 1, 60
        with (
            Client(relay.base, reconnect=quick) as through,
            pytest.raises(ik_client.ServiceError) as busy,
        ):
            through.frame(session, [tool(0.13)], id=12)
        assert busy.value.status_code == 503 and busy.value.retry_after_s == 60
        assert relay.dropped == 12
        assert ik.get_session(session).counters.frames == 3
    finally:
        relay.close()


def test_a_server_that_never_answers_is_a_timed_out_no_answer() -> None:
    # A listener that accepts and never answers: the client's timeout, as its own error.
    import socket

    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        base = f"http://127.0.0.1:{silent.getsockname()[1]}"
        with Client(base, timeout_s=0.3) as ik, pytest.raises(NoAnswer) as late:
            ik.create_session(PANDA)
    assert late.value.timed_out and isinstance(late.value.__cause__, httpx.TimeoutException)
