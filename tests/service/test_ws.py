"""WebSocket protocol over the TestClient: order, ids, encodings, errors, closes."""

from __future__ import annotations

import asyncio
import json
import types
from collections.abc import Callable
from typing import Any

import msgpack
import pytest
from pydantic import TypeAdapter
from starlette.testclient import TestClient
from starlette.websockets import WebSocket, WebSocketDisconnect

import schemas as S
from service.config import Settings
from service.routes import ws as ws_mod

from .helpers import Created, create, hand_frame

SERVER_MESSAGE: TypeAdapter[Any] = TypeAdapter(S.ServerMessage)


def frame_msg(frame_id: int, **pos: float) -> dict[str, Any]:
    return {"type": "frame", "id": frame_id, **hand_frame(None, **pos)}


def url(s: Created) -> str:
    return f"/v1/sessions/{s.id}/ws"


def test_json_frames_answered_in_order_with_ids(client: TestClient, session: Created) -> None:
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ids = [3, 4, 10, 11, 12]
        for i, fid in enumerate(ids):
            ws.send_text(json.dumps(frame_msg(fid, y=0.1 + 0.01 * i)))
        replies = [SERVER_MESSAGE.validate_python(ws.receive_json()) for _ in ids]
    assert [r.id for r in replies] == ids
    assert all(isinstance(r, S.ResultMessage) and r.success for r in replies)
    assert all(r.result.id == r.id and r.result.server_us > 0 for r in replies)


def test_msgpack_frames_get_msgpack_answers(client: TestClient, session: Created) -> None:
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        for fid in (1, 2):
            ws.send_bytes(msgpack.packb(frame_msg(fid)))
        replies = [msgpack.unpackb(ws.receive_bytes()) for _ in range(2)]
        ws.send_bytes(msgpack.packb({"type": "ping", "id": 3}))
        pong = msgpack.unpackb(ws.receive_bytes())
    assert [r["id"] for r in replies] == [1, 2]
    assert all(S.ResultMessage.model_validate(r).result.success for r in replies)
    assert pong == {"id": 3, "type": "pong"}


def test_token_as_query_parameter(client: TestClient, session: Created) -> None:
    with client.websocket_connect(f"{url(session)}?token={session.token}") as ws:
        ws.send_json({"type": "ping", "id": 0})
        assert ws.receive_json() == {"id": 0, "type": "pong"}


@pytest.mark.parametrize(
    ("bad", "code"),
    [
        ("this is not json", "invalid_format"),
        (json.dumps({"type": "frame", "id": 5}), "invalid_format"),
        (json.dumps({"type": "dance", "id": 5}), "invalid_format"),
        (json.dumps({**frame_msg(5), "extra": 1}), "invalid_format"),
        (
            json.dumps(
                {
                    "type": "frame",
                    "id": 5,
                    "targets": [{"effector": "foot", "position": {"x": 0, "y": 0, "z": 0}}],
                }
            ),
            "invalid_problem",
        ),
        (b"\xc1\xc1 not msgpack", "invalid_format"),
        (
            msgpack.packb(
                {
                    **frame_msg(5),
                    "targets": [
                        {"effector": "hand", "position": {"x": float("nan"), "y": 0, "z": 0}}
                    ],
                }
            ),
            "invalid_format",
        ),
    ],
)
def test_recoverable_errors_keep_the_socket_open(
    client: TestClient, session: Created, bad: str | bytes, code: str
) -> None:
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        if isinstance(bad, bytes):
            ws.send_bytes(bad)
            err = msgpack.unpackb(ws.receive_bytes())
        else:
            ws.send_text(bad)
            err = ws.receive_json()
        parsed = S.ErrorMessage.model_validate(err)
        assert parsed.error.code == code and parsed.success is False
        ws.send_text(json.dumps(frame_msg(6)))
        ok = ws.receive_json()
        assert ok["id"] == 6 and ok["success"] is True


def test_error_echoes_the_id_when_readable(client: TestClient, session: Created) -> None:
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json({"type": "frame", "id": 8, "targets": []})
        err = ws.receive_json()
        assert err["id"] == 8 and err["error"]["code"] == "invalid_format"
        assert err["error"]["field"] == "frame.targets"


def test_id_must_increase(client: TestClient, session: Created) -> None:
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json(frame_msg(5))
        assert ws.receive_json()["success"] is True
        ws.send_json(frame_msg(5))
        err = ws.receive_json()
        assert err["id"] == 5 and err["error"]["code"] == "id_reuse"
        ws.send_json({"type": "ping", "id": 4})
        assert ws.receive_json()["error"]["code"] == "id_reuse"
        ws.send_json(frame_msg(6))
        assert ws.receive_json()["success"] is True


def test_only_a_message_that_was_read_uses_up_its_id(client: TestClient, session: Created) -> None:
    """invalid_format: not read as a message, its id stays free for the corrected one;
    invalid_problem (a readable frame naming no effector of the chain) takes its id."""
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json({**frame_msg(40), "extra": 1})
        assert ws.receive_json()["error"]["code"] == "invalid_format"
        ws.send_json(frame_msg(40))
        assert ws.receive_json()["success"] is True
        unknown = frame_msg(41)
        unknown["targets"][0]["effector"] = "claw"
        ws.send_json(unknown)
        assert ws.receive_json()["error"]["code"] == "invalid_problem"
        ws.send_json(frame_msg(41))
        assert ws.receive_json()["error"]["code"] == "id_reuse"


def test_unreachable_frame_is_a_result_with_success_false(
    client: TestClient, session: Created
) -> None:
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json(frame_msg(1, x=9.0))
        reply = S.ResultMessage.model_validate(ws.receive_json())
    assert reply.success is False and reply.result.status != "solved"


@pytest.mark.parametrize(
    ("headers", "path_id", "close_code"),
    [
        ({}, None, 4401),
        ({"Authorization": "Bearer wrong"}, None, 4403),
        (None, "nosuchsession", 4404),
    ],
)
def test_handshake_failures_close_with_codes(
    client: TestClient,
    session: Created,
    headers: dict[str, str] | None,
    path_id: str | None,
    close_code: int,
) -> None:
    path = f"/v1/sessions/{path_id or session.id}/ws"
    with pytest.raises(WebSocketDisconnect) as info:
        with client.websocket_connect(
            path, headers=session.headers if headers is None else headers
        ) as ws:
            ws.receive_json()
    assert info.value.code == close_code


def test_deleted_session_closes_4404_at_the_next_message(
    client: TestClient, session: Created
) -> None:
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json(frame_msg(1))
        assert ws.receive_json()["success"] is True
        assert (
            client.delete(f"/v1/sessions/{session.id}", headers=session.headers).status_code == 204
        )
        ws.send_json(frame_msg(2))
        with pytest.raises(WebSocketDisconnect) as info:
            ws.receive_json()
    assert info.value.code == 4404


def test_message_over_the_limit_closes_1009(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(ws_max_message_bytes=1024))
    s = create(client)
    with client.websocket_connect(url(s), headers=s.headers) as ws:
        ws.send_text(json.dumps({**frame_msg(1), "pad": "x" * 2000}))
        with pytest.raises(WebSocketDisconnect) as info:
            ws.receive_json()
    assert info.value.code == 1009


def test_too_many_websockets_closes_1013(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_websockets=1))
    s = create(client)
    with client.websocket_connect(url(s), headers=s.headers) as first:
        first.send_json({"type": "ping", "id": 1})
        assert first.receive_json()["type"] == "pong"
        with pytest.raises(WebSocketDisconnect) as info:
            with client.websocket_connect(url(s), headers=s.headers) as second:
                second.receive_json()
        assert info.value.code == 1013
        first.send_json({"type": "ping", "id": 2})
        assert first.receive_json()["id"] == 2


def test_open_socket_keeps_the_session_alive_and_is_counted(
    make_client: Callable[..., TestClient],
) -> None:
    from service.sessions import InMemorySessionStore

    now = [0.0]
    store = InMemorySessionStore(max_sessions=10, ttl_s=5.0, clock=lambda: now[0])
    client = make_client(Settings(session_ttl_s=5.0), store=store)
    s = create(client)
    with client.websocket_connect(url(s), headers=s.headers) as ws:
        ws.send_json({"type": "ping", "id": 1})
        ws.receive_json()
        now[0] += 60.0
        info = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()
        assert info["websockets"] == 1
        ws.send_json(frame_msg(2))
        assert ws.receive_json()["success"] is True


def test_http_and_ws_frames_share_the_session_pose(client: TestClient, session: Created) -> None:
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json(frame_msg(1, y=0.2))
        q_ws = ws.receive_json()["result"]["q"]
    pose = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()["pose"]["q"]
    assert pose == q_ws


@pytest.mark.parametrize("path", ["pydantic", "fast"])
def test_unexpected_error_sends_internal_error_then_closes_1011(
    client: TestClient, session: Created, monkeypatch: pytest.MonkeyPatch, path: str
) -> None:
    """A bug while handling a frame, on either decoding path: an internal_error message,
    close 1011, and the session survives."""
    from service import convert
    from solver.ik import IKSolver

    def boom(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("bug")

    if path == "pydantic":
        monkeypatch.setattr(convert, "targets", boom)
        monkeypatch.setattr(convert, "fast_frame", lambda *args: None)  # take pydantic's path
    else:
        monkeypatch.setattr(IKSolver, "track", boom)  # what every solved frame calls
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json(frame_msg(1))
        err = ws.receive_json()
        assert err["error"]["code"] == "internal_error"
        with pytest.raises(WebSocketDisconnect) as info:
            ws.receive_json()
    assert info.value.code == 1011
    assert client.get(f"/v1/sessions/{session.id}", headers=session.headers).status_code == 200


# The frame loop runs in a task of its own (_serve), awaited by the endpoint: cancelling
# the endpoint (server shutdown after the graceful timeout, the TestClient on exit) must
# cancel the loop, and the counts kept by the endpoint must come back in every case.


def _gauge(client: Any) -> float:
    for line in client.get("/metrics").text.splitlines():
        if line.startswith("ik_websockets "):
            return float(line.split()[1])
    raise AssertionError("no ik_websockets")


def _track_inner(monkeypatch: pytest.MonkeyPatch) -> list[asyncio.Task[Any]]:
    """Record the task each _Connection is created in (= the task running _serve)."""
    seen: list[asyncio.Task[Any]] = []
    real = ws_mod._Connection.__init__

    def init(self: Any, *a: Any, **k: Any) -> None:
        real(self, *a, **k)
        # the watchdog must cancel the task running the frame loop, not the endpoint's
        assert self._task.get_coro().cr_code.co_name == "_serve"
        seen.append(self._task)

    monkeypatch.setattr(ws_mod._Connection, "__init__", init)
    return seen


def test_endpoint_cancelled_during_a_send_cancels_the_loop_and_frees_the_counts(
    make_client: Callable[..., TestClient], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The TestClient cancels the app on exit (as uvicorn does after the graceful
    timeout): the inner task is cancelled too, no slow_reader, counts back to 0."""
    client = make_client(Settings(ws_send_timeout_s=3600.0))
    s = create(client)
    svc = client.app.state.ik
    inner = _track_inner(monkeypatch)

    async def blocked(self: WebSocket, data: str) -> None:
        await asyncio.sleep(3600)

    monkeypatch.setattr(WebSocket, "send_text", blocked)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json({"type": "ping", "id": 1})
        client.get("/healthz")  # let the loop run the frame into the blocked send
        assert svc.open_websockets == 1
    assert len(inner) == 1 and inner[0].done() and inner[0].cancelled()
    assert svc.open_websockets == 0 and svc.ws_in_flight == 0
    assert client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["websockets"] == 0
    assert _gauge(client) == 0.0
    assert "slow_reader" not in client.get("/metrics").text


def test_endpoint_cancelled_during_a_solve(
    make_client: Callable[..., TestClient], monkeypatch: pytest.MonkeyPatch
) -> None:
    client = make_client(Settings())
    s = create(client)
    svc = client.app.state.ik
    inner = _track_inner(monkeypatch)

    async def stuck(*a: Any, **k: Any) -> Any:
        await asyncio.sleep(3600)

    monkeypatch.setattr(svc.runner, "session_frames", stuck)
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        ws.send_json(frame_msg(1))
        client.get("/healthz")
    assert inner and inner[0].done()
    assert svc.open_websockets == 0 and svc.ws_in_flight == 0 and _gauge(client) == 0.0


def test_an_exception_escaping_the_loop_task_still_frees_the_counts(
    make_client: Callable[..., TestClient], monkeypatch: pytest.MonkeyPatch
) -> None:
    client = make_client(Settings())
    s = create(client)
    svc = client.app.state.ik

    def boom(self: Any) -> None:
        raise RuntimeError("bug before the loop's try")

    monkeypatch.setattr(ws_mod._Connection, "start_watch", boom)
    with pytest.raises(RuntimeError):
        with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
            ws.send_json({"type": "ping", "id": 1})
            ws.receive_json()
    assert svc.open_websockets == 0 and _gauge(client) == 0.0
    assert client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["websockets"] == 0


def test_watchdog_and_endpoint_cancel_together_is_a_cancellation_not_a_slow_reader() -> None:
    """Both cancels land before the inner task resumes: the inner must re-raise
    CancelledError (uncancel() > 0), and the endpoint must see CancelledError."""

    async def main() -> tuple[str, str]:
        never = asyncio.Event()

        class FakeWS:
            async def send_text(self, data: str) -> None:
                await never.wait()

        svc = types.SimpleNamespace(
            settings=types.SimpleNamespace(ws_send_timeout_s=3600.0), store=None
        )
        out: dict[str, str] = {}

        async def serve() -> None:
            conn = ws_mod._Connection(FakeWS(), svc, None)  # type: ignore[arg-type]
            out["conn"] = "ok"
            holder.append(conn)
            try:
                await conn.send({"x": 1}, False)
            except ws_mod._SlowReader:
                out["inner"] = "slow_reader"
                return
            except asyncio.CancelledError:
                out["inner"] = "cancelled"
                raise

        holder: list[Any] = []

        async def endpoint() -> None:
            await asyncio.create_task(serve())

        outer = asyncio.create_task(endpoint())
        for _ in range(3):
            await asyncio.sleep(0)
        conn = holder[0]
        assert conn._task is not outer  # the loop's own task
        conn._timed_out = True
        conn._task.cancel()  # the watchdog
        outer.cancel()  # server shutdown
        try:
            await outer
            out["outer"] = "returned"
        except asyncio.CancelledError:
            out["outer"] = "cancelled"
        return out["inner"], out["outer"]

    assert asyncio.run(main()) == ("cancelled", "cancelled")


def _clip(msg_id: int, n: int, plan: bool) -> dict[str, Any]:
    frames = [hand_frame(10 + i, y=0.1 + 0.01 * i) for i in range(n)]
    return {"type": "clip", "id": msg_id, "frames": frames, "plan": plan}


def _pose(client: TestClient, s: Created) -> list[float]:
    r = client.get(f"/v1/sessions/{s.id}", headers=s.headers)
    q: list[float] = r.json()["pose"]["q"]
    return q


@pytest.mark.parametrize("plan", [True, False], ids=["planned", "in-order"])
def test_a_clip_message_is_answered_by_one_clip_result(
    client: TestClient, session: Created, plan: bool
) -> None:
    # As POST .../frames with {"frames": [...]}: one result per frame, in order, each
    # with its frame's id; the session's pose is the last frame's answer, and the next
    # frame message starts from it.
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json(_clip(4, 5, plan))
        reply = SERVER_MESSAGE.validate_python(ws.receive_json())
        assert isinstance(reply, S.ClipResultMessage)
        assert reply.id == 4 and reply.success
        assert [r.id for r in reply.results] == [10, 11, 12, 13, 14]
        assert all(r.success for r in reply.results)
        assert (reply.plan is not None) == plan
        if reply.plan is not None:
            assert reply.plan.candidates >= 5 and reply.plan.plan_us > 0
        assert _pose(client, session) == pytest.approx(reply.results[-1].q, abs=0.0)
        ws.send_json(frame_msg(5, y=0.15))
        assert ws.receive_json()["success"] is True
    counters = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()
    assert counters["counters"]["frames"] == 6


def test_a_clip_in_msgpack_with_compact_results(client: TestClient, session: Created) -> None:
    with client.websocket_connect(f"{url(session)}?results=compact", headers=session.headers) as ws:
        ws.send_bytes(msgpack.packb(_clip(1, 3, True)))
        raw = msgpack.unpackb(ws.receive_bytes())
    reply = S.ClipResultMessage.model_validate(raw)
    assert all(isinstance(r, S.CompactFrameResult) for r in reply.results)
    assert [r.id for r in reply.results] == [10, 11, 12] and reply.plan is not None


def test_a_clip_with_a_bad_frame_is_refused_whole(
    make_client: Callable[..., TestClient],
) -> None:
    client = make_client(Settings(max_frames_per_request=4))
    session = create(client)
    before = _pose(client, session)
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        bad = _clip(1, 3, True)
        bad["frames"][2]["targets"][0]["effector"] = "claw"
        ws.send_json(bad)
        err = S.ErrorMessage.model_validate(ws.receive_json())
        assert (err.id, err.error.code) == (1, "invalid_problem")
        assert err.error.field == "frames[2].targets[0].effector"
        ws.send_json(_clip(2, 5, False))  # over IK_MAX_FRAMES_PER_REQUEST
        err = S.ErrorMessage.model_validate(ws.receive_json())
        assert (err.id, err.error.code, err.error.field) == (2, "invalid_problem", "frames")
        ws.send_json(_clip(2, 2, True))
        assert ws.receive_json()["error"]["code"] == "id_reuse"
        ws.send_json({"type": "clip", "id": 3, "frames": []})
        err = S.ErrorMessage.model_validate(ws.receive_json())
        assert (err.error.code, err.error.field) == ("invalid_format", "clip.frames")
        assert _pose(client, session) == before
        ws.send_json(_clip(4, 2, True))  # the socket and the session are fine
        assert ws.receive_json()["success"] is True


def test_a_rate_limited_clip_is_refused_with_a_retry_hint(
    make_client: Callable[..., TestClient],
) -> None:
    # Each frame of a clip counts: at 3 frames per second (burst: one full clip of 5),
    # a second 5-frame clip right after the first is refused whole, with
    # retry_after_s, and none of its frames is solved.
    client = make_client(Settings(max_frames_per_s=3.0, max_frames_per_request=5))
    session = create(client)
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json(_clip(1, 5, True))
        assert ws.receive_json()["success"] is True
        ws.send_json(_clip(2, 5, True))
        err = S.ErrorMessage.model_validate(ws.receive_json())
        assert (err.id, err.error.code) == (2, "rate_limited")
        assert err.error.retry_after_s is not None and err.error.retry_after_s > 0
        ws.send_json({"type": "ping", "id": 3})
        assert ws.receive_json() == {"id": 3, "type": "pong"}
    body = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()
    assert body["counters"]["frames"] == 5


def test_a_solver_error_in_a_clip_is_an_error_message_not_a_close(
    client: TestClient, session: Created, monkeypatch: pytest.MonkeyPatch
) -> None:
    # convert.py rejects bad targets first, naming the field; a solver error that got
    # past it is still a recoverable invalid_problem, as over HTTP.
    from service import solving
    from solver.errors import InvalidProblem

    def refuse(*args: Any, **kwargs: Any) -> Any:
        raise InvalidProblem("refused for the test")

    monkeypatch.setattr(solving, "plan_path", refuse)
    with client.websocket_connect(url(session), headers=session.headers) as ws:
        ws.send_json(_clip(1, 2, True))
        err = S.ErrorMessage.model_validate(ws.receive_json())
        assert (err.id, err.error.code) == (1, "invalid_problem")
        assert "refused for the test" in err.error.message
        ws.send_json(_clip(2, 2, False))
        assert ws.receive_json()["success"] is True


def test_a_bad_results_value_closes_1008_after_the_handshake(
    client: TestClient, session: Created
) -> None:
    path = f"/v1/sessions/{session.id}/ws?results=bogus"
    with pytest.raises(WebSocketDisconnect) as info:
        with client.websocket_connect(path, headers=session.headers) as ws:
            ws.receive_text()
    assert info.value.code == 1008 and info.value.reason == "invalid_format"
