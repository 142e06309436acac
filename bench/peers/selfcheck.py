"""Self-check of the peers: FK against pinocchio, and a quick solve rate.

    OPENBLAS_NUM_THREADS=1 python -m bench.peers.selfcheck [--n 50] [--timeout 0.005] [--extra]

The reference FK is pinocchio on the FULL URDF model (not the peers' reduced one), tip
frame relative to base frame. A solve succeeds when, by that FK, |dp| <= 1e-5 m, the
angle of R_target^T R <= 1e-4 rad (pose targets only) and every joint is within limits.
Targets are FK of uniform random q within limits; the seed is mid-limits (TRAC-IK protocol).
"track" follows 100 frames of a smooth joint path (cosine blend between two random q: peak
step 1.6% of each joint's travel per frame, ~0.1 rad on Panda/iiwa, up to 0.2 rad on UR5;
the path may cross singularities), each solve seeded with the previous answer.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from bench.peers import SKIPPED, PeerSolver, available_peers
from bench.robots import ROBOTS, RobotSpec, robot

POS_TOL, ROT_TOL = 1e-5, 1e-4


def reference_fk(spec: RobotSpec) -> Callable[[np.ndarray], np.ndarray]:
    model = pin.buildModelFromUrdf(str(spec.urdf_path))
    data = model.createData()
    idx = [model.joints[model.getJointId(n)].idx_q for n in spec.joint_names]
    base, tip = model.getFrameId(spec.base_link), model.getFrameId(spec.tip_link)

    def fk(q: np.ndarray) -> np.ndarray:
        qf = pin.neutral(
            model
        )  # off-chain joints (Panda fingers) at neutral: they hang below the tip
        qf[idx] = q
        pin.framesForwardKinematics(model, data, qf)
        return data.oMf[base].actInv(data.oMf[tip]).homogeneous

    return fk


def errors(T: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """(position error in m, rotation angle of R_target^T R in rad)."""
    return (
        float(np.linalg.norm(T[:3, 3] - target[:3, 3])),
        float(np.linalg.norm(pin.log3(target[:3, :3].T @ T[:3, :3]))),
    )


def check_peer(
    spec: RobotSpec,
    peer: PeerSolver,
    fk: Callable[[np.ndarray], np.ndarray],
    qs_fk: np.ndarray,
    qs_ik: np.ndarray,
    timeout_s: float,
) -> dict[str, str]:
    fk_err = max(float(np.abs(peer.fk(q) - fk(q)).max()) for q in qs_fk)
    row = {"robot": spec.name, "peer": peer.name, "fk max|dT|": f"{fk_err:.1e}"}
    for position_only in (False, True):
        ok, times = 0, []
        for q in qs_ik:
            target = fk(q)
            t0 = time.perf_counter()
            sol = peer.solve(target, spec.mid(), position_only=position_only, timeout_s=timeout_s)
            times.append(time.perf_counter() - t0)
            if sol is None or np.any(sol < spec.lower) or np.any(sol > spec.upper):
                continue
            dp, dr = errors(fk(sol), target)
            ok += dp <= POS_TOL and (position_only or dr <= ROT_TOL)
        kind = "pos" if position_only else "pose"
        row[f"{kind} ok"] = f"{ok}/{len(qs_ik)}"
        row[f"{kind} median ms"] = f"{1e3 * float(np.median(times)):.2f}"
    # tracking: a smooth joint path sampled at 100 frames, each solve seeded with the
    # previous answer (the first with the true start, as a tracker would be)
    t = np.linspace(0.0, 1.0, 100)[:, None]
    a, b = qs_ik[0], qs_ik[1]
    path = a + (b - a) * 0.5 * (1 - np.cos(np.pi * t))
    seed, ok, times = path[0], 0, []
    for q in path:
        target = fk(q)
        t0 = time.perf_counter()
        sol = peer.solve(target, seed, position_only=False, timeout_s=timeout_s)
        times.append(time.perf_counter() - t0)
        if sol is not None and np.all(sol >= spec.lower) and np.all(sol <= spec.upper):
            dp, dr = errors(fk(sol), target)
            ok += dp <= POS_TOL and dr <= ROT_TOL
            seed = sol
    row["track ok"] = f"{ok}/{len(path)}"
    row["track median ms"] = f"{1e3 * float(np.median(times)):.2f}"
    # does the peer keep to the budget when it cannot succeed? (targets 10 m out of reach)
    worst = 0.0
    for q in qs_ik[:5]:
        far = fk(q)
        far[:3, 3] += 10.0
        t0 = time.perf_counter()
        peer.solve(far, spec.mid(), position_only=False, timeout_s=timeout_s)
        worst = max(worst, time.perf_counter() - t0)
    row["unreachable max ms"] = f"{1e3 * worst:.2f}"
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=50, help="IK targets per robot")
    ap.add_argument("--timeout", type=float, default=0.005, help="budget per solve, s")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--extra", action="store_true", help="also the variants (rtb NR/GN, CLIK dt=1)")
    ap.add_argument("--robots", nargs="*", default=list(ROBOTS))
    args = ap.parse_args()

    rows: list[dict[str, str]] = []
    for name in args.robots:
        spec = robot(name)
        fk = reference_fk(spec)
        rng = np.random.default_rng(args.seed)
        qs_fk = rng.uniform(spec.lower, spec.upper, (20, spec.dof))
        qs_ik = rng.uniform(spec.lower, spec.upper, (args.n, spec.dof))
        for peer in available_peers(spec, extra=args.extra):
            rows.append(check_peer(spec, peer, fk, qs_fk, qs_ik, args.timeout))

    cols = list(rows[0]) if rows else []
    print(
        f"timeout {1e3 * args.timeout:g} ms, {args.n} targets, seed = mid-limits, "
        f"success: |dp| <= {POS_TOL:g} m, angle <= {ROT_TOL:g} rad, within limits\n"
    )
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(r[c] for c in cols) + " |")
    for what, why in SKIPPED.items():
        print(f"\nskipped {what}: {why}")


if __name__ == "__main__":
    main()
