"""The benchmark's settings: tolerances, the solvers it knows, one run's configuration."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

POS_TOL = 1e-5  # m
ROT_TOL = 1e-4  # rad
ARMS = ("panda", "ur5", "iiwa")
SOLVER_KEYS = ("ours", "ours-plan", "ours-bfgs", "scipy", "rtb", "ikpy", "clik")
RTB = "rtb"
T0 = time.perf_counter()


def progress(msg: str) -> None:
    print(f"[{time.perf_counter() - T0:7.1f}s] {msg}", file=sys.stderr, flush=True)


@dataclass
class Config:
    n: int
    peer_n: int
    seed: int
    timeout_s: float
    frames: int
    fps: float
    streams: int
    solvers: tuple[str, ...]
    chains: tuple[str, ...]
