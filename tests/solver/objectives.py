"""Small compiled test objectives, one switch so numba compiles (and caches) once.

data = (kind: int64[1], p: float64[:], a: float64[:, :]) with kinds:
    0  quadratic 1/2 x'Ax - p'x (A symmetric)
    1  extended Rosenbrock
    2  quadratic but NaN when |x|_inf > p[0] (non-finite region)
    3  quadratic with the gradient's sign flipped (no descent: line search fails)
    4  non-convex: sum sin(3 x_i) + 1/2 x'Ax (A positive definite)
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from solver.optim import register_objective

jit = njit(cache=True, error_model="numpy")

QUADRATIC = 0
ROSENBROCK = 1
NAN_REGION = 2
WRONG_GRADIENT = 3
NONCONVEX = 4


@jit
def toy_objective(x, g, need_grad, data):  # type: ignore[no-untyped-def]
    kind = data[0][0]
    p = data[1]
    a = data[2]
    n = x.shape[0]
    if kind == ROSENBROCK:
        f = 0.0
        if need_grad:
            for i in range(n):
                g[i] = 0.0
        for i in range(0, n - 1, 2):
            t1 = 10.0 * (x[i + 1] - x[i] * x[i])
            t2 = 1.0 - x[i]
            f += t1 * t1 + t2 * t2
            if need_grad:
                g[i] += -40.0 * x[i] * t1 - 2.0 * t2
                g[i + 1] += 20.0 * t1
        return f
    f = 0.0
    for i in range(n):
        ax = 0.0
        for j in range(n):
            ax += a[i, j] * x[j]
        f += 0.5 * x[i] * ax - (p[i + 1] if kind == NAN_REGION else p[i]) * x[i]
        if need_grad:
            g[i] = ax - (p[i + 1] if kind == NAN_REGION else p[i])
    if kind == NONCONVEX:
        for i in range(n):
            f += math.sin(3.0 * x[i])
            if need_grad:
                g[i] += 3.0 * math.cos(3.0 * x[i])
    if kind == NAN_REGION:
        for i in range(n):
            if abs(x[i]) > p[0]:
                return math.nan
    if kind == WRONG_GRADIENT and need_grad:
        for i in range(n):
            g[i] = -g[i]
    return f


def make_data(kind: int, p: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (
        np.array([kind], dtype=np.int64),
        np.ascontiguousarray(p, dtype=np.float64),
        np.ascontiguousarray(a, dtype=np.float64),
    )


register_objective(toy_objective, None, make_data(0, np.zeros(1), np.zeros((1, 1))))
