"""Helpers for the service tests: the example arm, session creation, frames."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from schemas.chain import EXAMPLE_ARM
from solver.model import matrix_to_quaternion
from solver.model.examples import panda_arm
from solver.model.forward import effector_poses

if TYPE_CHECKING:
    from starlette.testclient import TestClient

ARM = EXAMPLE_ARM


class Created:
    """A created session: id, token, headers, and the response body."""

    def __init__(self, body: dict[str, Any]) -> None:
        self.body = body
        self.id: str = body["id"]
        self.token: str = body["token"]
        self.headers = {"Authorization": f"Bearer {self.token}"}


def create(client: TestClient, chain: dict[str, Any] | None = None, **extra: Any) -> Created:
    r = client.post("/v1/sessions", json={"chain": chain or ARM, **extra})
    assert r.status_code == 201, r.text
    return Created(r.json())


def hand_frame(
    frame_id: int | None, x: float = 0.3, y: float = 0.1, z: float = 0.6
) -> dict[str, Any]:
    """A frame for the example arm's position effector (reachable for small changes)."""
    frame: dict[str, Any] = {
        "targets": [{"effector": "hand", "position": {"x": x, "y": y, "z": z}}]
    }
    if frame_id is not None:
        frame["id"] = frame_id
    return frame


def panda_target(q: np.ndarray) -> dict[str, Any]:
    """A pose target the Panda reaches at q (w >= 0 quaternion of the flange)."""
    pose = effector_poses(panda_arm(), q)[0]
    w, x, y, z = matrix_to_quaternion(pose[:3, :3])
    px, py, pz = pose[:3, 3]
    return {
        "effector": "tool",
        "position": {"x": px, "y": py, "z": pz},
        "orientation": {"w": w, "x": x, "y": y, "z": z},
    }


ROOT = Path(__file__).resolve().parents[2]


def python_m_service(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """``python -m service`` run to its end (a refused start), in the repository, with
    no IK_* variable of this process's and ``env`` added (names as they are)."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("IK_")}
    return subprocess.run(
        [sys.executable, "-m", "service", *args],
        cwd=ROOT,
        env={**clean, **env},
        capture_output=True,
        text=True,
        timeout=120,
    )
