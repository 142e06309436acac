"""ikpy: the whole IK is one scipy.optimize.least_squares (trf, bounded by the joint
limits, finite-difference Jacobian) on the residual [p - p*, R - R*] (12 values).

ikpy has no success flag (it always returns the optimiser's x), so solve() returns x
unless the optimiser was stopped by the deadline. Time is enforced with scipy's
least_squares callback (scipy >= 1.16): raising StopIteration ends the run.
"""

from __future__ import annotations

import time
import warnings

import numpy as np
from ikpy.chain import Chain

from bench.robots import RobotSpec

# ikpy's `tol` sets scipy's ftol and xtol (default 1e-8 each, relative); gtol (on the
# scaled gradient, default 1e-8) goes through optimizer_kwargs. Tightened to 1e-10 so a
# slow stretch of trf cannot stop early far from 1e-5 m; the defaults already end near
# 1e-8 m on the targets tried, and 1e-12 only added evaluations.
TOL = 1e-10
GTOL = 1e-10
# Cap on residual evaluations (ikpy's optimizer_budget = scipy max_nfev); each Jacobian
# costs n_joints evaluations, so this is ~100 trf iterations. The deadline usually bites first.
BUDGET = 1000


class _Deadline(Exception):
    pass


class IkpyIK:
    name = "ikpy (scipy least_squares trf)"

    def __init__(self, robot: RobotSpec) -> None:
        with warnings.catch_warnings():  # iiwa's fixed joint carries an axis; ikpy warns
            warnings.simplefilter("ignore")
            full = Chain.from_urdf_file(
                str(robot.urdf_path), base_elements=list(robot.path_elements())
            )
            # ikpy keeps walking past the tip (first child of each link), so cut the chain at
            # the tip's joint: [origin link] + one ikpy link per URDF joint on the path
            n_path = (len(robot.path_elements()) - 1) // 2
            links = full.links[: 1 + n_path]
            names = tuple(link.name for link in links if link.joint_type != "fixed")
            mask = [link.joint_type != "fixed" for link in links]
            self._chain = Chain(links, active_links_mask=mask, name=robot.name)
        if names != robot.joint_names:
            raise ValueError(f"ikpy chain {names} != URDF chain {robot.joint_names}")
        self.joint_names = robot.joint_names
        self.lower, self.upper = robot.lower, robot.upper
        self._mask = np.array(mask)
        # first call pays for lazily built sympy/numpy FK pieces; keep it out of the timings
        self.solve(self.fk(robot.mid()), robot.mid(), position_only=False, timeout_s=0.05)
        self.settings = (
            f"least_squares trf, tol={TOL:g} (ftol=xtol), gtol={GTOL:g}, "
            f"optimizer_budget={BUDGET} evals, deadline via callback, "
            "orientation_mode='all' (R - R* residual, weight 1)"
        )

    def _full(self, q: np.ndarray) -> np.ndarray:
        full = np.zeros(len(self._mask))
        full[self._mask] = q
        return full

    def fk(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(self._chain.forward_kinematics(self._full(np.asarray(q, dtype=float))))

    def solve(
        self, target: np.ndarray, seed: np.ndarray, *, position_only: bool, timeout_s: float
    ) -> np.ndarray | None:
        deadline = time.perf_counter() + timeout_s

        def stop_at_deadline(x: np.ndarray) -> None:
            if time.perf_counter() > deadline:
                raise StopIteration  # scipy ends the run with status -2

        target = np.asarray(target, dtype=float)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                full = self._chain.inverse_kinematics(
                    target_position=target[:3, 3],
                    target_orientation=None if position_only else target[:3, :3],
                    orientation_mode=None if position_only else "all",
                    initial_position=self._full(np.asarray(seed, dtype=float)),
                    optimizer="least_squares",
                    tol=TOL,
                    optimizer_budget=BUDGET,
                    optimizer_kwargs={"gtol": GTOL, "callback": stop_at_deadline},
                )
        except Exception:  # noqa: BLE001 - a peer that raises has failed this target
            return None
        if time.perf_counter() > deadline:
            return None  # cut short by the callback: no answer within the budget
        return np.asarray(full, dtype=float)[self._mask]
