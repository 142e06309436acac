"""The README's curl walk-through and Python WebSocket client, run against a real server."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from .conftest import ROOT, Server

pytestmark = pytest.mark.live

README = (ROOT / "README.md").read_text()


def block(name: str) -> str:
    m = re.search(
        rf"<!-- {name}:start -->\s*```\w*\n(.*?)```\s*<!-- {name}:end -->", README, re.DOTALL
    )
    assert m is not None, f"README has no {name} block"
    return m.group(1)


@pytest.mark.skipif(
    shutil.which("curl") is None or shutil.which("jq") is None, reason="needs curl and jq"
)
def test_curl_walkthrough(server: Server, tmp_path: Path) -> None:
    script = "set -euo pipefail\n" + block("curl-walkthrough")
    out = subprocess.run(
        ["bash", "-c", script],
        env={**os.environ, "IK": server.base},
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr + out.stdout
    text = out.stdout
    assert '"status":"ready"' in text
    assert '"success": true' in text  # the single frame (jq pretty-prints it)
    assert '{"id":2,"success":true' in text and '{"id":3,"success":true' in text
    assert '"ids":[4,5],"solved":[true,true]}' in text and '"largest_step_rad":' in text
    # JSON bodies end with a newline, so curl's -w status line follows on its own line.
    assert re.search(r'"code":"unauthorized"}\n\s*HTTP 401', text), text
    assert re.search(r'"field":"targets\[0\]\.effector"}\n\s*HTTP 422', text), text
    assert '"time_budget_us":500' in text
    assert '"joint4":-1.5' in text
    assert '{"name":"tool","position":{"x":' in text  # 4b: the tool's pose from FK
    assert 'ik_frames_total{success="true",termination="goal_reached"}' in text
    assert text.rstrip().endswith("HTTP 204")
    # The walk-through kept the session's token in a file; it must not leave it behind.
    assert "session.json" in script and list(tmp_path.iterdir()) == []


def test_python_websocket_client(server: Server, tmp_path: Path) -> None:
    code = block("ws-client")
    assert len(code.strip().splitlines()) <= 20
    script = tmp_path / "client.py"
    script.write_text(code)
    out = subprocess.run(
        [sys.executable, str(script)],
        # As after `pip install ./clients/python`: the client from the source tree.
        env={**os.environ, "IK": server.base, "PYTHONPATH": str(ROOT / "clients" / "python")},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.strip().splitlines()
    assert [line.split()[0] for line in lines] == ["0", "1", "2", "3", "4"]
    assert all("error" not in line for line in lines)
    assert sum("goal_reached" in line for line in lines) >= 4


def test_typescript_client_as_the_readme_installs_it(server: Server, tmp_path: Path) -> None:
    """The README's TypeScript steps, from a copy of the repository's client folder (so
    the test neither builds in nor leaves a project in the checkout)."""
    npm = shutil.which("npm")
    if npm is None or shutil.which("node") is None:
        if os.environ.get("CI") == "true":
            pytest.fail("node and npm are needed for the TypeScript client's README steps")
        pytest.skip("node and npm are not installed")
    source = ROOT / "clients" / "typescript"
    shutil.copytree(
        source,
        tmp_path / "clients" / "typescript",
        ignore=shutil.ignore_patterns("node_modules", "dist"),
    )
    out = subprocess.run(
        ["bash", "-c", "set -euo pipefail\n" + block("ts-client")],
        env={**os.environ, "IK": server.base},
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr + out.stdout
    line = out.stdout.strip().splitlines()[-1].split()
    assert line[:2] == ["0", "goal_reached"] and len(line) == 2 + 7, out.stdout
