"""Property tests of the optimizer (Hypothesis) and the plain-Python mode of the core."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from solver import MinimizeOptions, minimize

from .objectives import NONCONVEX, QUADRATIC, ROSENBROCK, make_data, toy_objective


@st.composite
def boxed_problem(draw):  # type: ignore[no-untyped-def]
    n = draw(st.integers(2, 6))
    seed = draw(st.integers(0, 2**32 - 1))
    kind = draw(st.sampled_from([QUADRATIC, NONCONVEX, ROSENBROCK]))
    rng = np.random.default_rng(seed)
    m = rng.normal(size=(n, n))
    a = m @ m.T + 0.1 * np.eye(n)
    b = rng.normal(size=n) * 2.0
    lo = rng.uniform(-3.0, 0.0, n)
    hi = lo + rng.uniform(0.0, 3.0, n)  # may be degenerate (lo == hi) in a coordinate
    x0 = rng.uniform(-5.0, 5.0, n)  # often outside the box: it must be projected
    if kind == ROSENBROCK and n % 2:
        n -= 1
        a, b, lo, hi, x0 = a[:n, :n], b[:n], lo[:n], hi[:n], x0[:n]
    return make_data(kind, b, a), x0, lo, hi


@given(boxed_problem(), st.booleans())
def test_steps_stay_in_the_box_and_never_raise_f(problem, curvature: bool) -> None:  # type: ignore[no-untyped-def]
    data, x0, lo, hi = problem
    opts = MinimizeOptions(curvature=curvature, max_iter=200)
    r = minimize(toy_objective, x0, bounds=(lo, hi), data=data, options=opts, record_steps=True)
    assert np.all(r.x >= lo) and np.all(r.x <= hi)
    f0 = toy_objective(np.clip(x0, lo, hi), np.zeros_like(x0), False, data)
    assert r.f <= f0
    for s in r.steps:
        assert s.bound_slack >= 0.0
        assert s.f_after <= s.f_before + opts.armijo_c1 * s.decrease
        assert s.f_after <= s.f_before


def test_plain_python_mode_runs_the_same_code() -> None:
    """NUMBA_DISABLE_JIT=1 runs the one implementation as Python (debugging, coverage)."""
    script = textwrap.dedent(
        """
        import numpy as np
        from solver import IKOptions, IKSolver, minimize
        from solver.model.examples import panda_arm
        from solver.ik import pose_targets
        from tests.solver.objectives import ROSENBROCK, make_data, toy_objective
        data = make_data(ROSENBROCK, np.zeros(2), np.zeros((1, 1)))
        r = minimize(toy_objective, [-1.2, 1.0], data=data)
        assert r.f < 1e-10, r.f
        chain = panda_arm()
        s = IKSolver(chain, IKOptions(time_budget_us=None))
        res = s.solve(pose_targets(chain, chain.mid_limits() + 0.2))
        assert res.success, res.status
        print("ok", r.iterations, res.iterations)
        """
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    out = subprocess.run(
        [sys.executable, "-W", "error", "-c", script],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))),
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.startswith("ok")
