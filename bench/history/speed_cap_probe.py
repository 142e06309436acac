"""Probe of 2026-11-30-speed-cap.md (issue 22): the default policy (``smooth``) with its
per-frame step cap taken from the targets' own speed, beside the fixed 0.1 rad cap, on
the streams of ``bench.tracking`` (no time budget, the benchmark's tolerances).

Before each frame the cap is ``min(0.1, max(1e-3, k * m))``, ``m`` the largest, over
the frames so far, of the largest joint move of the damped least-squares step (damping
``lam``) that makes the target's move, at the previous answer (finite-difference
Jacobian). Unlike a cap that follows the arm's own steps
(2026-11-29-adaptive-step-cap.md) it does not compound while the arm lags.

    OPENBLAS_NUM_THREADS=1 python bench/history/speed_cap_probe.py iiwa pose 12 1.5 0.01

(from the repository root: chain, mode, streams, k, lam; needs the benchmark extras).
"""

# ruff: noqa: E402  (the repository root goes on sys.path before the imports)

import math
import sys
from dataclasses import replace

import numpy as np

sys.path.insert(0, ".")
from bench.tracking import CHAINS, FPS, chain, largest_steps, policies, within_tolerance
from bench.tracking_streams import PeerChain, make_stream
from solver.ik import IKSolver, Target
from solver.model import Chain
from solver.model.forward import effector_poses


def rotation_vector(r: np.ndarray) -> np.ndarray:
    angle = math.acos(max(-1.0, min(1.0, 0.5 * (float(np.trace(r)) - 1.0))))
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    s = math.sin(angle)
    return v * (0.5 if s < 1e-9 else angle / (2.0 * s))


def twist(a: np.ndarray, b: np.ndarray, position: bool) -> np.ndarray:
    dp = b[:3, 3] - a[:3, 3]
    return dp if position else np.concatenate([dp, rotation_vector(b[:3, :3] @ a[:3, :3].T)])


def jacobian(model: Chain, q: np.ndarray, position: bool, h: float = 1e-6) -> np.ndarray:
    x0 = effector_poses(model, q)[0]
    columns = []
    for i in range(len(q)):
        dq = q.copy()
        dq[i] += h
        columns.append(twist(x0, effector_poses(model, dq)[0], position) / h)
    return np.array(columns).T


name, mode = sys.argv[1], sys.argv[2]
n_streams, k, lam = int(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5])
position = mode == "position"
bc = chain(name)
assert bc.spec is not None
peer_chain = PeerChain(bc.spec, lambda q: effector_poses(bc.pose, bc.to_ours(q))[0])
base = policies(None)["default"]
model = bc.position if position else bc.pose
counts = {"fixed": [0, 0.0], "speed": [0, 0.0]}
for si in range(n_streams):
    stream = make_stream(peer_chain, 0, CHAINS.index(name), si, 600, FPS)
    path = np.array([bc.to_ours(q) for q in stream.path])
    poses = np.array([effector_poses(bc.pose, q)[0] for q in path])
    e = bc.effector
    targets = [
        [Target(effector=e, position=p[:3, 3].copy())]
        if position
        else [Target(effector=e, position=p[:3, 3].copy(), rotation=p[:3, :3].copy())]
        for p in poses
    ]
    line = f"{si:3d} {stream.kind:13s} reference step {stream.largest_step:.4f}"
    for label, count in counts.items():
        solver = IKSolver(model, base)
        solver.set_pose(path[0])
        qs = np.empty((len(targets), model.n_dof))
        fastest = 0.0
        for t, frame in enumerate(targets):
            options = base
            if label == "speed" and t > 0:
                jac = jacobian(bc.pose, solver.q, position)
                dx = twist(poses[t - 1], poses[t], position)
                step = jac.T @ np.linalg.solve(jac @ jac.T + lam**2 * np.eye(len(dx)), dx)
                fastest = max(fastest, float(np.abs(step).max()))
                options = replace(base, max_joint_step_rad=min(0.1, max(1e-3, k * fastest)))
            qs[t] = solver.track(frame, options=options).q
        worst = float(largest_steps(path[0], qs).max())
        within = float(within_tolerance(bc, position, qs, poses).mean())
        count[0] += worst <= 2.0 * stream.largest_step
        count[1] += within
        line += f" | {label} {worst / stream.largest_step:6.2f}x {100 * within:6.2f}%"
    print(line, flush=True)
for label, (within_2x, frames) in counts.items():
    print(
        f"{name} {mode} {label} (k={k}, lam={lam}): streams within 2x {within_2x} of "
        f"{n_streams}, frames within tolerance {100 * frames / n_streams:.2f}%"
    )
