"""Load (or compile) the numba core before the first real frame.

A fresh checkout compiles the core once (tens of seconds on these machines) and
writes it to ``solver/__pycache__``; later processes load it in about a second.
The service calls ``solver.warmup()`` at startup and reports ready only afterwards.
"""

from __future__ import annotations

import time

import numpy as np

from .ik import IKOptions, IKSolver, Target, pose_targets
from .model import Effector, EffectorMode, Joint, JointKind, Transform, build_chain
from .model.examples import panda_arm
from .path import plan_path


def warmup() -> float:
    """Run one small solve of every compiled path (and a small plan); returns the seconds
    it took."""
    start = time.perf_counter()
    for mode in (EffectorMode.POSE, EffectorMode.POSITION, EffectorMode.AIM):
        chain = panda_arm(mode)
        solver = IKSolver(chain, IKOptions(time_budget_us=None, max_iter=50))
        q = chain.mid_limits() + 0.1
        solver.solve(pose_targets(chain, q))
        solver.track(pose_targets(chain, q + 0.01))
    # The planner's kernels (solver/path/): a two-frame clip of a 7-DOF pose task.
    chain = panda_arm()
    q = chain.mid_limits() + 0.1
    planner = IKSolver(chain, IKOptions(time_budget_us=None, max_iter=50))
    planner.set_pose(q)
    plan_path(planner, [pose_targets(chain, q), pose_targets(chain, q + 0.01)])
    # A chain with no variables takes its own compiled path (errors only).
    bolt = Joint(
        name="bolt",
        parent="base",
        child="tip",
        kind=JointKind.FIXED,
        origin=Transform(np.array([0.0, 0.0, 1.0])),
    )
    fixed = IKSolver(build_chain([bolt], [Effector(name="tip", link="tip")]))
    fixed.solve([Target(effector="tip", position=np.array([0.0, 0.0, 1.0]))])
    return time.perf_counter() - start
