"""roboticstoolbox-python's C++ numerical IK (ik_LM by default; ik_NR / ik_GN also work).

The C++ loop has no time limit, only `ilimit` iterations per search and `slimit` searches
(search 1 starts at q0, every later one at a uniform random q within limits). To respect
timeout_s we time one search at start-up and hand rtb the searches that fit in half the
time left, calling again (random starts, as rtb would do itself) until the budget is spent.
"""

from __future__ import annotations

import io
import time
import warnings
from typing import Any

import numpy as np
from roboticstoolbox.models.URDF.URDFRobot import URDF_file
from roboticstoolbox.robot.Robot import Robot

from bench.robots import RobotSpec

# rtb's error is E = 0.5 * e^T diag(mask) e with e = (dp, angle-axis). The default 1e-6
# lets |dp| reach 1.4e-3 m; E < 1e-12 gives |e| < 1.4e-6, safely inside 1e-5 m / 1e-4 rad
# and costs at most one more Newton-like step.
TOL = 1e-12
ILIMIT = 30  # rtb default
SLIMIT = 100  # rtb default: cap on searches, further cut by the time budget
# Each call gets the searches that fit in this share of the time left, so a slow spell on
# the shared cores (or a low start-up estimate) overruns by a fraction of a search at most
# instead of by several; extra calls cost ~20 us each.
_SHARE = 0.5


def renumber_joints(ets: Any) -> None:
    """Number an ETS's joints 0..n-1 along the chain. ``Robot.ets(start, end)`` keeps
    each joint's index in the whole robot (PR2's right arm: 3..9), and ``ik_LM`` then
    reads a q of the chain's length at those indexes: it failed every frame."""
    for i, e in enumerate(e for e in ets if e.isjoint):
        e.jindex = i


class RtbIK:
    def __init__(self, robot: RobotSpec, method: str = "LM") -> None:
        with warnings.catch_warnings():  # rtb warns about deprecated helpers on load
            warnings.simplefilter("ignore")
            elinks, name, _ = URDF_file(io.StringIO(robot.kinematic_urdf_text()))
            self._ets = Robot(elinks, name=name).ets(start=robot.base_link, end=robot.tip_link)
        renumber_joints(self._ets)
        self.joint_names = robot.joint_names
        self.lower, self.upper = robot.lower, robot.upper
        # rtb numbers the joints along the ETS, which is the chain order; check it really
        # carries our limits in our order, since we pass vectors through unpermuted
        if self._ets.n != len(self.joint_names) or not np.allclose(
            self._ets.qlim, np.vstack([self.lower, self.upper])
        ):
            raise ValueError(f"rtb chain for {robot.name} does not match the URDF chain")
        self._ik = {"LM": self._ets.ik_LM, "NR": self._ets.ik_NR, "GN": self._ets.ik_GN}[method]
        self.name = f"rtb ik_{method} (C++)"
        self._t_search = self._time_one_search(robot.mid())
        self.settings = (
            f"tol={TOL:g} (on 0.5*|e|^2), ilimit={ILIMIT}, slimit<={SLIMIT} "
            f"cut to the time budget (~{self._t_search * 1e6:.0f} us/search), "
            f"joint_limits=True" + (", method=chan, k=1.0" if method == "LM" else "")
        )

    def _time_one_search(self, q0: np.ndarray) -> float:
        far = np.eye(4)
        far[:3, 3] = 100.0  # unreachable, so every search runs all ILIMIT iterations
        runs = []
        for _ in range(5):
            t0 = time.perf_counter()
            self._ik(far, q0=q0, ilimit=ILIMIT, slimit=4, tol=TOL)
            runs.append((time.perf_counter() - t0) / 4)
        return float(np.median(runs))

    def fk(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(self._ets.eval(np.asarray(q, dtype=float)))

    def solve(
        self, target: np.ndarray, seed: np.ndarray, *, position_only: bool, timeout_s: float
    ) -> np.ndarray | None:
        deadline = time.perf_counter() + timeout_s
        mask = np.array([1, 1, 1, 0, 0, 0.0]) if position_only else np.ones(6)
        target = np.asarray(target, dtype=float)
        q0: np.ndarray | None = np.asarray(seed, dtype=float)
        left = SLIMIT
        while left > 0:
            # always allow one search, so a tiny budget still tries the seed
            n = min(left, max(1, int(_SHARE * (deadline - time.perf_counter()) / self._t_search)))
            sol = self._ik(
                target, q0=q0, ilimit=ILIMIT, slimit=n, tol=TOL, mask=mask, joint_limits=True
            )
            if sol.success:
                return np.array(sol.q, dtype=float)
            left -= n
            q0 = None  # later calls start at random, as rtb's own restarts do
            if deadline - time.perf_counter() < self._t_search:
                break
        return None
