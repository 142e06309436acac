"""Smooth, reachable target paths for the shipped example chains, pre-encoded as JSON.

Targets come from forward kinematics of a smooth joint trajectory, so every target is
reachable and consecutive frames are close (what a game's animation sends). Paths are
closed loops: every joint moves with a whole number of periods per loop, so a client
that runs longer than one loop wraps without a jump.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import orjson

from solver.model import Chain, EffectorMode, matrix_to_quaternion
from solver.model.examples import EXAMPLES
from solver.model.forward import effector_poses

# The chains the issue names: a 7-DOF arm, a humanoid arm, a 40-DOF tail.
DEFAULT_CHAINS: tuple[str, ...] = ("panda_arm", "humanoid_arm", "tail")
LOOP_S = 8.0  # one loop of the path [s]


@dataclass(frozen=True, slots=True)
class Path:
    """One chain's path: ``targets[k]`` is the JSON text of frame k's ``targets`` list."""

    chain: str
    n_dof: int
    targets: tuple[bytes, ...]
    target_objs: tuple[list[dict[str, object]], ...]  # the same, decoded (HTTP/locust)


def _target(name: str, mode: EffectorMode, pose: np.ndarray) -> dict[str, object]:
    px, py, pz = (float(v) for v in pose[:3, 3])
    t: dict[str, object] = {"effector": name, "position": {"x": px, "y": py, "z": pz}}
    if mode == EffectorMode.POSE:
        w, x, y, z = (float(v) for v in matrix_to_quaternion(pose[:3, :3]))
        t["orientation"] = {"w": w, "x": x, "y": y, "z": z}
    return t


def make_path(chain_name: str, rate_hz: float, *, loop_s: float = LOOP_S) -> Path:
    """A closed smooth path of ``rate_hz * loop_s`` frames for example ``chain_name``.

    Each joint swings around mid-range by a quarter of its range (at most 0.5 rad), with
    1 or 2 periods per loop and its own phase, so the effector sweeps a smooth curve.
    """
    if chain_name not in EXAMPLES:
        raise ValueError(f"unknown example chain {chain_name!r}; one of {sorted(EXAMPLES)}")
    chain: Chain = EXAMPLES[chain_name]()  # type: ignore[operator]  # untyped table
    n = max(2, round(rate_hz * loop_s))
    mid = chain.mid_limits()
    half = 0.5 * (chain.upper - chain.lower)
    amp = np.minimum(np.where(np.isfinite(half), 0.25 * half, 0.5), 0.5)
    j = np.arange(chain.n_dof)
    cycles = 1 + (j % 2)
    phase = 0.7 * j
    encoded: list[bytes] = []
    objs: list[list[dict[str, object]]] = []
    for k in range(n):
        s = 2.0 * math.pi * k / n
        q = np.clip(mid + amp * np.sin(cycles * s + phase), chain.lower, chain.upper)
        poses = effector_poses(chain, q)
        targets = [_target(e.name, e.mode, p) for e, p in zip(chain.effectors, poses, strict=True)]
        objs.append(targets)
        encoded.append(orjson.dumps(targets))
    return Path(chain_name, chain.n_dof, tuple(encoded), tuple(objs))
