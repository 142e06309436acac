"""The IK solve runs the core compiled without reference counting (``run_solver_leaf``,
see ``solver._jit.jit_leaf``); the generic ``run_solver`` is the same body compiled
normally, with its work arrays allocated inside. Both must take the same iterates to
the bit: the build changes what numba counts, never what the solver computes."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from solver import EffectorMode, IKOptions, IKSolver
from solver.ik import pose_targets
from solver.ik.kinematics import DD_HI, DD_LO, DD_QREF
from solver.model import Chain, Effector, build_chain
from solver.model.examples import humanoid_arm, panda_arm, tail
from solver.optim import codes as C
from solver.optim.loop import WORK_ROWS, run_solver, run_solver_leaf
from solver.optim.minimize import pack_options


def _tail_with_two_points() -> Chain:
    """Two position effectors on 40 variables: the metric stacks their rows in DD."""
    base = tail(20)
    return build_chain(
        list(base.joints),
        [*base.effectors, Effector(name="middle", link="seg10", mode=EffectorMode.POSITION)],
    )


def _run(
    core: Callable[..., tuple[float, ...]], solver: IKSolver, targets, x0: np.ndarray, leaf: bool
):  # type: ignore[no-untyped-def]
    """One core call on private copies of everything the core writes."""
    fopt, iopt = pack_options(solver.options.minimize_options(), seed=0)
    data = tuple(a.copy() for a in solver.load_frame(targets, x0))
    dd = data[4]
    dd[DD_QREF] = x0
    n = x0.shape[0]
    h = np.eye(n)
    log = np.zeros((16, C.N_LOG))
    out_x = np.empty(n)
    out_g = np.empty(n)
    policy = solver.options.policy.as_array()
    trace = np.empty((0, 5))
    if leaf:
        # Garbage in the work blocks: the core must not read what it has not written.
        work = np.full((WORK_ROWS, n), np.nan)
        ints = np.full(3, -7, dtype=np.int64)
        res = core(
            None, data, x0, h, dd[DD_LO], dd[DD_HI], fopt, iopt, policy, log, trace, out_x,
            out_g, work, ints,
        )  # fmt: skip
    else:
        res = core(
            None, data, x0, h, dd[DD_LO], dd[DD_HI], fopt, iopt, policy, log, trace, out_x, out_g
        )
    return res[:-1], out_x, out_g, h, log  # res[-1] is the elapsed time


@pytest.mark.parametrize(
    "factory",
    [panda_arm, lambda: panda_arm(EffectorMode.POSITION), humanoid_arm, _tail_with_two_points],
)
@pytest.mark.parametrize("curvature", [False, True])  # True: the search's kept point
def test_leaf_core_takes_the_generic_cores_iterates(factory, curvature: bool) -> None:  # type: ignore[no-untyped-def]
    chain = factory()
    rng = np.random.default_rng(5)
    lo = np.where(np.isfinite(chain.lower), chain.lower, -np.pi)
    hi = np.where(np.isfinite(chain.upper), chain.upper, np.pi)
    # A budget that never runs out, so that timing cannot change a path.
    solver = IKSolver(chain, IKOptions(curvature=curvature, time_budget_us=None))
    for _ in range(3):
        targets = pose_targets(chain, rng.uniform(lo, hi))
        solver.solve(targets)  # sets the options' weights in the compiled arrays
        x0 = rng.uniform(lo, hi)
        generic = _run(run_solver, solver, targets, x0, leaf=False)
        leaf = _run(run_solver_leaf, solver, targets, x0, leaf=True)
        assert generic[0] == leaf[0]  # f, goal, pg, code, iterations, evaluations, ...
        assert generic[0][4] > 0  # it iterated
        for a, b in zip(generic[1:], leaf[1:], strict=True):
            np.testing.assert_array_equal(a, b)
