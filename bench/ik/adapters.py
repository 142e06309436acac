"""The solvers under test behind one small protocol: ours (per frame and planned) and
the peers of bench/peers/. scipy's L-BFGS-B is in scipy_lbfgsb.py."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from bench.ik_chains import BenchChain
from bench.peers import PeerSolver
from solver.ik import STREAM_DEFAULTS, IKOptions, IKSolver, Target
from solver.path import PlannedPath, plan_path

from .config import POS_TOL, ROT_TOL


def ours_options(
    metric_every: int = 1, stream: bool = False, carry: bool = False, budget_us: float = 5000.0
) -> IKOptions:
    base = STREAM_DEFAULTS if stream else IKOptions()
    return replace(
        base,
        position_tolerance_m=POS_TOL,
        rotation_tolerance_rad=ROT_TOL,
        time_budget_us=budget_us,
        metric_every=metric_every,
        carry_hessian=carry,
    )


def ours_settings(o: IKOptions) -> str:
    rr = "inf" if math.isinf(o.restart_radius_rad) else f"{o.restart_radius_rad:g}"
    s = (
        f"metric_every={o.metric_every}, damping_scale={o.damping_scale:g}, "
        f"max_restarts={o.max_restarts}, restart_radius={rr}, "
        f"max_iter={o.max_iter}, tol {o.position_tolerance_m:g} m / {o.rotation_tolerance_rad:g} rad, "
        f"budget {o.time_budget_us:g} us"
    )
    if o.limit_weight or o.posture_weight:
        s += f", limit_weight={o.limit_weight:g} (margin {o.limit_margin:g}), posture_weight={o.posture_weight:g}"
    if o.damping:
        only = " (redundant tasks only)" if o.damping_redundant_only else ""
        s += f", damping floor {o.damping:g}{only}"
    if o.metric_until:
        s += f", metric_until={o.metric_until}"
    if o.null_space_step_rad:
        s += f", null_space_step_rad={o.null_space_step_rad:g}"
    if o.global_fallback:
        s += ", global_fallback=True"
    if o.carry_hessian:
        s += ", carry_hessian=True"
    return s


# Each adapter: solve(k, seed_ours) -> (q in our variable order or None, core_us or nan,
# own success flag or None); the wall time is taken around this call by the runner.
class Adapter(Protocol):
    """What the runner needs from a solver: load the frame's targets, reset a stream,
    solve frame k -> (q in our variable order or None, in-core us or nan, own flag)."""

    name: str
    settings: str

    def load(self, targets: Any) -> None: ...

    def reset(self, q0: np.ndarray) -> None: ...

    def solve(self, k: int, seed: np.ndarray) -> tuple[np.ndarray | None, float, bool | None]: ...


class Ours:
    def __init__(
        self, bc: BenchChain, position_only: bool, opts: IKOptions, label: str, track: bool = False
    ) -> None:
        self.solver = IKSolver(bc.position if position_only else bc.pose, opts)
        self.opts, self.track = opts, track
        self.name, self.settings = label, ours_settings(opts)
        self.targets: list[list[Target]] = []

    def load(self, targets: list[list[Target]]) -> None:
        self.targets = targets

    def reset(self, q0: np.ndarray) -> None:
        self.solver.set_pose(q0)

    def solve(self, k: int, seed: np.ndarray) -> tuple[np.ndarray | None, float, bool | None]:
        if self.track:
            r = self.solver.track(self.targets[k])
        else:
            r = self.solver.solve(self.targets[k], seed)
        return r.q, r.solve_us, r.success


class OursPlanned:
    """``IKSolver.plan`` over a whole stream (part (c) only): the stream is planned at
    once, after the frame-by-frame solvers have run it; each frame is charged the
    plan's time divided by the frames."""

    def __init__(self, bc: BenchChain, opts: IKOptions, label: str) -> None:
        self.solver = IKSolver(bc.pose, opts)
        self.opts = opts
        self.name, self.settings = label, ours_settings(opts)
        self.targets: list[list[Target]] = []
        self._planned: PlannedPath | None = None

    def load(self, targets: list[list[Target]]) -> None:
        self.targets = targets
        self._planned = None

    def reset(self, q0: np.ndarray) -> None:
        self.solver.set_pose(q0)
        self._planned = None

    def plan(self) -> PlannedPath:
        self._planned = plan_path(self.solver, self.targets)
        return self._planned

    def solve(self, k: int, seed: np.ndarray) -> tuple[np.ndarray | None, float, bool | None]:
        planned = self._planned or self.plan()
        r = planned.results[k]
        return r.q, planned.plan_us / len(planned.results), r.success


class Peer:
    def __init__(
        self, bc: BenchChain, peer: PeerSolver, position_only: bool, timeout_s: float
    ) -> None:
        self.bc, self.peer, self.position_only, self.timeout_s = bc, peer, position_only, timeout_s
        self.name, self.settings = peer.name, peer.settings
        self.poses: np.ndarray = np.empty((0, 4, 4))
        self.prev: np.ndarray | None = None
        self.track = False

    def load(self, poses: np.ndarray) -> None:
        self.poses = poses

    def reset(self, q0: np.ndarray) -> None:
        self.prev = self.bc.to_peer(q0)

    def solve(self, k: int, seed: np.ndarray) -> tuple[np.ndarray | None, float, bool | None]:
        s = self.prev if self.track and self.prev is not None else self.bc.to_peer(seed)
        q = self.peer.solve(
            self.poses[k], s, position_only=self.position_only, timeout_s=self.timeout_s
        )
        if q is None:
            return None, math.nan, False
        if self.track:
            self.prev = np.asarray(q, dtype=float)
        return self.bc.to_ours(np.asarray(q, dtype=float)), math.nan, True


def peer_key(p: PeerSolver) -> str:
    name = p.name.lower()
    return (
        "rtb"
        if name.startswith("rtb ik_lm")
        else "ikpy"
        if name.startswith("ikpy")
        else "clik"
        if name.startswith("pinocchio")
        else name
    )
