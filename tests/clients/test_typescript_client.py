"""clients/typescript's own tests (node's test runner) against this session's live server.

`npm ci`, `npm run build` (tsc), then `npm test` with IK_BASE_URL set to the live
server's URL: the TypeScript tests check the client's types against the server's
/openapi.json, every call, both encodings and a reconnect mid-stream; the restart tests
(test/reconnect.test.ts) start their own servers with this interpreter (`PYTHON`) and a
redis-server. Without node and npm the test is skipped, except under CI=true, where it
fails (.ci/run installs them).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from .conftest import Server

pytestmark = [pytest.mark.live, pytest.mark.slow]

PACKAGE = Path(__file__).resolve().parents[2] / "clients" / "typescript"
STEP_TIMEOUT_S = 600.0


def npm_or_skip() -> str:
    npm, node = shutil.which("npm"), shutil.which("node")
    if npm is None or node is None:
        if os.environ.get("CI") == "true":
            pytest.fail("node and npm are needed for the TypeScript client's tests")
        pytest.skip("node and npm are not installed")
    return npm


def run(args: list[str], cwd: Path = PACKAGE, **env: str) -> str:
    done = subprocess.run(
        args,
        cwd=cwd,
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=STEP_TIMEOUT_S,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, f"{' '.join(args)} exited {done.returncode}:\n{output}"
    return output


def test_typescript_client_against_the_live_server(server: Server) -> None:
    npm = npm_or_skip()
    run([npm, "ci", "--no-audit", "--no-fund"])
    run([npm, "run", "build"])
    # PYTHON: the interpreter the restart tests (test/reconnect.test.ts) start servers with.
    report = run([npm, "test"], IK_BASE_URL=server.base, PYTHON=sys.executable)
    # node --test's summary: tests ran and passed (a runner that found none exits 0 too).
    summary = dict(re.findall(r"^# (tests|pass) (\d+)$", report, flags=re.MULTILINE))
    assert int(summary["tests"]) > 0 and summary["pass"] == summary["tests"], report
