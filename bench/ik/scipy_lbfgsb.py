"""scipy's L-BFGS-B on our compiled objective: the IKSolver's data tuple for a frame
(``IKSolver.load_frame``, its documented surface) handed to scipy."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from bench.ik_chains import BenchChain
from solver.ik import IKOptions, IKSolver, Target
from solver.ik.kinematics import effector_errors, ik_objective


class _Deadline(Exception):
    pass


class _GoalMet(Exception):
    pass


SCIPY_FTOL, SCIPY_GTOL, SCIPY_MAXITER = 1e-16, 1e-12, 1000
# The report's line on this adapter.
SCIPY_DESCRIPTION = (
    "scipy L-BFGS-B: scipy.optimize.minimize(method='L-BFGS-B', jac=True, bounds=limits) on "
    "solver.ik.kinematics.ik_objective(q, g, True, data) with the IKSolver's data tuple from "
    "IKSolver.load_frame (same FK, weights w_p=1, w_r=0.01, exact gradient); "
    f"ftol={SCIPY_FTOL:g}, gtol={SCIPY_GTOL:g} (scipy's defaults 2.2e-9 / 1e-5 stop around 5e-5 m, short "
    f"of 1e-5 m), maxiter={SCIPY_MAXITER}, maxfun={20 * SCIPY_MAXITER}, maxcor=10 (default); stops as soon "
    "as an iterate is within tolerance (callback), gives no answer once 5 ms have passed (checked "
    "at each evaluation); one local run, no restarts"
)


class ScipyLBFGSB:
    """L-BFGS-B on our compiled objective f = w_p |dp|^2 + w_r |rot err|^2 (same weights,
    same FK, exact gradient). Stops at our goal (max error/tolerance <= 1, checked at each
    iterate in the callback), at the deadline (checked at each evaluation) or at scipy's
    own tests. One local run from the seed: no restarts."""

    name = "scipy L-BFGS-B (our objective)"

    def __init__(
        self, bc: BenchChain, position_only: bool, opts: IKOptions, timeout_s: float
    ) -> None:
        from scipy.optimize import Bounds, minimize

        self._minimize = minimize
        self._ik = IKSolver(bc.position if position_only else bc.pose, opts)
        self._opts = opts
        self._bounds = Bounds(bc.pose.lower, bc.pose.upper)
        self._n = bc.pose.n_dof
        self._timeout = timeout_s
        self.targets: list[list[Target]] = []
        self.settings = (
            f"ftol={SCIPY_FTOL:g}, gtol={SCIPY_GTOL:g} (defaults 2.2e-9 / 1e-5 stop near "
            f"5e-5 m), maxiter={SCIPY_MAXITER}, maxcor=10, bounds=limits; stops at our goal "
            "(errors within tolerance, checked per iterate) or the 5 ms deadline "
            "(checked per evaluation); no restarts"
        )

    def load(self, targets: list[list[Target]]) -> None:
        self.targets = targets

    def reset(self, q0: np.ndarray) -> None:
        pass

    def solve(self, k: int, seed: np.ndarray) -> tuple[np.ndarray | None, float, bool | None]:
        n = self._n
        data = self._ik.load_frame(self.targets[k], seed, options=self._opts)
        deadline = time.perf_counter() + self._timeout
        best: list[np.ndarray] = [seed]

        def fg(q: np.ndarray) -> tuple[float, np.ndarray]:
            if time.perf_counter() > deadline:
                raise _Deadline
            g = np.empty(n)
            f = ik_objective(q, g, True, data)
            return f, g

        def callback(intermediate_result: Any) -> None:  # scipy passes it by this name
            x = intermediate_result.x
            if effector_errors(x, data) <= 1.0:
                best[0] = x.copy()
                raise _GoalMet

        try:
            res = self._minimize(
                fg,
                seed,
                jac=True,
                method="L-BFGS-B",
                bounds=self._bounds,
                callback=callback,
                options={
                    "ftol": SCIPY_FTOL,
                    "gtol": SCIPY_GTOL,
                    "maxiter": SCIPY_MAXITER,
                    "maxfun": 20 * SCIPY_MAXITER,
                },
            )
            q = np.asarray(res.x, dtype=float)
        except _GoalMet:
            q = best[0]
        except _Deadline:
            return None, math.nan, None
        return q, math.nan, None
