"""The load generator against a real `python -m service` (issue #5, CI part).

About 10 s of 20 WebSocket clients at 60 Hz (the three shipped chains in turn), plus a
short HTTP run and the command line: zero errors, every frame answered exactly once and
in order, no session lost, and the server counted exactly the frames that were sent.
Latency is not asserted here: CI shares two cores with whatever else runs.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from loadtest.report import summarize, table
from loadtest.run import RunConfig, RunOutput, run

from .conftest import ROOT, Server

pytestmark = [pytest.mark.live, pytest.mark.slow]

CLIENTS = 20
SECONDS = 10.0
RATE_HZ = 60.0


def frames_counted(server: Server) -> int:
    """Sum of ik_frames_total over its labels, from the server's /metrics."""
    text = httpx.get(f"{server.base}/metrics", timeout=30.0).text
    return round(sum(float(v) for v in re.findall(r"^ik_frames_total\{[^}]*\} (\S+)$", text, re.M)))


def assert_clean(out: RunOutput, clients: int) -> dict[str, object]:
    s = summarize(out)
    assert s["errors"] == {}, table(s)
    assert s["sessions"] == {**s["sessions"], "opened": clients, "lost": 0}, table(s)
    for r in out.results:
        # Exactly once and in order: the client matches each answer with the oldest frame
        # in flight and counts anything else as out_of_order / unknown_id (none above).
        assert r.answered == r.sent, (r.index, r.sent, r.answered)
        assert r.sent >= 0.9 * out.config.duration_s * out.config.rate_hz, (r.index, r.sent)
    return s


@pytest.fixture(scope="module")
def fresh_server(start_server: Callable[..., Server]) -> Server:
    """A server of its own, so its frame counter holds exactly this module's frames."""
    return start_server()


def test_websocket_clients_every_frame_answered_once_in_order(fresh_server: Server) -> None:
    before = frames_counted(fresh_server)
    cfg = RunConfig(
        url=fresh_server.base, clients=CLIENTS, rate_hz=RATE_HZ, duration_s=SECONDS, drain_s=60.0
    )
    out = run(cfg)
    s = assert_clean(out, CLIENTS)
    sent = sum(r.sent for r in out.results)
    assert frames_counted(fresh_server) - before == sent
    assert {r.chain for r in out.results} == {"panda_arm", "humanoid_arm", "tail"}
    assert sum(s["terminations"].values()) == sent  # type: ignore[arg-type]
    json.dumps(s)  # the JSON output is plain data


def test_http_clients_every_frame_answered_once_in_order(fresh_server: Server) -> None:
    before = frames_counted(fresh_server)
    cfg = RunConfig(
        url=fresh_server.base,
        transport="http",
        clients=4,
        rate_hz=RATE_HZ,
        duration_s=3.0,
        warmup_s=0.5,
        drain_s=30.0,
    )
    out = run(cfg)
    assert_clean(out, 4)
    assert frames_counted(fresh_server) - before == sum(r.sent for r in out.results)


def test_command_line_json_table_and_png(fresh_server: Server, tmp_path: Path) -> None:
    png = tmp_path / "run.png"
    args = [
        sys.executable,
        "-m",
        "loadtest",
        "--url",
        fresh_server.base,
        "--clients",
        "3",
        "--duration",
        "1.5",
        "--warmup",
        "0.5",
        "--quiet",
        "--json",
        str(tmp_path / "r.json"),
    ]
    try:
        import matplotlib  # noqa: F401

        args += ["--png", str(png)]
    except ImportError:  # the loadtest extra is not installed: no PNG then
        png = None  # type: ignore[assignment]
    p = subprocess.run(args, cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "round trip [ms] p50/p95/p99/max" in p.stdout
    s = json.loads((tmp_path / "r.json").read_text())
    assert s["frames"]["answered"] == s["frames"]["sent"] > 0
    assert s["sessions"]["lost"] == 0 and s["errors"] == {}
    if png is not None:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_refuses_a_non_loopback_url() -> None:
    with pytest.raises(ValueError, match="loopback"):
        RunConfig(url="http://192.0.2.1:8000").check()
    with pytest.raises(ValueError, match="clients"):
        RunConfig(clients=0).check()


def test_summary_counts_late_frames_after_the_warmup_only() -> None:
    from array import array

    from loadtest.records import ClientResult

    r = ClientResult(0, "panda_arm", "ws", opened=True, sent=5, answered=5)
    r.t_s = array("d", [0.0, 1.0, 1.5, 2.0, 2.5])
    r.rtt_us = array("d", [90_000.0, 1_000.0, 2_000.0, 20_000.0, 3_000.0])
    r.solve_us = array("d", [10.0] * 5)
    r.server_us = array("d", [100.0] * 5)
    r.terminations["goal_reached"] = 5
    cfg = RunConfig(clients=1, duration_s=3.0, warmup_s=1.0)
    s = summarize(RunOutput(cfg, [r], wall_s=3.0, generator_cpu_s=0.5))
    assert s["frames"]["measured"] == 4  # the 90 ms frame was in the warm-up
    assert s["frames"]["late"] == 1  # 20 ms > 16.7 ms
    assert s["round_trip_ms"]["max"] == pytest.approx(20.0)
    assert s["frames"]["achieved_per_s"] == pytest.approx(4 / 2.0)
    assert "late (> one frame period)" in table(s)
