"""The optimizer on small problems: convergence, bounds, budgets, codes, line search."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.optimize import minimize as scipy_minimize

from solver import (
    Action,
    GradientMode,
    InvalidProblem,
    MinimizeOptions,
    PassStart,
    Termination,
    minimize,
)
from solver.optim import codes as C
from solver.optim.evaluate import evaluate

from .objectives import (
    NAN_REGION,
    NONCONVEX,
    QUADRATIC,
    ROSENBROCK,
    WRONG_GRADIENT,
    make_data,
    toy_objective,
)


def spd(rng: np.random.Generator, n: int, cond: float = 10.0) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return q @ np.diag(np.geomspace(1.0, cond, n)) @ q.T


def quadratic(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, ...]:
    return make_data(QUADRATIC, b, a)


def rosenbrock(n: int) -> tuple[np.ndarray, ...]:
    return make_data(ROSENBROCK, np.zeros(n), np.zeros((1, 1)))


def scipy_fg(data: tuple[np.ndarray, ...]):  # type: ignore[no-untyped-def]
    def fg(x: np.ndarray) -> tuple[float, np.ndarray]:
        g = np.zeros_like(x)
        return float(toy_objective(np.ascontiguousarray(x), g, True, data)), g

    return fg


def test_quadratic_reaches_exact_minimizer(rng: np.random.Generator) -> None:
    a = spd(rng, 6)
    b = rng.normal(size=6)
    res = minimize(
        toy_objective, np.zeros(6), data=quadratic(a, b), options=MinimizeOptions(gtol=1e-10)
    )
    assert res.termination in (Termination.GTOL, Termination.STEP_SMALL)
    assert_allclose(res.x, np.linalg.solve(a, b), rtol=0, atol=1e-9)
    assert res.projected_gradient_norm <= 1e-9


def test_exact_initial_inverse_hessian_takes_one_newton_step(rng: np.random.Generator) -> None:
    a = spd(rng, 5)
    b = rng.normal(size=5)
    res = minimize(
        toy_objective,
        np.zeros(5),
        data=quadratic(a, b),
        initial_inverse_hessian=np.linalg.inv(a),
        options=MinimizeOptions(gtol=1e-10),
    )
    assert res.iterations == 1
    assert_allclose(res.x, np.linalg.solve(a, b), rtol=0, atol=1e-10)


@pytest.mark.parametrize("n", [2, 10])
@pytest.mark.parametrize("gradient", list(GradientMode))
def test_rosenbrock_from_standard_start(n: int, gradient: GradientMode) -> None:
    x0 = np.tile([-1.2, 1.0], n // 2)
    res = minimize(
        toy_objective, x0, data=rosenbrock(n), options=MinimizeOptions(gradient=gradient)
    )
    tol = 1e-6 if gradient is GradientMode.FORWARD else 1e-9
    assert res.f <= tol
    assert_allclose(
        res.x, np.ones(n), rtol=0, atol=1e-3 if gradient is GradientMode.FORWARD else 1e-5
    )


@pytest.mark.parametrize("mode", [GradientMode.FORWARD, GradientMode.CENTRAL])
def test_finite_difference_gradient_agrees_with_analytic(
    rng: np.random.Generator, mode: GradientMode
) -> None:
    data = make_data(NONCONVEX, rng.normal(size=4), spd(rng, 4))
    lo = np.full(4, -np.inf)
    hi = np.full(4, np.inf)
    for _ in range(5):
        x = rng.normal(size=4)
        g_exact = np.zeros(4)
        g_fd = np.zeros(4)
        counters = np.zeros(2, dtype=np.int64)
        toy_objective(x, g_exact, True, data)
        code = C.GRAD_FORWARD if mode is GradientMode.FORWARD else C.GRAD_CENTRAL
        evaluate(None, data, x.copy(), g_fd, True, code, lo, hi, np.zeros(4), counters)
        tol = 1e-6 if mode is GradientMode.FORWARD else 1e-9
        assert_allclose(g_fd, g_exact, rtol=tol, atol=tol)
        assert counters[0] == (5 if mode is GradientMode.FORWARD else 9)


def test_finite_differences_never_step_outside_the_box() -> None:
    # On the upper bound a forward step would leave the box: it must go backwards.
    data = make_data(NAN_REGION, np.array([1.0, 0.0, 0.0]), np.eye(2))
    x = np.array([1.0, 1.0])
    g = np.zeros(2)
    counters = np.zeros(2, dtype=np.int64)
    f = evaluate(
        None,
        data,
        x,
        g,
        True,
        C.GRAD_FORWARD,
        np.full(2, -1.0),
        np.full(2, 1.0),
        np.zeros(2),
        counters,
    )
    assert math.isfinite(f)
    assert np.isfinite(g).all()
    assert_allclose(g, [1.0, 1.0], rtol=0, atol=1e-6)


@pytest.mark.parametrize("seed", range(6))
def test_bound_constrained_minimum_matches_scipy_lbfgsb(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 5
    a = spd(rng, n, cond=50.0)
    b = rng.normal(size=n) * 3.0
    x_free = np.linalg.solve(a, b)
    # A box that cuts the unconstrained minimizer off in at least one coordinate.
    lo = x_free - rng.uniform(0.5, 1.5, n)
    hi = x_free + rng.uniform(0.5, 1.5, n)
    k = int(rng.integers(n))
    hi[k] = x_free[k] - 0.3
    lo[k] = hi[k] - 1.0
    data = quadratic(a, b)
    ours = minimize(
        toy_objective, (lo + hi) / 2, bounds=(lo, hi), data=data, options=MinimizeOptions(gtol=1e-9)
    )
    ref = scipy_minimize(
        scipy_fg(data),
        (lo + hi) / 2,
        jac=True,
        method="L-BFGS-B",
        bounds=list(zip(lo, hi, strict=True)),
        options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 10_000},
    )
    # Near the minimum, f ~ 10 leaves sufficient decrease below rounding: the search may
    # end LINE_SEARCH_FAILED there (Dennis & Schnabel's "x may already be a minimum").
    assert ours.termination in (
        Termination.GTOL,
        Termination.STEP_SMALL,
        Termination.LINE_SEARCH_FAILED,
    )
    assert ours.projected_gradient_norm <= 1e-6
    assert ours.x[k] == hi[k]  # the active bound is held exactly
    assert_allclose(ours.x, ref.x, rtol=0, atol=1e-6)
    assert ours.f <= ref.fun + 1e-12


def test_rosenbrock_minimum_on_a_bound_matches_scipy() -> None:
    data = rosenbrock(2)
    lo, hi = np.array([-2.0, 1.5]), np.array([2.0, 3.0])
    ours = minimize(
        toy_objective, [1.0, 2.0], bounds=(lo, hi), data=data, options=MinimizeOptions(gtol=1e-12)
    )
    ref = scipy_minimize(
        scipy_fg(data),
        [1.0, 2.0],
        jac=True,
        method="L-BFGS-B",
        bounds=list(zip(lo, hi, strict=True)),
        options={"ftol": 1e-15, "gtol": 1e-12},
    )
    assert ours.x[1] == 1.5
    assert_allclose(ours.x, ref.x, rtol=0, atol=1e-6)


def test_start_outside_the_box_is_projected() -> None:
    res = minimize(
        toy_objective,
        [5.0, -5.0],
        bounds=([-1.0, -1.0], [1.0, 1.0]),
        data=rosenbrock(2),
        record_steps=True,
    )
    assert np.all(res.x >= -1.0) and np.all(res.x <= 1.0)
    assert all(s.bound_slack >= 0.0 for s in res.steps)


def test_nonfinite_start_ends_with_nonfinite() -> None:
    data = make_data(NAN_REGION, np.array([1.0, 0.0, 0.0]), np.eye(2))
    res = minimize(toy_objective, [3.0, 0.0], data=data)
    assert res.termination is Termination.NONFINITE
    assert res.pass_log[-1].action is Action.STOP


def test_line_search_backs_off_a_nonfinite_region() -> None:
    # Minimum at (2, 2) but f is NaN beyond |x| > 2.5: full steps overshoot into NaN.
    data = make_data(NAN_REGION, np.array([2.5, 2.0, 2.0]), np.eye(2))
    res = minimize(toy_objective, [-2.0, -2.0], data=data, record_steps=True)
    assert res.termination.converged
    assert_allclose(res.x, [2.0, 2.0], rtol=0, atol=1e-6)
    assert all(math.isfinite(s.f_after) for s in res.steps)


def test_wrong_gradient_ends_in_line_search_failure_after_a_reset() -> None:
    data = make_data(WRONG_GRADIENT, np.array([1.0, 1.0]), np.eye(2))
    res = minimize(toy_objective, [0.0, 0.0], data=data)
    assert res.termination is Termination.LINE_SEARCH_FAILED
    assert res.pass_log[0].termination is Termination.LINE_SEARCH_FAILED
    assert res.iterations == 0
    # The first pass began with H = I and went nowhere: a reset cannot help (guard).
    assert res.pass_log[-1].action is Action.ACCEPT
    assert res.f == 0.0


def test_deadline_is_honoured_and_reported() -> None:
    res = minimize(
        toy_objective,
        np.tile([-1.2, 1.0], 50),
        data=rosenbrock(100),
        options=MinimizeOptions(time_budget_s=0.0),
    )
    assert res.termination is Termination.DEADLINE
    assert res.iterations == 0


def test_iteration_budget_is_shared_by_all_passes() -> None:
    opts = MinimizeOptions(max_iter=40, stall_window=2, ftol=0.5)
    res = minimize(toy_objective, np.tile([-1.2, 1.0], 5), data=rosenbrock(10), options=opts)
    assert res.passes > 1
    assert sum(p.iterations for p in res.pass_log) == res.iterations <= 40
    assert all(p.start is PassStart.RESET_H for p in res.pass_log[1:])


def test_evaluation_budget() -> None:
    res = minimize(
        toy_objective,
        np.tile([-1.2, 1.0], 5),
        data=rosenbrock(10),
        options=MinimizeOptions(max_fev=15),
    )
    assert res.termination is Termination.MAX_FEV
    assert res.function_evals <= 15 + 1


def test_iteration_limit() -> None:
    res = minimize(
        toy_objective, [-1.2, 1.0], data=rosenbrock(2), options=MinimizeOptions(max_iter=3)
    )
    assert res.termination is Termination.MAX_ITER
    assert res.iterations == 3


def test_step_cap_limits_every_step() -> None:
    a = np.eye(3)
    b = np.full(3, 10.0)
    capped = minimize(
        toy_objective, np.zeros(3), data=quadratic(a, b), options=MinimizeOptions(max_step=0.5)
    )
    assert capped.iterations >= 20  # 10 units at <= 0.5 per step
    assert_allclose(capped.x, b, rtol=0, atol=1e-8)


@pytest.mark.parametrize("curvature", [False, True])
def test_every_accepted_step_satisfies_armijo_and_stays_feasible(curvature: bool) -> None:
    lo, hi = np.full(6, -1.5), np.full(6, 0.8)
    opts = MinimizeOptions(curvature=curvature)
    res = minimize(
        toy_objective,
        np.full(6, -1.0),
        bounds=(lo, hi),
        data=rosenbrock(6),
        options=opts,
        record_steps=True,
    )
    assert res.steps
    for s in res.steps:
        assert s.f_after <= s.f_before + opts.armijo_c1 * s.decrease
        assert s.decrease < 0.0
        assert s.bound_slack >= 0.0
        assert 0.0 < s.step_length


def test_curvature_condition_reduces_iterations_or_matches_on_rosenbrock() -> None:
    x0 = np.tile([-1.2, 1.0], 5)
    plain = minimize(toy_objective, x0, data=rosenbrock(10))
    curv = minimize(toy_objective, x0, data=rosenbrock(10), options=MinimizeOptions(curvature=True))
    assert curv.f <= 1e-9 and plain.f <= 1e-9
    assert curv.skipped_updates <= plain.skipped_updates + 5


def test_bfgs_update_skipped_and_counted_on_concave_steps() -> None:
    # Non-convex: y.s < 0 happens on the way; the update must be skipped, not applied.
    rng = np.random.default_rng(3)
    data = make_data(NONCONVEX, np.zeros(3), 0.05 * np.eye(3))
    res = minimize(toy_objective, rng.normal(size=3), data=data, record_steps=True)
    assert res.termination.converged
    assert res.skipped_updates >= 0
    assert np.all(np.linalg.eigvalsh(res.inverse_hessian) > 0.0)


def test_restarts_are_reproducible_from_the_rng() -> None:
    data = make_data(NONCONVEX, np.zeros(4), 0.1 * np.eye(4))
    opts = MinimizeOptions(f_goal=-10.0, max_restarts=5)
    box = (np.full(4, -3.0), np.full(4, 3.0))
    r1 = minimize(
        toy_objective,
        np.zeros(4),
        bounds=box,
        data=data,
        options=opts,
        rng=np.random.default_rng(7),
    )
    r2 = minimize(
        toy_objective,
        np.zeros(4),
        bounds=box,
        data=data,
        options=opts,
        rng=np.random.default_rng(7),
    )
    assert r1.restarts == 5
    assert_allclose(r1.x, r2.x, rtol=0, atol=0)
    assert [p.f_end for p in r1.pass_log] == [p.f_end for p in r2.pass_log]


@pytest.mark.parametrize(
    "kwargs",
    [
        {"armijo_c1": 0.0},
        {"curvature_c2": 1e-5},
        {"gtol": math.nan},
        {"max_step": 0.0},
        {"max_iter": 0},
        {"stall_window": -1},
        {"time_budget_s": -1.0},
    ],
)
def test_invalid_options_are_rejected(kwargs: dict[str, float]) -> None:
    with pytest.raises(InvalidProblem):
        MinimizeOptions(**kwargs)  # type: ignore[arg-type]


def test_invalid_problems_are_rejected() -> None:
    data = rosenbrock(2)
    with pytest.raises(InvalidProblem):
        minimize(toy_objective, [math.nan, 0.0], data=data)
    with pytest.raises(InvalidProblem):
        minimize(toy_objective, [0.0, 0.0], bounds=([1.0, 0.0], [0.0, 1.0]), data=data)
    with pytest.raises(InvalidProblem):
        minimize(toy_objective, [0.0, 0.0], data=data, initial_inverse_hessian=-np.eye(2))
    with pytest.raises(InvalidProblem):
        minimize(lambda x: 0.0, [0.0], data=data)
