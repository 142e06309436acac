"""Pinocchio's closed-loop IK example ("inverse kinematics (clik)" in its docs), on a frame.

Same loop as the docs: err = log6(oMtip^-1 * oMdes) in the tip frame, J = -Jlog6 * J_local,
damped least squares v = -J^T (J J^T + damp I)^-1 err, q <- integrate(q, v * DT).
Changes, each because the benchmark needs it: eps tightened (docs: 1e-4), q clipped to
the joint limits after each step, a wall-clock deadline next to IT_MAX, and a
position-only variant (3 rows: world-aligned translation error and Jacobian).
"""

from __future__ import annotations

import math
import time

import numpy as np
import pinocchio as pin

from bench.robots import RobotSpec

# |log6| < eps. For small errors log6's linear part ~ the translation error, so 1e-6 leaves
# a 10x margin under 1e-5 m (and far under 1e-4 rad). DT = 0.1 makes the loop contract the
# error by ~0.9 per step, so each extra decade costs ~22 iterations.
EPS = 1e-6
IT_MAX = 1000  # docs value
DT = 1e-1  # docs value
DAMP = 1e-12  # docs value


def reduced_model(robot: RobotSpec) -> tuple[pin.Model, list[int]]:
    """Pinocchio model with every joint off the base->tip chain locked (Panda fingers),
    and for each chain joint its index in q."""
    full = pin.buildModelFromUrdf(str(robot.urdf_path))
    keep = set(robot.joint_names)
    lock = [full.getJointId(n) for n in full.names[1:] if n not in keep]
    model = pin.buildReducedModel(full, lock, pin.neutral(full)) if lock else full
    if model.nq != model.nv:
        raise ValueError("continuous joints (nq != nv) are not handled")
    idx = [model.joints[model.getJointId(n)].idx_q for n in robot.joint_names]
    return model, idx


class PinClik:
    def __init__(
        self,
        robot: RobotSpec,
        *,
        eps: float = EPS,
        dt: float = DT,
        damp: float = DAMP,
        it_max: int = IT_MAX,
    ) -> None:
        # knobs are exposed so a variant (e.g. dt=1, plain damped Gauss-Newton) can be
        # benchmarked too; the defaults are the docs' loop
        self._eps, self._dt, self._it_max = eps, dt, it_max
        self._damp6, self._damp3 = damp * np.eye(6), damp * np.eye(3)
        changed = [
            f"{k}={v:g}"
            for k, v, d in (
                ("eps", eps, EPS),
                ("dt", dt, DT),
                ("damp", damp, DAMP),
                ("it_max", it_max, IT_MAX),
            )
            if v != d
        ]
        self.name = "pinocchio CLIK (docs example" + "".join(", " + c for c in changed) + ")"
        self.settings = (
            f"eps={eps:g} on |log6|, DT={dt:g}, damp={damp:g}, IT_MAX={it_max}, "
            "clip to limits each step, deadline checked each step"
        )
        self._model, self._idx = reduced_model(robot)
        self._data = self._model.createData()
        self._base = self._model.getFrameId(robot.base_link)
        self._tip = self._model.getFrameId(robot.tip_link)
        self.joint_names = robot.joint_names
        self.lower, self.upper = robot.lower, robot.upper
        # base_link hangs off the universe by fixed joints only, so oMbase never moves
        pin.framesForwardKinematics(self._model, self._data, pin.neutral(self._model))
        self._oMbase = pin.SE3(self._data.oMf[self._base])
        self._lo = self._model.lowerPositionLimit.copy()
        self._hi = self._model.upperPositionLimit.copy()

    def _to_pin(self, q: np.ndarray) -> np.ndarray:
        qp = pin.neutral(self._model)
        qp[self._idx] = q
        return qp

    def fk(self, q: np.ndarray) -> np.ndarray:
        pin.framesForwardKinematics(self._model, self._data, self._to_pin(np.asarray(q, float)))
        return (self._oMbase.actInv(self._data.oMf[self._tip])).homogeneous

    def solve(
        self, target: np.ndarray, seed: np.ndarray, *, position_only: bool, timeout_s: float
    ) -> np.ndarray | None:
        deadline = time.perf_counter() + timeout_s
        m, d, tip = self._model, self._data, self._tip
        oMdes = self._oMbase * pin.SE3(np.asarray(target, dtype=float))
        q = self._to_pin(np.asarray(seed, dtype=float))
        damp = self._damp3 if position_only else self._damp6
        for _ in range(self._it_max):
            pin.framesForwardKinematics(m, d, q)
            if position_only:
                err = d.oMf[tip].translation - oMdes.translation  # world frame
            else:
                iMd = d.oMf[tip].actInv(oMdes)
                err = pin.log(iMd).vector  # tip frame
            if math.sqrt(err @ err) < self._eps:
                return q[self._idx].copy()
            if time.perf_counter() > deadline:
                return None
            if position_only:
                J = pin.computeFrameJacobian(m, d, q, tip, pin.LOCAL_WORLD_ALIGNED)[:3]
                v = -J.T @ np.linalg.solve(J @ J.T + damp, err)
            else:
                J = -pin.Jlog6(iMd.inverse()) @ pin.computeFrameJacobian(m, d, q, tip, pin.LOCAL)
                v = -J.T @ np.linalg.solve(J @ J.T + damp, err)
            q = np.minimum(np.maximum(pin.integrate(m, q, v * self._dt), self._lo), self._hi)
        return None
