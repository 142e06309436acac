"""Probe of 2026-11-30-first-frame-miss.md: sessions whose first frame misses a
reachable pose target (the service's stream options at a budget that makes some miss):
how many frames of the same target until one is solved, when the stream keeps to the
step limit around a first answer that missed (``before``, emulated by marking the
solver solved) or is solved as under ``reach`` until a frame is (``now``).

    OPENBLAS_NUM_THREADS=1 python bench/history/first_frame_probe.py ur5 150 300

(from the repository root: chain, budget in us, sessions).
"""

# ruff: noqa: E402  (the repository root goes on sys.path before the imports)

import sys
from dataclasses import replace

import numpy as np

sys.path.insert(0, ".")
from bench.ik_chains import load
from solver.ik import STREAM_DEFAULTS, IKSolver, Target
from solver.model.forward import effector_poses

name, budget, sessions = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
chain = load(name).pose
options = replace(
    STREAM_DEFAULTS,
    time_budget_us=budget,
    position_tolerance_m=1e-4,
    rotation_tolerance_rad=1e-3,
)
rng = np.random.default_rng(1)
frames_to_solve: dict[str, list[int]] = {"before": [], "now": []}
for i in range(sessions):
    q = rng.uniform(np.maximum(chain.lower, -np.pi), np.minimum(chain.upper, np.pi))
    pose = effector_poses(chain, q)[0]
    target = [Target(effector=chain.effectors[0].name, position=pose[:3, 3], rotation=pose[:3, :3])]
    for label, counts in frames_to_solve.items():
        solver = IKSolver(chain, options, seed=i)
        r = solver.track(target)
        if r.success:
            continue
        if label == "before":
            solver._anchored = True  # any first answer, missed or not, was one to stay near
        k = 1
        while not r.success and k < 30:
            r = solver.track(target)
            k += 1
        counts.append(k if r.success else 99)
for label, counts in frames_to_solve.items():
    ks = np.array(counts, dtype=int)
    print(
        f"{name} {label}: first frame missed {len(ks)} of {sessions}; solved by frame 2: "
        f"{np.sum(ks <= 2)}, by 10: {np.sum(ks <= 10)}, never in 30: {np.sum(ks == 99)}"
    )
