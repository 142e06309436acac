"""The compiled solver's numba cache goes where ``NUMBA_CACHE_DIR`` says when it is set.

The image (Dockerfile) compiles as root with ``NUMBA_CACHE_DIR=/app/numba-cache`` and
runs as another user: the cache must be written there, not into a site-packages
``__pycache__`` the runtime user cannot write to (numba skips such a folder and would
compile again at every start). solver/_jit.py's locators once put the tree first, so
the variable was ignored and the image's ``chown`` of the folder had nothing to chown.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# One small compiled function of the solver (ik/continuity.py), called once: its cache
# hits and misses, and where the warm-up would load from.
_CALL = """
import numpy as np
from solver.ik.continuity import largest_step
from solver.precompile import cache_location
largest_step(np.zeros(3), np.ones(3))
stats = largest_step.stats
print(sum(stats.cache_hits.values()) > 0, sum(stats.cache_misses.values()) > 0)
print(cache_location())
print(largest_step._cache._cache_path)  # numba's: where this function's cache is
"""


def _run(env: dict[str, str], *, replace: bool = False) -> list[str]:
    """``_CALL``'s two lines, in a process with ``env`` added (or as its whole
    environment with ``replace``)."""
    done = subprocess.run(
        [sys.executable, "-c", _CALL],
        cwd=ROOT,
        env={**(env if replace else {**os.environ, **env}), "OPENBLAS_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    return done.stdout.split("\n")


def test_numba_cache_dir_is_where_the_solver_compiles_to_and_loads_from(tmp_path: Path) -> None:
    cache = tmp_path / "numba-cache"
    first = _run({"NUMBA_CACHE_DIR": str(cache)})
    assert first[0] == "False True", first  # compiled: nothing there yet
    assert first[1] == str(cache)
    assert first[2].startswith(str(cache)), first
    written = [p.name for p in cache.rglob("*.nbi")]
    assert any(name.startswith("continuity.largest_step") for name in written), written
    again = _run({"NUMBA_CACHE_DIR": str(cache)})
    assert again[0] == "True False", again  # loaded from there, not compiled


def test_without_numba_cache_dir_the_cache_is_the_tree_s() -> None:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    out = _run(env, replace=True)
    assert out[1] == f"{ROOT / 'solver'}/**/__pycache__", out
    assert out[2] == str(ROOT / "solver" / "ik" / "__pycache__"), out  # its module's


def test_an_unwritable_numba_cache_dir_is_not_named_as_the_cache(tmp_path: Path) -> None:
    """numba passes over a folder it cannot write to: the start's log must not say the
    solver is cached there (a file where the folder should be, so that root cannot
    write to it either)."""
    blocked = tmp_path / "not-a-dir"
    blocked.write_text("")
    out = _run({"NUMBA_CACHE_DIR": str(blocked / "cache")})
    assert out[1] == f"{ROOT / 'solver'}/**/__pycache__", out
    assert out[2] == str(ROOT / "solver" / "ik" / "__pycache__"), out  # where numba went
