"""Peer IK solvers for bench/ik/, each behind the same small protocol.

The peers are benchmark extras (see bench/PEERS.md): a peer whose package does not
import is skipped, and the reason is kept in SKIPPED so the benchmark can print it.
Success is never taken from a peer's own flag: the benchmark checks the returned joint
vector with the project's FK.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import numpy as np

from bench.robots import RobotSpec


@runtime_checkable
class PeerSolver(Protocol):
    name: str  # e.g. "rtb ik_LM (C++)"
    settings: str  # human-readable settings, for the benchmark report
    joint_names: tuple[str, ...]  # chain order base -> tip, as in RobotSpec.joint_names
    lower: np.ndarray
    upper: np.ndarray

    def fk(self, q: np.ndarray) -> np.ndarray:
        """4x4 pose of the tip in the base frame, by the peer's own FK."""
        ...

    def solve(
        self, target: np.ndarray, seed: np.ndarray, *, position_only: bool, timeout_s: float
    ) -> np.ndarray | None:
        """Joint vector in joint_names order, or None when the peer reports failure."""
        ...


# (module, class, kwargs); imported lazily so one broken extra does not hide the others
_Entry = tuple[str, str, dict[str, Any]]
_PEERS: tuple[_Entry, ...] = (
    ("bench.peers.rtb_peer", "RtbIK", {}),
    ("bench.peers.ikpy_peer", "IkpyIK", {}),
    ("bench.peers.pin_clik", "PinClik", {}),
)
# Variants, for context only: rtb's other C++ solvers, and the CLIK loop with full steps
_EXTRA: tuple[_Entry, ...] = (
    ("bench.peers.rtb_peer", "RtbIK", {"method": "NR"}),
    ("bench.peers.rtb_peer", "RtbIK", {"method": "GN"}),
    ("bench.peers.pin_clik", "PinClik", {"dt": 1.0}),
)

# "<module> on <robot>" -> reason, filled by available_peers()
SKIPPED: dict[str, str] = {}


def available_peers(robot: RobotSpec, *, extra: bool = False) -> list[PeerSolver]:
    """Peers that import and load this robot; the others go to SKIPPED with the reason.
    extra=True adds the variants in _EXTRA."""
    peers: list[PeerSolver] = []
    for module, cls, kwargs in _PEERS + (_EXTRA if extra else ()):
        try:
            factory: Callable[..., PeerSolver] = getattr(importlib.import_module(module), cls)
            peers.append(factory(robot, **kwargs))
        except Exception as e:  # ImportError, or a loader that rejects the URDF
            SKIPPED[f"{module} on {robot.name}"] = f"{type(e).__name__}: {e}"
    return peers
