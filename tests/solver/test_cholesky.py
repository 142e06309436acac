"""The optimizer's Cholesky helpers against numpy, and the step from a metric's
factor against the step from its inverse (held variables included)."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from solver import IKOptions, IKSolver
from solver.ik import pose_targets
from solver.ik.kinematics import DD_HI, DD_LO, ik_objective
from solver.ik.metric import metric_inverse
from solver.model.examples import panda_arm
from solver.optim.bfgs import descent_direction, factor_direction
from solver.optim.cholesky import cholesky_in_place, cholesky_solve, inverse_from_cholesky


def _spd(n: int, seed: int) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(n, 2 * n))
    return a @ a.T / n + 1e-3 * np.eye(n)


@pytest.mark.parametrize("n", [1, 2, 7, 27])
def test_factor_solve_and_inverse_match_numpy(n: int) -> None:
    a = _spd(n, n)
    m = a.copy()
    m[np.triu_indices(n, 1)] = 7.0  # the strict upper triangle is not read
    assert cholesky_in_place(m, n)
    low = np.tril(m)
    assert_allclose(low, np.linalg.cholesky(a), rtol=1e-10, atol=1e-12)
    assert (m[np.triu_indices(n, 1)] == 7.0).all()  # ... nor written
    b = np.random.default_rng(1).normal(size=n)
    out = np.empty(n)
    cholesky_solve(m, b, out)
    assert_allclose(out, np.linalg.solve(a, b), rtol=1e-9)
    inverse_from_cholesky(m)
    assert_allclose(m, np.linalg.inv(a), rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(m, m.T)


def test_a_matrix_that_is_not_positive_definite_is_refused() -> None:
    m = _spd(5, 2)
    m[3, 3] = -1.0
    assert not cholesky_in_place(m, 5)


def test_the_step_from_the_factor_is_the_step_from_the_inverse() -> None:
    """The metric leaves held variables (on a bound, the gradient pushing out) out of
    the coupling: a row of their own. The factor's step and the inverse's step then
    agree, with 0 for the held ones."""
    n = 6
    a = _spd(n, 4)
    lo = np.full(n, -1.0)
    hi = np.full(n, 1.0)
    x = np.array([0.2, 1.0, -0.3, -1.0, 0.0, 0.5])
    # x[1] held (at hi, pushed up); x[3] at lo but pulled inside: free.
    g = np.array([0.3, -2.0, 0.1, -0.4, -0.7, 0.2])
    held = np.array([False, True, False, False, False, False])
    a[held, :] = 0.0
    a[:, held] = 0.0
    a[held, held] = 0.5
    inv = np.linalg.inv(a)
    factor = a.copy()
    assert cholesky_in_place(factor, n)
    d_inv, d_fac = np.empty(n), np.empty(n)
    slope_inv = descent_direction(inv, g, x, lo, hi, d_inv, np.empty(n))
    slope_fac = factor_direction(factor, g, x, lo, hi, d_fac, np.empty(n))
    assert d_fac[1] == 0.0 and d_inv[1] == 0.0
    assert d_fac[3] > 0.0
    assert_allclose(d_fac, d_inv, rtol=1e-10, atol=1e-14)
    assert slope_fac < 0.0
    assert slope_fac == pytest.approx(slope_inv, rel=1e-10)


def test_a_solve_hands_back_an_inverse_when_its_last_metric_was_a_factor() -> None:
    """A solve cut off right after a metric re-seeded H (as its factor) hands back H
    itself: the factor completed, symmetric positive definite, and the metric's
    inverse at the point where it stopped."""
    chain = panda_arm()
    targets = pose_targets(chain, chain.mid_limits() + 0.6)
    options = IKOptions(max_iter=1, max_restarts=0, time_budget_us=None)
    solver = IKSolver(chain, options)
    result = solver.solve(targets)
    assert not result.success and result.iterations == 1
    h = result.inverse_hessian
    np.testing.assert_array_equal(h, h.T)
    assert np.linalg.eigvalsh(h).min() > 0.0
    data = solver.load_frame(targets, chain.mid_limits())  # as the solve loaded them
    g = np.empty(chain.n_dof)
    ik_objective(result.q, g, True, data)
    expected = np.empty_like(h)
    assert metric_inverse(result.q, g, data[4][DD_LO], data[4][DD_HI], data, expected)
    assert_allclose(h, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
