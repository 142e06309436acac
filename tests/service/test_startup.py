"""service.startup: the solver loaded from numba's on-disk cache, or compiled into it
by child processes first; what the log and the progress reports say either way."""

from __future__ import annotations

import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from schemas import StartupPhase, StartupProgress
from service import startup
from solver.precompile import STEP_NAMES

ROOT = Path(__file__).resolve().parents[2]


def test_each_step_is_compiled_by_one_process_at_most() -> None:
    for processes in (1, 2, 5):
        split = startup.shares(processes)
        names = [name for share in split for name in share]
        assert len(names) == len(set(names)) and set(names) <= set(STEP_NAMES)
        # Only the planner end to end is left to the loading process (it combines
        # kernels that other steps compile).
        assert set(STEP_NAMES) - set(names) <= {"plan"}
        assert 1 <= len(split) <= processes
    assert startup.shares(1) == [STEP_NAMES]
    assert startup.shares(2, ["plan_nodes", "pose"]) == [("pose",), ("plan_nodes",)]


def test_a_warm_cache_is_loaded_and_the_log_says_so(
    warm_solver: float, caplog: pytest.LogCaptureFixture
) -> None:
    reports: list[StartupProgress] = []
    with caplog.at_level(logging.INFO, logger="service"):
        startup.warm_solver(reports.append)
    assert "loaded from its on-disk cache" in caplog.text
    assert "compiling" not in caplog.text
    assert {r.phase for r in reports} == {StartupPhase.LOADING}
    assert [r.done for r in reports] == list(range(len(STEP_NAMES) + 1))
    assert reports[-1].total == len(STEP_NAMES) and reports[-1].compiled == 0


def test_a_failed_compile_process_is_logged(caplog: pytest.LogCaptureFixture) -> None:
    reports: list[StartupProgress] = []
    with caplog.at_level(logging.INFO, logger="service"):
        codes = startup.compile_in_children([("no_such_step",)], reports.append)
    assert codes == [1]
    assert "exited with 1" in caplog.text and "no_such_step" in caplog.text
    assert reports == []


def test_a_compile_process_stops_when_its_parent_goes_away(warm_solver: float) -> None:
    child = subprocess.Popen(
        [sys.executable, "-m", "service.compile_worker", "plan"],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
    )
    assert child.stdin is not None
    child.stdin.close()  # what the parent's exit does to the pipe
    assert child.wait(timeout=60) == 1  # 0 only if it ran the warm-up to the end


def _copy_packages(dest: Path) -> None:
    """solver/, schemas/ and service/ without any compiled code: a fresh checkout."""
    for package in ("solver", "schemas", "service"):
        shutil.copytree(
            ROOT / package, dest / package, ignore=shutil.ignore_patterns("__pycache__")
        )


_WARM = """
import logging, sys
logging.basicConfig(level="INFO", stream=sys.stderr, format="%(message)s")
from service.startup import warm_solver
warm_solver(lambda p: print(p.model_dump_json(), flush=True), processes=2)
"""


def _warm_in(root: Path) -> tuple[list[dict[str, object]], str]:
    env = {**os.environ, "PYTHONPATH": str(root), "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, "-c", _WARM],
        cwd=root,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
        check=True,
    )
    return [json.loads(line) for line in done.stdout.splitlines()], done.stderr


@pytest.mark.slow
def test_a_cold_cache_is_filled_by_child_processes_then_loaded(tmp_path: Path) -> None:
    """Minutes: the whole solver compiles, in two processes."""
    _copy_packages(tmp_path)
    solver_dir = tmp_path / "solver"  # each (sub)package's __pycache__ holds its own
    n = len(STEP_NAMES)
    shared = sum(len(share) for share in startup.shares(2))

    reports, log = _warm_in(tmp_path)
    assert "compiling it now, in 2 process(es)" in log and "once per checkout or image" in log
    assert f"compiling the solver: {shared}/{shared} steps done" in log
    assert "compiled and loaded" in log
    # The shares compiled everything the warm-up needs: this process compiled nothing.
    assert "missing from the on-disk cache" not in log
    compiling = [r for r in reports if r["phase"] == "compiling"]
    assert compiling and compiling[-1]["done"] == shared and compiling[-1]["compiled"] > 0
    assert reports[-1]["phase"] == "loading" and reports[-1]["done"] == n
    assert reports[-1]["compiled"] == 0
    assert list(solver_dir.rglob("__pycache__/*.nbi")), "the children wrote no cache index"

    reports, log = _warm_in(tmp_path)
    assert "loaded from its on-disk cache" in log and "compiling" not in log
    assert {r["phase"] for r in reports} == {"loading"}
