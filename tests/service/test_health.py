"""/healthz, /readyz (flips after warm-up), /metrics (the series exist and count)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from starlette.testclient import TestClient

from schemas import StartupPhase, StartupProgress

from .helpers import Created, create, hand_frame


def test_healthz(client: TestClient) -> None:
    r = client.get("/healthz")
    assert r.status_code == 200 and r.json() == {"status": "ok"}


def test_readyz_is_503_until_the_warmup_returns(make_client: Callable[..., TestClient]) -> None:
    gate = threading.Event()

    def warmup(report: object) -> float:
        assert gate.wait(30.0)
        return 0.0

    client = make_client(warmup=warmup)
    r = client.get("/readyz")
    assert r.status_code == 503 and r.json()["code"] == "not_ready"
    assert client.get("/healthz").status_code == 200  # alive while warming
    gate.set()
    assert client.app.state.ik.runner.warmup.ready.wait(30.0)  # type: ignore[attr-defined]
    r = client.get("/readyz")
    assert r.status_code == 200 and r.json()["status"] == "ready"


def test_readyz_shows_how_far_the_warmup_is(make_client: Callable[..., TestClient]) -> None:
    reported, gate = threading.Event(), threading.Event()

    def warmup(report: Callable[[StartupProgress], None]) -> float:
        report(
            StartupProgress(
                phase=StartupPhase.COMPILING, done=2, total=5, elapsed_s=3.0, compiled=40
            )
        )
        reported.set()
        assert gate.wait(30.0)
        return 0.0

    client = make_client(warmup=warmup)
    try:
        assert reported.wait(30.0)
        r = client.get("/readyz")
        assert r.status_code == 503 and r.headers["retry-after"] == "1"
        body = r.json()
        assert body["code"] == "not_ready"
        progress = body["progress"]
        assert progress.pop("elapsed_s") >= 3.0  # brought up to the time of the request
        assert progress == {"phase": "compiling", "done": 2, "total": 5, "compiled": 40}
        assert "compiling the solver" in body["detail"] and "cached on disk" in body["detail"]
        assert "2/5 steps" in body["detail"]
    finally:
        gate.set()
    assert client.app.state.ik.runner.warmup.ready.wait(30.0)  # type: ignore[attr-defined]
    r = client.get("/readyz")
    assert r.status_code == 200 and "progress" not in r.json()


def test_readyz_before_the_first_report_has_no_progress(
    make_client: Callable[..., TestClient],
) -> None:
    gate = threading.Event()

    def warmup(report: object) -> float:
        assert gate.wait(30.0)
        return 0.0

    client = make_client(warmup=warmup)
    try:
        body = client.get("/readyz").json()
        assert body == {"detail": "the solver is warming up", "code": "not_ready"}
    finally:
        gate.set()


def test_readyz_503_body_is_documented(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    content = spec["paths"]["/readyz"]["get"]["responses"]["503"]["content"]
    ref = content["application/json"]["schema"]["$ref"].rsplit("/", 1)[-1]
    schemas = spec["components"]["schemas"]
    assert "progress" in schemas[ref]["properties"]
    progress = schemas["StartupProgress"]
    assert set(progress["required"]) == {"phase", "done", "total", "elapsed_s", "compiled"}
    assert set(schemas["StartupPhase"]["enum"]) == {"compiling", "loading"}


def test_readyz_reports_a_failed_warmup(make_client: Callable[..., TestClient]) -> None:
    done = threading.Event()

    def warmup(report: object) -> float:
        done.set()
        raise RuntimeError("no compiler")

    client = make_client(warmup=warmup)
    assert done.wait(30.0)
    warm = client.app.state.ik.runner.warmup  # type: ignore[attr-defined]
    warm._thread.join(30.0)
    r = client.get("/readyz")
    assert r.status_code == 503 and r.json()["code"] == "warmup_failed"


def test_metrics_series(client: TestClient, session: Created) -> None:
    client.post(f"/v1/sessions/{session.id}/frames", json=hand_frame(1), headers=session.headers)
    with client.websocket_connect(f"/v1/sessions/{session.id}/ws", headers=session.headers) as ws:
        ws.send_json({"type": "frame", "id": 1, **hand_frame(None)})
        ws.receive_json()
        ws.send_text("not json")
        ws.receive_json()
        text = client.get("/metrics").text
    assert 'ik_frames_total{success="true",termination="goal_reached"} 2.0' in text
    assert "ik_solve_duration_seconds_bucket" in text
    assert 'ik_server_duration_seconds_count{transport="http"} 1.0' in text
    assert 'ik_server_duration_seconds_count{transport="ws"} 1.0' in text
    assert "ik_active_sessions 1.0" in text
    assert "ik_websockets 1.0" in text
    assert 'ik_errors_total{code="invalid_format",transport="ws"} 1.0' in text
    assert "ik_sessions_created_total 1.0" in text
    assert session.id not in text and session.token not in text
    assert "_created" not in text.replace("ik_sessions_created", "")  # no series of starts
    after = client.get("/metrics").text
    assert "ik_websockets 0.0" in after


def test_http_errors_are_counted(client: TestClient, session: Created) -> None:
    """ik_errors_total counts HTTP answers too: each kind of handler's (a ServiceError,
    a validation error, starlette's 404), not only the WebSocket's and batch entries'."""
    frames = f"/v1/sessions/{session.id}/frames"
    assert client.post(frames, json=hand_frame(1)).status_code == 401  # no token
    assert client.post(frames, json={"targets": []}, headers=session.headers).status_code == 422
    assert client.get("/v1/no-such-path").status_code == 404
    text = client.get("/metrics").text
    assert 'ik_errors_total{code="unauthorized",transport="http"} 1.0' in text
    assert 'ik_errors_total{code="invalid_format",transport="http"} 1.0' in text
    assert 'ik_errors_total{code="not_found",transport="http"} 1.0' in text


def test_metrics_count_sessions(client: TestClient) -> None:
    a = create(client)
    create(client)
    assert "ik_active_sessions 2.0" in client.get("/metrics").text
    client.delete(f"/v1/sessions/{a.id}", headers=a.headers)
    assert "ik_active_sessions 1.0" in client.get("/metrics").text


def test_openapi_documents_every_route(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    assert set(spec["paths"]) >= {
        "/v1/sessions",
        "/v1/sessions/{session_id}",
        "/v1/sessions/{session_id}/pose",
        "/v1/sessions/{session_id}/frames",
        "/v1/solve",
        "/healthz",
        "/readyz",
        "/metrics",
    }
    assert "HTTPBearer" in spec["components"]["securitySchemes"]
    assert client.get("/docs").status_code == 200 and client.get("/redoc").status_code == 200


def test_passed_health_checks_are_left_out_of_the_access_log() -> None:
    """uvicorn's access-log record (its args as uvicorn passes them): a balancer's
    passed probes are dropped, failed ones and every other request kept."""
    from service.log_format import QuietProbes

    def record(path: str, status: int) -> logging.LogRecord:
        args = ("127.0.0.1:5000", "GET", path, "1.1", status)
        msg = '%s - "%s %s HTTP/%s" %d'
        return logging.LogRecord("uvicorn.access", logging.INFO, "", 0, msg, args, None)

    quiet = QuietProbes()
    assert not quiet.filter(record("/readyz", 200))
    assert not quiet.filter(record("/healthz", 200))
    assert quiet.filter(record("/readyz", 503))
    assert quiet.filter(record("/v1/sessions", 201))
    assert quiet.filter(record("/readyz?x=1", 200))  # not a probe the balancers send


def test_a_failing_probe_is_logged_when_it_changes_and_then_every_30_s() -> None:
    """A compile of minutes probed twice a second: not a line per probe."""
    from service.log_format import QuietProbes

    def record(path: str, status: int) -> logging.LogRecord:
        args = ("127.0.0.1:5000", "GET", path, "1.1", status)
        return logging.LogRecord("uvicorn.access", logging.INFO, "", 0, "%s", args, None)

    now = [0.0]
    quiet = QuietProbes(repeat_s=30.0, clock=lambda: now[0])
    kept = []
    for step in range(120):  # 60 s of probes every 0.5 s
        now[0] = step * 0.5
        kept.append(quiet.filter(record("/readyz", 503)))
    assert kept.count(True) == 2 and kept[0] and kept[60]  # at 0 s and at 30 s
    assert quiet.filter(record("/healthz", 503))  # another path: its own first line
    assert quiet.filter(record("/readyz", 500))  # another status: logged at once
    assert not quiet.filter(record("/readyz", 200))  # passed: dropped, and the
    assert quiet.filter(record("/readyz", 503))  # next failure is news again
