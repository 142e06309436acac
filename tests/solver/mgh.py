"""More-Garbow-Hillstrom test problems as numba-compiled residuals with exact Jacobians.

Source: J. J. More, B. S. Garbow, K. E. Hillstrom, "Testing unconstrained optimization
software", ACM TOMS 7(1), 1981, pp. 17-41 (below: "MGH"). Problem numbers (#1..#35)
are the paper's. Every problem is a sum of squares f(x) = sum_i r_i(x)^2 with m
residuals in n unknowns.

Layout, and why:

* ``mgh_residuals`` / ``mgh_jacobian`` hold ONE ``if pid == ...: elif ...`` switch each,
  so numba compiles one function for all 35 problems instead of 35 (each distinct
  compiled function costs about 1-2 s; the cache then makes later imports cheap).
* ``pid`` is the MGH number itself: the switch needs no extra lookup table.
* n and m are read from the shapes of ``x`` and ``r``/``jac``, so variable-dimension
  problems need nothing besides ``pid``.
* ``mgh_objective`` has the optimizer's objective signature ``fg(x, g, need_grad, data)``
  with ``data = (int64 array [pid, m],)``.
* Compiled with ``error_model="numpy"``: a line search may try x where a denominator is
  0 (Bard, Kowalik-Osborne, Meyer) or an exponential overflows; f must then be
  inf/nan, which the optimizer rejects, instead of a ZeroDivisionError raised from
  inside compiled code.
* With NUMBA_DISABLE_JIT=1 the same bodies run as plain Python on numpy scalars, which
  warn on overflow/invalid where compiled code is silent; the public functions are then
  wrapped in ``np.errstate(all="ignore")`` (bottom of this module) so both modes agree
  and ``filterwarnings = error`` does not turn an inf trial point into a test failure.

Reference values (``f_star``, ``local_minima``) are the paper's, each re-derived here
with scipy's MINPACK Levenberg-Marquardt (``least_squares(method="lm")`` with
ftol=xtol=gtol=1e-15); the higher-precision values found that way are quoted in the
comments of ``_spec``. ``tests/solver/test_mgh_definitions.py`` re-checks all of them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt
from numba import njit
from numba.core import config as _numba_config

Vector = npt.NDArray[np.float64]
Matrix = npt.NDArray[np.float64]

# ---------------------------------------------------------------------------------------
# Data tables (MGH appendix). Module-level arrays are frozen into the compiled code as
# constants by numba, so they cost nothing per call.
# ---------------------------------------------------------------------------------------

# #8 Bard, y_i, i = 1..15.
_BARD_Y = np.array(
    [0.14, 0.18, 0.22, 0.25, 0.29, 0.32, 0.35, 0.39, 0.37, 0.58, 0.73, 0.96, 1.34, 2.10, 4.39]
)
# #9 Gaussian, y_i, i = 1..15 (symmetric around t = 0).
_GAUSSIAN_Y = np.array(
    [
        0.0009, 0.0044, 0.0175, 0.0540, 0.1295, 0.2420, 0.3521, 0.3989,
        0.3521, 0.2420, 0.1295, 0.0540, 0.0175, 0.0044, 0.0009,
    ]
)  # fmt: skip
# #10 Meyer, y_i, i = 1..16.
_MEYER_Y = np.array(
    [
        34780.0, 28610.0, 23650.0, 19630.0, 16370.0, 13720.0, 11540.0, 9744.0,
        8261.0, 7030.0, 6005.0, 5147.0, 4427.0, 3820.0, 3307.0, 2872.0,
    ]
)  # fmt: skip
# #15 Kowalik-Osborne, y_i and u_i, i = 1..11.
_KOWALIK_Y = np.array(
    [0.1957, 0.1947, 0.1735, 0.1600, 0.0844, 0.0627, 0.0456, 0.0342, 0.0323, 0.0235, 0.0246]
)
_KOWALIK_U = np.array([4.0, 2.0, 1.0, 0.5, 0.25, 0.167, 0.125, 0.1, 0.0833, 0.0714, 0.0625])
# #17 Osborne 1, y_i, i = 1..33.
_OSBORNE1_Y = np.array(
    [
        0.844, 0.908, 0.932, 0.936, 0.925, 0.908, 0.881, 0.850, 0.818, 0.784, 0.751,
        0.718, 0.685, 0.658, 0.628, 0.603, 0.580, 0.558, 0.538, 0.522, 0.506, 0.490,
        0.478, 0.467, 0.457, 0.448, 0.438, 0.431, 0.424, 0.420, 0.414, 0.411, 0.406,
    ]
)  # fmt: skip
# #19 Osborne 2, y_i, i = 1..65.
_OSBORNE2_Y = np.array(
    [
        1.366, 1.191, 1.112, 1.013, 0.991, 0.885, 0.831, 0.847, 0.786, 0.725,
        0.746, 0.679, 0.608, 0.655, 0.616, 0.606, 0.602, 0.626, 0.651, 0.724,
        0.649, 0.649, 0.694, 0.644, 0.624, 0.661, 0.612, 0.558, 0.533, 0.495,
        0.500, 0.423, 0.395, 0.375, 0.372, 0.391, 0.396, 0.405, 0.428, 0.429,
        0.523, 0.562, 0.607, 0.653, 0.672, 0.708, 0.633, 0.668, 0.645, 0.632,
        0.591, 0.559, 0.597, 0.625, 0.739, 0.710, 0.729, 0.720, 0.636, 0.581,
        0.428, 0.292, 0.162, 0.098, 0.054,
    ]
)  # fmt: skip

_TWO_PI = 2.0 * np.pi
_SQRT5 = np.sqrt(5.0)
_SQRT10 = np.sqrt(10.0)
_SQRT90 = np.sqrt(90.0)
_SQRT_PENALTY_A = np.sqrt(1e-5)  # #23/#24: a = 1e-5, residuals carry a^(1/2)


@njit(cache=True, error_model="numpy")
def mgh_residuals(pid: int, x: Vector, r: Vector) -> None:
    """Fill ``r`` (shape (m,)) with the residuals of MGH problem ``pid`` at ``x`` (shape (n,)).

    The paper's 1-based formulas are written with 0-based indices: x[0] is x_1.
    """
    n = x.shape[0]
    m = r.shape[0]
    if pid == 1:  # Rosenbrock
        r[0] = 10.0 * (x[1] - x[0] * x[0])
        r[1] = 1.0 - x[0]
    elif pid == 2:  # Freudenstein and Roth
        r[0] = -13.0 + x[0] + ((5.0 - x[1]) * x[1] - 2.0) * x[1]
        r[1] = -29.0 + x[0] + ((x[1] + 1.0) * x[1] - 14.0) * x[1]
    elif pid == 3:  # Powell badly scaled
        r[0] = 1e4 * x[0] * x[1] - 1.0
        r[1] = np.exp(-x[0]) + np.exp(-x[1]) - 1.0001
    elif pid == 4:  # Brown badly scaled
        r[0] = x[0] - 1e6
        r[1] = x[1] - 2e-6
        r[2] = x[0] * x[1] - 2.0
    elif pid == 5:  # Beale: y = (1.5, 2.25, 2.625)
        r[0] = 1.5 - x[0] * (1.0 - x[1])
        r[1] = 2.25 - x[0] * (1.0 - x[1] * x[1])
        r[2] = 2.625 - x[0] * (1.0 - x[1] * x[1] * x[1])
    elif pid == 6:  # Jennrich and Sampson
        for i in range(m):
            k = i + 1.0
            r[i] = 2.0 + 2.0 * k - (np.exp(k * x[0]) + np.exp(k * x[1]))
    elif pid == 7:  # Helical valley
        # theta as MGH define it (not atan2): range (-1/4, 3/4), continuous across x1 < 0.
        # At x1 == 0 the limit 1/4 * sign(x2), as MINPACK's test code does.
        if x[0] > 0.0:
            th = np.arctan(x[1] / x[0]) / _TWO_PI
        elif x[0] < 0.0:
            th = np.arctan(x[1] / x[0]) / _TWO_PI + 0.5
        elif x[1] >= 0.0:
            th = 0.25
        else:
            th = -0.25
        r[0] = 10.0 * (x[2] - 10.0 * th)
        r[1] = 10.0 * (np.sqrt(x[0] * x[0] + x[1] * x[1]) - 1.0)
        r[2] = x[2]
    elif pid == 8:  # Bard: u_i = i, v_i = 16 - i, w_i = min(u_i, v_i)
        for i in range(m):
            u = i + 1.0
            v = 15.0 - i
            w = min(u, v)
            r[i] = _BARD_Y[i] - (x[0] + u / (v * x[1] + w * x[2]))
    elif pid == 9:  # Gaussian: t_i = (8 - i) / 2
        for i in range(m):
            d = (7.0 - i) / 2.0 - x[2]
            r[i] = x[0] * np.exp(-0.5 * x[1] * d * d) - _GAUSSIAN_Y[i]
    elif pid == 10:  # Meyer: t_i = 45 + 5 i
        for i in range(m):
            t = 50.0 + 5.0 * i
            r[i] = x[0] * np.exp(x[1] / (t + x[2])) - _MEYER_Y[i]
    elif pid == 11:  # Gulf research and development: t_i = i/100
        # MGH print "|y_i m i x_2|": the "m i" is a typeset minus, i.e. |y_i - x_2|.
        for i in range(m):
            t = (i + 1.0) / 100.0
            y = 25.0 + (-50.0 * np.log(t)) ** (2.0 / 3.0)
            r[i] = np.exp(-(np.abs(y - x[1]) ** x[2]) / x[0]) - t
    elif pid == 12:  # Box three-dimensional: t_i = 0.1 i
        for i in range(m):
            t = 0.1 * (i + 1.0)
            r[i] = np.exp(-t * x[0]) - np.exp(-t * x[1]) - x[2] * (np.exp(-t) - np.exp(-10.0 * t))
    elif pid == 13:  # Powell singular
        d23 = x[1] - 2.0 * x[2]
        d14 = x[0] - x[3]
        r[0] = x[0] + 10.0 * x[1]
        r[1] = _SQRT5 * (x[2] - x[3])
        r[2] = d23 * d23
        r[3] = _SQRT10 * d14 * d14
    elif pid == 14:  # Wood
        r[0] = 10.0 * (x[1] - x[0] * x[0])
        r[1] = 1.0 - x[0]
        r[2] = _SQRT90 * (x[3] - x[2] * x[2])
        r[3] = 1.0 - x[2]
        r[4] = _SQRT10 * (x[1] + x[3] - 2.0)
        r[5] = (x[1] - x[3]) / _SQRT10
    elif pid == 15:  # Kowalik and Osborne
        for i in range(m):
            u = _KOWALIK_U[i]
            r[i] = _KOWALIK_Y[i] - x[0] * (u * u + u * x[1]) / (u * u + u * x[2] + x[3])
    elif pid == 16:  # Brown and Dennis: t_i = i/5
        for i in range(m):
            t = (i + 1.0) / 5.0
            a = x[0] + t * x[1] - np.exp(t)
            b = x[2] + x[3] * np.sin(t) - np.cos(t)
            r[i] = a * a + b * b
    elif pid == 17:  # Osborne 1: t_i = 10 (i - 1)
        for i in range(m):
            t = 10.0 * i
            r[i] = _OSBORNE1_Y[i] - (x[0] + x[1] * np.exp(-t * x[3]) + x[2] * np.exp(-t * x[4]))
    elif pid == 18:  # Biggs EXP6: t_i = 0.1 i, data generated by x = (1, 10, 1, 5, 4, 3)
        for i in range(m):
            t = 0.1 * (i + 1.0)
            y = np.exp(-t) - 5.0 * np.exp(-10.0 * t) + 3.0 * np.exp(-4.0 * t)
            r[i] = (
                x[2] * np.exp(-t * x[0]) - x[3] * np.exp(-t * x[1]) + x[5] * np.exp(-t * x[4]) - y
            )
    elif pid == 19:  # Osborne 2: t_i = (i - 1)/10
        for i in range(m):
            t = i / 10.0
            d9 = t - x[8]
            d10 = t - x[9]
            d11 = t - x[10]
            r[i] = _OSBORNE2_Y[i] - (
                x[0] * np.exp(-t * x[4])
                + x[1] * np.exp(-d9 * d9 * x[5])
                + x[2] * np.exp(-d10 * d10 * x[6])
                + x[3] * np.exp(-d11 * d11 * x[7])
            )
    elif pid == 20:  # Watson: 29 polynomial residuals (t_i = i/29) and two more
        for i in range(29):
            t = (i + 1.0) / 29.0
            s1 = 0.0  # sum_{j=2}^n (j-1) x_j t^(j-2)
            s2 = 0.0  # sum_{j=1}^n x_j t^(j-1)
            tp = 1.0  # t^(j-1) for the 0-based j of the loop
            for j in range(n):
                s2 += x[j] * tp
                if j + 1 < n:
                    s1 += (j + 1.0) * x[j + 1] * tp
                tp *= t
            r[i] = s1 - s2 * s2 - 1.0
        r[29] = x[0]
        r[30] = x[1] - x[0] * x[0] - 1.0
    elif pid == 21:  # Extended Rosenbrock
        for k in range(n // 2):
            r[2 * k] = 10.0 * (x[2 * k + 1] - x[2 * k] * x[2 * k])
            r[2 * k + 1] = 1.0 - x[2 * k]
    elif pid == 22:  # Extended Powell singular
        for k in range(n // 4):
            j = 4 * k
            d23 = x[j + 1] - 2.0 * x[j + 2]
            d14 = x[j] - x[j + 3]
            r[j] = x[j] + 10.0 * x[j + 1]
            r[j + 1] = _SQRT5 * (x[j + 2] - x[j + 3])
            r[j + 2] = d23 * d23
            r[j + 3] = _SQRT10 * d14 * d14
    elif pid == 23:  # Penalty I: m = n + 1
        s = 0.0
        for j in range(n):
            r[j] = _SQRT_PENALTY_A * (x[j] - 1.0)
            s += x[j] * x[j]
        r[n] = s - 0.25
    elif pid == 24:  # Penalty II: m = 2n
        e01 = np.exp(-0.1)
        r[0] = x[0] - 0.2
        for i in range(1, n):
            y = np.exp((i + 1.0) / 10.0) + np.exp(i / 10.0)
            r[i] = _SQRT_PENALTY_A * (np.exp(x[i] / 10.0) + np.exp(x[i - 1] / 10.0) - y)
        for i in range(n, 2 * n - 1):
            r[i] = _SQRT_PENALTY_A * (np.exp(x[i - n + 1] / 10.0) - e01)
        s = 0.0
        for j in range(n):
            s += (n - j) * x[j] * x[j]
        r[2 * n - 1] = s - 1.0
    elif pid == 25:  # Variably dimensioned: m = n + 2
        s = 0.0
        for j in range(n):
            r[j] = x[j] - 1.0
            s += (j + 1.0) * (x[j] - 1.0)
        r[n] = s
        r[n + 1] = s * s
    elif pid == 26:  # Trigonometric
        s = 0.0
        for j in range(n):
            s += np.cos(x[j])
        for i in range(n):
            r[i] = n - s + (i + 1.0) * (1.0 - np.cos(x[i])) - np.sin(x[i])
    elif pid == 27:  # Brown almost-linear
        s = 0.0
        p = 1.0
        for j in range(n):
            s += x[j]
            p *= x[j]
        for i in range(n - 1):
            r[i] = x[i] + s - (n + 1.0)
        r[n - 1] = p - 1.0
    elif pid == 28:  # Discrete boundary value: h = 1/(n+1), t_i = i h, x_0 = x_{n+1} = 0
        h = 1.0 / (n + 1.0)
        for i in range(n):
            t = (i + 1.0) * h
            xl = x[i - 1] if i > 0 else 0.0
            xr = x[i + 1] if i < n - 1 else 0.0
            c = x[i] + t + 1.0
            r[i] = 2.0 * x[i] - xl - xr + h * h * c * c * c / 2.0
    elif pid == 29:  # Discrete integral equation, same grid as #28
        h = 1.0 / (n + 1.0)
        for i in range(n):
            ti = (i + 1.0) * h
            s1 = 0.0  # sum_{j <= i} t_j (x_j + t_j + 1)^3
            s2 = 0.0  # sum_{j > i} (1 - t_j) (x_j + t_j + 1)^3
            for j in range(n):
                tj = (j + 1.0) * h
                c = x[j] + tj + 1.0
                if j <= i:
                    s1 += tj * c * c * c
                else:
                    s2 += (1.0 - tj) * c * c * c
            r[i] = x[i] + h * ((1.0 - ti) * s1 + ti * s2) / 2.0
    elif pid == 30:  # Broyden tridiagonal, x_0 = x_{n+1} = 0
        for i in range(n):
            xl = x[i - 1] if i > 0 else 0.0
            xr = x[i + 1] if i < n - 1 else 0.0
            r[i] = (3.0 - 2.0 * x[i]) * x[i] - xl - 2.0 * xr + 1.0
    elif pid == 31:  # Broyden banded: m_l = 5, m_u = 1
        for i in range(n):
            s = 0.0
            for j in range(max(0, i - 5), min(n, i + 2)):
                if j != i:
                    s += x[j] * (1.0 + x[j])
            r[i] = x[i] * (2.0 + 5.0 * x[i] * x[i]) + 1.0 - s
    elif pid == 32:  # Linear function - full rank
        s = 0.0
        for j in range(n):
            s += x[j]
        for i in range(m):
            r[i] = -2.0 * s / m - 1.0
            if i < n:
                r[i] += x[i]
    elif pid == 33:  # Linear function - rank 1
        s = 0.0
        for j in range(n):
            s += (j + 1.0) * x[j]
        for i in range(m):
            r[i] = (i + 1.0) * s - 1.0
    elif pid == 34:  # Linear function - rank 1 with zero columns and rows
        s = 0.0
        for j in range(1, n - 1):
            s += (j + 1.0) * x[j]
        for i in range(m):
            r[i] = -1.0
            if 0 < i < m - 1:
                r[i] += i * s
    elif pid == 35:  # Chebyquad: shifted Chebyshev T_i on [0, 1] via the recurrence
        for i in range(m):
            r[i] = 0.0
        for j in range(n):
            y = 2.0 * x[j] - 1.0
            t_prev = 1.0
            t_cur = y
            r[0] += t_cur
            for i in range(1, m):
                t_next = 2.0 * y * t_cur - t_prev
                t_prev = t_cur
                t_cur = t_next
                r[i] += t_cur
        for i in range(m):
            r[i] /= n
            if (i + 1) % 2 == 0:  # integral of T_k over [0, 1] is -1/(k^2-1) for even k
                k = i + 1.0
                r[i] += 1.0 / (k * k - 1.0)
    else:
        for i in range(m):
            r[i] = np.nan  # unknown id: poison rather than leave r uninitialised


@njit(cache=True, error_model="numpy")
def mgh_jacobian(pid: int, x: Vector, jac: Matrix) -> None:
    """Fill ``jac`` (shape (m, n)) with the exact Jacobian dr_i/dx_j of problem ``pid``."""
    n = x.shape[0]
    m = jac.shape[0]
    for i in range(m):
        for j in range(n):
            jac[i, j] = 0.0  # most problems are sparse; only nonzeros are written below
    if pid == 1:
        jac[0, 0] = -20.0 * x[0]
        jac[0, 1] = 10.0
        jac[1, 0] = -1.0
    elif pid == 2:
        jac[0, 0] = 1.0
        jac[0, 1] = (10.0 - 3.0 * x[1]) * x[1] - 2.0
        jac[1, 0] = 1.0
        jac[1, 1] = (3.0 * x[1] + 2.0) * x[1] - 14.0
    elif pid == 3:
        jac[0, 0] = 1e4 * x[1]
        jac[0, 1] = 1e4 * x[0]
        jac[1, 0] = -np.exp(-x[0])
        jac[1, 1] = -np.exp(-x[1])
    elif pid == 4:
        jac[0, 0] = 1.0
        jac[1, 1] = 1.0
        jac[2, 0] = x[1]
        jac[2, 1] = x[0]
    elif pid == 5:
        jac[0, 0] = -(1.0 - x[1])
        jac[0, 1] = x[0]
        jac[1, 0] = -(1.0 - x[1] * x[1])
        jac[1, 1] = 2.0 * x[0] * x[1]
        jac[2, 0] = -(1.0 - x[1] * x[1] * x[1])
        jac[2, 1] = 3.0 * x[0] * x[1] * x[1]
    elif pid == 6:
        for i in range(m):
            k = i + 1.0
            jac[i, 0] = -k * np.exp(k * x[0])
            jac[i, 1] = -k * np.exp(k * x[1])
    elif pid == 7:
        # d theta/dx1 = -x2 / (2 pi rho^2), d theta/dx2 = x1 / (2 pi rho^2) on both branches.
        rho2 = x[0] * x[0] + x[1] * x[1]
        rho = np.sqrt(rho2)
        jac[0, 0] = 100.0 * x[1] / (_TWO_PI * rho2)
        jac[0, 1] = -100.0 * x[0] / (_TWO_PI * rho2)
        jac[0, 2] = 10.0
        jac[1, 0] = 10.0 * x[0] / rho
        jac[1, 1] = 10.0 * x[1] / rho
        jac[2, 2] = 1.0
    elif pid == 8:
        for i in range(m):
            u = i + 1.0
            v = 15.0 - i
            w = min(u, v)
            den = v * x[1] + w * x[2]
            jac[i, 0] = -1.0
            jac[i, 1] = u * v / (den * den)
            jac[i, 2] = u * w / (den * den)
    elif pid == 9:
        for i in range(m):
            d = (7.0 - i) / 2.0 - x[2]
            e = np.exp(-0.5 * x[1] * d * d)
            jac[i, 0] = e
            jac[i, 1] = -0.5 * x[0] * e * d * d
            jac[i, 2] = x[0] * e * x[1] * d
    elif pid == 10:
        for i in range(m):
            den = 50.0 + 5.0 * i + x[2]
            e = np.exp(x[1] / den)
            jac[i, 0] = e
            jac[i, 1] = x[0] * e / den
            jac[i, 2] = -x[0] * e * x[1] / (den * den)
    elif pid == 11:
        for i in range(m):
            t = (i + 1.0) / 100.0
            y = 25.0 + (-50.0 * np.log(t)) ** (2.0 / 3.0)
            d = y - x[1]
            ad = np.abs(d)
            a = ad ** x[2]
            e = np.exp(-a / x[0])
            jac[i, 0] = e * a / (x[0] * x[0])
            # d|d|^x3/dx2 = -x3 |d|^x3 / d; its limit at d == 0 is 0 for x3 > 1.
            if d != 0.0:
                jac[i, 1] = e * x[2] * a / (x[0] * d)
                jac[i, 2] = -e * a * np.log(ad) / x[0]
    elif pid == 12:
        for i in range(m):
            t = 0.1 * (i + 1.0)
            jac[i, 0] = -t * np.exp(-t * x[0])
            jac[i, 1] = t * np.exp(-t * x[1])
            jac[i, 2] = -(np.exp(-t) - np.exp(-10.0 * t))
    elif pid == 13:
        d23 = x[1] - 2.0 * x[2]
        d14 = x[0] - x[3]
        jac[0, 0] = 1.0
        jac[0, 1] = 10.0
        jac[1, 2] = _SQRT5
        jac[1, 3] = -_SQRT5
        jac[2, 1] = 2.0 * d23
        jac[2, 2] = -4.0 * d23
        jac[3, 0] = 2.0 * _SQRT10 * d14
        jac[3, 3] = -2.0 * _SQRT10 * d14
    elif pid == 14:
        jac[0, 0] = -20.0 * x[0]
        jac[0, 1] = 10.0
        jac[1, 0] = -1.0
        jac[2, 2] = -2.0 * _SQRT90 * x[2]
        jac[2, 3] = _SQRT90
        jac[3, 2] = -1.0
        jac[4, 1] = _SQRT10
        jac[4, 3] = _SQRT10
        jac[5, 1] = 1.0 / _SQRT10
        jac[5, 3] = -1.0 / _SQRT10
    elif pid == 15:
        for i in range(m):
            u = _KOWALIK_U[i]
            num = u * u + u * x[1]
            den = u * u + u * x[2] + x[3]
            jac[i, 0] = -num / den
            jac[i, 1] = -x[0] * u / den
            jac[i, 2] = x[0] * num * u / (den * den)
            jac[i, 3] = x[0] * num / (den * den)
    elif pid == 16:
        for i in range(m):
            t = (i + 1.0) / 5.0
            st = np.sin(t)
            a = x[0] + t * x[1] - np.exp(t)
            b = x[2] + x[3] * st - np.cos(t)
            jac[i, 0] = 2.0 * a
            jac[i, 1] = 2.0 * a * t
            jac[i, 2] = 2.0 * b
            jac[i, 3] = 2.0 * b * st
    elif pid == 17:
        for i in range(m):
            t = 10.0 * i
            e4 = np.exp(-t * x[3])
            e5 = np.exp(-t * x[4])
            jac[i, 0] = -1.0
            jac[i, 1] = -e4
            jac[i, 2] = -e5
            jac[i, 3] = t * x[1] * e4
            jac[i, 4] = t * x[2] * e5
    elif pid == 18:
        for i in range(m):
            t = 0.1 * (i + 1.0)
            e1 = np.exp(-t * x[0])
            e2 = np.exp(-t * x[1])
            e5 = np.exp(-t * x[4])
            jac[i, 0] = -t * x[2] * e1
            jac[i, 1] = t * x[3] * e2
            jac[i, 2] = e1
            jac[i, 3] = -e2
            jac[i, 4] = -t * x[5] * e5
            jac[i, 5] = e5
    elif pid == 19:
        for i in range(m):
            t = i / 10.0
            d9 = t - x[8]
            d10 = t - x[9]
            d11 = t - x[10]
            e1 = np.exp(-t * x[4])
            e2 = np.exp(-d9 * d9 * x[5])
            e3 = np.exp(-d10 * d10 * x[6])
            e4 = np.exp(-d11 * d11 * x[7])
            jac[i, 0] = -e1
            jac[i, 1] = -e2
            jac[i, 2] = -e3
            jac[i, 3] = -e4
            jac[i, 4] = x[0] * t * e1
            jac[i, 5] = x[1] * d9 * d9 * e2
            jac[i, 6] = x[2] * d10 * d10 * e3
            jac[i, 7] = x[3] * d11 * d11 * e4
            jac[i, 8] = -2.0 * x[1] * x[5] * d9 * e2
            jac[i, 9] = -2.0 * x[2] * x[6] * d10 * e3
            jac[i, 10] = -2.0 * x[3] * x[7] * d11 * e4
    elif pid == 20:
        for i in range(29):
            t = (i + 1.0) / 29.0
            s2 = 0.0
            tp = 1.0
            for j in range(n):
                s2 += x[j] * tp
                tp *= t
            # d r_i / d x_j = (j-1) t^(j-2) - 2 s2 t^(j-1) in 1-based j
            tp = 1.0  # t^j (0-based j)
            tpm = 0.0  # j t^(j-1)
            for j in range(n):
                jac[i, j] = tpm - 2.0 * s2 * tp
                tpm = (j + 1.0) * tp
                tp *= t
        jac[29, 0] = 1.0
        jac[30, 0] = -2.0 * x[0]
        jac[30, 1] = 1.0
    elif pid == 21:
        for k in range(n // 2):
            jac[2 * k, 2 * k] = -20.0 * x[2 * k]
            jac[2 * k, 2 * k + 1] = 10.0
            jac[2 * k + 1, 2 * k] = -1.0
    elif pid == 22:
        for k in range(n // 4):
            j = 4 * k
            d23 = x[j + 1] - 2.0 * x[j + 2]
            d14 = x[j] - x[j + 3]
            jac[j, j] = 1.0
            jac[j, j + 1] = 10.0
            jac[j + 1, j + 2] = _SQRT5
            jac[j + 1, j + 3] = -_SQRT5
            jac[j + 2, j + 1] = 2.0 * d23
            jac[j + 2, j + 2] = -4.0 * d23
            jac[j + 3, j] = 2.0 * _SQRT10 * d14
            jac[j + 3, j + 3] = -2.0 * _SQRT10 * d14
    elif pid == 23:
        for j in range(n):
            jac[j, j] = _SQRT_PENALTY_A
            jac[n, j] = 2.0 * x[j]
    elif pid == 24:
        jac[0, 0] = 1.0
        for i in range(1, n):
            jac[i, i] = _SQRT_PENALTY_A * np.exp(x[i] / 10.0) / 10.0
            jac[i, i - 1] = _SQRT_PENALTY_A * np.exp(x[i - 1] / 10.0) / 10.0
        for i in range(n, 2 * n - 1):
            jac[i, i - n + 1] = _SQRT_PENALTY_A * np.exp(x[i - n + 1] / 10.0) / 10.0
        for j in range(n):
            jac[2 * n - 1, j] = 2.0 * (n - j) * x[j]
    elif pid == 25:
        s = 0.0
        for j in range(n):
            s += (j + 1.0) * (x[j] - 1.0)
        for j in range(n):
            jac[j, j] = 1.0
            jac[n, j] = j + 1.0
            jac[n + 1, j] = 2.0 * s * (j + 1.0)
    elif pid == 26:
        for i in range(n):
            for j in range(n):
                jac[i, j] = np.sin(x[j])
            jac[i, i] += (i + 1.0) * np.sin(x[i]) - np.cos(x[i])
    elif pid == 27:
        for i in range(n - 1):
            for j in range(n):
                jac[i, j] = 1.0
            jac[i, i] = 2.0
        for j in range(n):
            # prod_{k != j} x_k without dividing, so zeros in x are handled exactly
            p = 1.0
            for k in range(n):
                if k != j:
                    p *= x[k]
            jac[n - 1, j] = p
    elif pid == 28:
        h = 1.0 / (n + 1.0)
        for i in range(n):
            c = x[i] + (i + 1.0) * h + 1.0
            jac[i, i] = 2.0 + 1.5 * h * h * c * c
            if i > 0:
                jac[i, i - 1] = -1.0
            if i < n - 1:
                jac[i, i + 1] = -1.0
    elif pid == 29:
        h = 1.0 / (n + 1.0)
        for i in range(n):
            ti = (i + 1.0) * h
            for j in range(n):
                tj = (j + 1.0) * h
                c = x[j] + tj + 1.0
                w = (1.0 - ti) * tj if j <= i else ti * (1.0 - tj)
                jac[i, j] = 1.5 * h * w * c * c
            jac[i, i] += 1.0
    elif pid == 30:
        for i in range(n):
            jac[i, i] = 3.0 - 4.0 * x[i]
            if i > 0:
                jac[i, i - 1] = -1.0
            if i < n - 1:
                jac[i, i + 1] = -2.0
    elif pid == 31:
        for i in range(n):
            for j in range(max(0, i - 5), min(n, i + 2)):
                if j != i:
                    jac[i, j] = -(1.0 + 2.0 * x[j])
            jac[i, i] = 2.0 + 15.0 * x[i] * x[i]
    elif pid == 32:
        for i in range(m):
            for j in range(n):
                jac[i, j] = -2.0 / m
            if i < n:
                jac[i, i] += 1.0
    elif pid == 33:
        for i in range(m):
            for j in range(n):
                jac[i, j] = (i + 1.0) * (j + 1.0)
    elif pid == 34:
        for i in range(1, m - 1):
            for j in range(1, n - 1):
                jac[i, j] = i * (j + 1.0)
    elif pid == 35:
        for j in range(n):
            # d/dx T_k(2x - 1) = 2 T_k'(y); T'_{k+1} = 2 T_k + 2 y T'_k - T'_{k-1}
            y = 2.0 * x[j] - 1.0
            t_prev = 1.0
            t_cur = y
            d_prev = 0.0
            d_cur = 1.0
            jac[0, j] = 2.0 * d_cur / n
            for i in range(1, m):
                d_next = 2.0 * t_cur + 2.0 * y * d_cur - d_prev
                t_next = 2.0 * y * t_cur - t_prev
                t_prev = t_cur
                t_cur = t_next
                d_prev = d_cur
                d_cur = d_next
                jac[i, j] = 2.0 * d_cur / n
    else:
        for i in range(m):
            for j in range(n):
                jac[i, j] = np.nan


@njit(cache=True, error_model="numpy")
def mgh_objective(x: Vector, g: Vector, need_grad: bool, data: tuple[Any, ...]) -> float:
    """f = sum r_i^2; if need_grad: g[:] = 2 J^T r. data = (pid_and_m: int64 array [pid, m],)"""
    pid = data[0][0]
    m = data[0][1]
    n = x.shape[0]
    r = np.empty(m)
    mgh_residuals(pid, x, r)
    f = 0.0
    for i in range(m):
        f += r[i] * r[i]
    if need_grad:
        jac = np.empty((m, n))
        mgh_jacobian(pid, x, jac)
        for j in range(n):
            s = 0.0
            for i in range(m):
                s += jac[i, j] * r[i]
            g[j] = 2.0 * s
    return f


_F = TypeVar("_F", bound=Callable[..., Any])


def _quiet(fn: _F) -> _F:
    """Run fn under np.errstate(all="ignore"): plain-Python mode only (see module doc)."""

    @functools.wraps(fn)
    def wrapper(*args: Any) -> Any:
        with np.errstate(all="ignore"):
            return fn(*args)

    return wrapper  # type: ignore[return-value]


if _numba_config.DISABLE_JIT:  # type: ignore[attr-defined]  # numba's config is untyped
    # Rebinding the globals also covers mgh_objective's calls, which resolve by name.
    mgh_residuals = _quiet(mgh_residuals)
    mgh_jacobian = _quiet(mgh_jacobian)
    mgh_objective = _quiet(mgh_objective)


# ---------------------------------------------------------------------------------------
# Problem descriptions
# ---------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class MGHProblem:
    """One instance (n, m fixed) of an MGH problem.

    eq=False: the fields hold arrays, so the generated __eq__/__hash__ would fail; an
    instance compares and hashes by identity. ``x0`` and ``x_star`` are read-only
    because instances are shared (``PROBLEMS``); copy them before changing them. A
    read-only array is a distinct numba type, so pass ``x0.copy()`` to compiled code
    that is otherwise called with writable arrays, or it compiles a second time.
    """

    name: str  # e.g. "rosenbrock"
    number: int  # MGH paper number (#1 Rosenbrock ... #35 Chebyquad)
    pid: int  # internal id used by the njit switch (equal to ``number``)
    n: int
    m: int
    x0: Vector  # standard starting point (extended problems: the pattern repeated)
    f_star: float  # known minimum value (global) from the paper
    x_star: Vector | None  # known minimizer if unique and known in closed form, else None
    # Known non-global local minima / non-minimizing stationary f values; "at infinity"
    # entries are infima approached as some x_j -> +-inf (see _spec comments).
    local_minima: tuple[float, ...] = ()

    def data(self) -> tuple[npt.NDArray[np.int64]]:
        """The data tuple for mgh_objective: (int64 array [pid, m],)."""
        return (np.array([self.pid, self.m], dtype=np.int64),)

    def residuals(self, x: npt.ArrayLike) -> Vector:
        """r(x), shape (m,)."""
        xv = self._vec(x)
        r = np.empty(self.m)
        mgh_residuals(self.pid, xv, r)
        return r

    def jacobian(self, x: npt.ArrayLike) -> Matrix:
        """J(x), shape (m, n)."""
        xv = self._vec(x)
        jac = np.empty((self.m, self.n))
        mgh_jacobian(self.pid, xv, jac)
        return jac

    def objective(self, x: npt.ArrayLike) -> float:
        """f(x) = sum r_i(x)^2."""
        xv = self._vec(x)
        return float(mgh_objective(xv, np.empty(self.n), False, self.data()))

    def gradient(self, x: npt.ArrayLike) -> Vector:
        """grad f(x) = 2 J(x)^T r(x)."""
        xv = self._vec(x)
        g = np.empty(self.n)
        mgh_objective(xv, g, True, self.data())
        return g

    def _vec(self, x: npt.ArrayLike) -> Vector:
        # A fresh writable C-contiguous float64 copy: the one array type the compiled
        # functions are specialised for, and the caller's array is never touched.
        xv = np.array(x, dtype=np.float64).reshape(-1)
        if xv.shape != (self.n,):
            raise ValueError(f"{self.name}: x must have shape ({self.n},), got {xv.shape}")
        return xv


def _frozen(values: npt.ArrayLike) -> Vector:
    a = np.array(values, dtype=np.float64).reshape(-1)
    a.setflags(write=False)
    return a


def _grid_start(n: int) -> Vector:
    # #28/#29: x0_j = t_j (t_j - 1), t_j = j h, h = 1/(n+1)
    t = np.arange(1, n + 1, dtype=np.float64) / (n + 1.0)
    return t * (t - 1.0)


# name -> (MGH number, default n, whether n may vary)
_CATALOGUE: dict[str, tuple[int, int, bool]] = {
    "rosenbrock": (1, 2, False),
    "freudenstein_roth": (2, 2, False),
    "powell_badly_scaled": (3, 2, False),
    "brown_badly_scaled": (4, 2, False),
    "beale": (5, 2, False),
    "jennrich_sampson": (6, 2, False),
    "helical_valley": (7, 3, False),
    "bard": (8, 3, False),
    "gaussian": (9, 3, False),
    "meyer": (10, 3, False),
    "gulf": (11, 3, False),
    "box_3d": (12, 3, False),
    "powell_singular": (13, 4, False),
    "wood": (14, 4, False),
    "kowalik_osborne": (15, 4, False),
    "brown_dennis": (16, 4, False),
    "osborne1": (17, 5, False),
    "biggs_exp6": (18, 6, False),
    "osborne2": (19, 11, False),
    "watson": (20, 6, True),
    "extended_rosenbrock": (21, 10, True),
    "extended_powell_singular": (22, 4, True),
    "penalty1": (23, 4, True),
    "penalty2": (24, 4, True),
    "variably_dimensioned": (25, 10, True),
    "trigonometric": (26, 10, True),
    "brown_almost_linear": (27, 10, True),
    "discrete_boundary_value": (28, 10, True),
    "discrete_integral_equation": (29, 10, True),
    "broyden_tridiagonal": (30, 10, True),
    "broyden_banded": (31, 10, True),
    "linear_full_rank": (32, 5, True),
    "linear_rank1": (33, 5, True),
    "linear_rank1_zero": (34, 5, True),
    "chebyquad": (35, 8, True),
}

NAMES: tuple[str, ...] = tuple(_CATALOGUE)


def _need(cond: bool, name: str, what: str) -> None:
    if not cond:
        raise ValueError(f"{name}: {what}")


def _spec(
    name: str, n: int, m: int | None
) -> tuple[int, Vector, float, Vector | None, tuple[float, ...]]:
    """(m, x0, f_star, x_star, local_minima) of one instance; ValueError where unknown.

    f* values are MGH's (6 significant digits); "LM:" gives the value reproduced with
    scipy least_squares(method="lm") at ftol=xtol=gtol=1e-15 (tests re-check them).
    """

    def fixed_m(default: int) -> int:
        _need(m is None or m == default, name, f"m is fixed at {default} (f* known only there)")
        return default

    if name == "rosenbrock":  # #1: f* = 0 at (1, 1)
        return fixed_m(2), _frozen([-1.2, 1.0]), 0.0, _frozen([1.0, 1.0]), ()
    if name == "freudenstein_roth":
        # #2: f* = 0 at (5, 4); local min f = 48.9842... at (11.41..., -0.8968...)
        # (LM from (11.4, -0.9): 48.984253679240 at (11.41278, -0.896805)).
        return fixed_m(2), _frozen([0.5, -2.0]), 0.0, _frozen([5.0, 4.0]), (48.98425367924,)
    if name == "powell_badly_scaled":
        # #3: f* = 0 at (1.098...e-5, 9.106...). Not unique: the problem is symmetric in
        # (x1, x2), so the swapped point is a minimizer too -> x_star None.
        return fixed_m(2), _frozen([0.0, 1.0]), 0.0, None, ()
    if name == "brown_badly_scaled":  # #4: f* = 0 at (1e6, 2e-6)
        return fixed_m(3), _frozen([1.0, 1.0]), 0.0, _frozen([1e6, 2e-6]), ()
    if name == "beale":  # #5: f* = 0 at (3, 0.5)
        return fixed_m(3), _frozen([1.0, 1.0]), 0.0, _frozen([3.0, 0.5]), ()
    if name == "jennrich_sampson":
        # #6: f* = 124.362 at x1 = x2 = 0.2578 for m = 10 (LM: 124.36218236).
        return fixed_m(10), _frozen([0.3, 0.4]), 124.362, None, ()
    if name == "helical_valley":  # #7: f* = 0 at (1, 0, 0)
        return fixed_m(3), _frozen([-1.0, 0.0, 0.0]), 0.0, _frozen([1.0, 0.0, 0.0]), ()
    if name == "bard":
        # #8: f* = 8.21487e-3 (LM: 8.2148773066e-3 at (0.0824106, 1.13304, 2.34370));
        # f = 17.4286... at (0.8406..., -inf, -inf): there u/(v x2 + w x3) -> 0 and
        # x1 = mean(y) = 0.840667, so the value is sum (y - mean y)^2 = 17.4286933...
        return fixed_m(15), _frozen([1.0, 1.0, 1.0]), 8.21487e-3, None, (17.42869333,)
    if name == "gaussian":
        # #9: f* = 1.12793e-8 (LM: 1.1279327696e-8).
        return fixed_m(15), _frozen([0.4, 1.0, 0.0]), 1.12793e-8, None, ()
    if name == "meyer":
        # #10: f* = 87.9458 (LM: 87.945855170).
        return fixed_m(16), _frozen([0.02, 4000.0, 250.0]), 87.9458, None, ()
    if name == "gulf":
        # #11: f* = 0 at (50, 25, 1.5) for any 3 <= m <= 100 (the data are generated by
        # that x); m = 99 is the usual choice (MGH leave it open).
        mm = 99 if m is None else m
        _need(3 <= mm <= 100, name, "needs 3 <= m <= 100")
        return mm, _frozen([5.0, 2.5, 0.15]), 0.0, _frozen([50.0, 25.0, 1.5]), ()
    if name == "box_3d":
        # #12: f* = 0 at (1, 10, 1), (10, 1, -1) and wherever x1 = x2, x3 = 0 -> no
        # unique x_star. MGH's standard m is 10; any m >= 3 keeps f* = 0.
        mm = 10 if m is None else m
        _need(mm >= 3, name, "needs m >= 3")
        return mm, _frozen([0.0, 10.0, 20.0]), 0.0, None, ()
    if name == "powell_singular":  # #13: f* = 0 at the origin (singular Hessian there)
        return fixed_m(4), _frozen([3.0, -1.0, 0.0, 1.0]), 0.0, _frozen(np.zeros(4)), ()
    if name == "wood":
        # #14: f* = 0 at (1, 1, 1, 1). Non-minimizing stationary point (a saddle: the
        # Hessian has one negative eigenvalue, about -0.12) at (-0.96797, 0.94714,
        # -0.96952, 0.95125) with f = 7.8769671652 (computed here: scipy.optimize.root
        # of the gradient from (-0.97, 0.95, -0.97, 0.95)); optimizers crawl near it.
        x0 = _frozen([-3.0, -1.0, -3.0, -1.0])
        return fixed_m(6), x0, 0.0, _frozen(np.ones(4)), (7.8769671652,)
    if name == "kowalik_osborne":
        # #15: f* = 3.07505e-4 (LM: 3.0750560385e-4); f = 1.02734e-3 at
        # (+inf, -14.07..., -inf, -inf): with x1, x3, x4 -> inf in fixed ratios the model
        # tends to a u (u + x2) / (u + b), whose LM fit gives 1.0273430487e-3 at
        # (a, x2, b) = (-0.0220959, -14.07588, 0.623801).
        return (
            fixed_m(11),
            _frozen([0.25, 0.39, 0.415, 0.39]),
            3.07505e-4,
            None,
            (1.0273430487e-3,),
        )
    if name == "brown_dennis":
        # #16: f* = 85822.2 for m = 20 (LM: 85822.201626).
        return fixed_m(20), _frozen([25.0, 5.0, -5.0, -1.0]), 85822.2, None, ()
    if name == "osborne1":
        # #17: f* = 5.46489e-5 (LM: 5.4648946975e-5).
        return fixed_m(33), _frozen([0.5, 1.5, -1.0, 0.01, 0.02]), 5.46489e-5, None, ()
    if name == "biggs_exp6":
        # #18: f* = 0 at (1, 10, 1, 5, 4, 3), the point that generated the data (also at
        # (4, 10, 3, 5, 1, 1): terms 1 and 3 swap -> x_star None); LM reaches 0 from x0.
        # MGH: f = 5.65565e-3 for m = 13, a local minimum (LM from a random start:
        # 5.6556499255e-3 at (1.7114, 1.7114, 4.2326, 1.9063, 17.683, -5.1866), a valley
        # along which x1 = x2 and only x3 - x4 matters).
        return fixed_m(13), _frozen([1.0, 2.0, 1.0, 1.0, 1.0, 1.0]), 0.0, None, (5.65565e-3,)
    if name == "osborne2":
        # #19: f* = 4.01377e-2 (LM: 4.0137736294e-2).
        x0 = _frozen([1.3, 0.65, 0.65, 0.7, 0.6, 3.0, 5.0, 7.0, 2.0, 4.5, 5.5])
        return fixed_m(65), x0, 4.01377e-2, None, ()
    if name == "watson":
        # #20: m = 31; f* = 2.28767e-3 (n = 6), 1.39976e-6 (n = 9), 4.72238e-10 (n = 12)
        # (LM: 2.2876700536e-3, 1.3997601381e-6, 4.7223811025e-10).
        stars = {6: 2.28767e-3, 9: 1.39976e-6, 12: 4.72238e-10}
        _need(n in stars, name, f"f* is known for n in {sorted(stars)}")
        return fixed_m(31), _frozen(np.zeros(n)), stars[n], None, ()
    if name == "extended_rosenbrock":  # #21: f* = 0 at (1, ..., 1)
        _need(n % 2 == 0, name, "n must be even")
        x0 = np.tile([-1.2, 1.0], n // 2)
        return fixed_m(n), _frozen(x0), 0.0, _frozen(np.ones(n)), ()
    if name == "extended_powell_singular":  # #22: f* = 0 at the origin
        _need(n % 4 == 0, name, "n must be a multiple of 4")
        x0 = np.tile([3.0, -1.0, 0.0, 1.0], n // 4)
        return fixed_m(n), _frozen(x0), 0.0, _frozen(np.zeros(n)), ()
    if name == "penalty1":
        # #23: m = n + 1; f* = 2.24997e-5 (n = 4), 7.08765e-5 (n = 10)
        # (LM: 2.2499775009e-5, 7.0876514671e-5).
        stars = {4: 2.24997e-5, 10: 7.08765e-5}
        _need(n in stars, name, f"f* is known for n in {sorted(stars)}")
        x0 = np.arange(1, n + 1, dtype=np.float64)
        return fixed_m(n + 1), _frozen(x0), stars[n], None, ()
    if name == "penalty2":
        # #24: m = 2n; f* = 9.37629e-6 (n = 4), 2.93660e-4 (n = 10)
        # (LM: 9.3762930074e-6, 2.9366053746e-4).
        stars = {4: 9.37629e-6, 10: 2.93660e-4}
        _need(n in stars, name, f"f* is known for n in {sorted(stars)}")
        return fixed_m(2 * n), _frozen(np.full(n, 0.5)), stars[n], None, ()
    if name == "variably_dimensioned":  # #25: m = n + 2, f* = 0 at (1, ..., 1)
        x0 = 1.0 - np.arange(1, n + 1, dtype=np.float64) / n
        return fixed_m(n + 2), _frozen(x0), 0.0, _frozen(np.ones(n)), ()
    if name == "trigonometric":
        # #26: f* = 0 (e.g. at x = 0, and every 2 pi shift of it -> x_star None).
        # Not in the paper: for n = 10 LM stalls from x0 at a local minimum with
        # f = 2.7950561219e-5 (gradient ~1e-9 there), a value also quoted in later
        # studies of this set.
        local = (2.7950561219e-5,) if n == 10 else ()
        return fixed_m(n), _frozen(np.full(n, 1.0 / n)), 0.0, None, local
    if name == "brown_almost_linear":
        # #27: f* = 0 at (a, ..., a, a^(1-n)) with n a^n - (n+1) a^(n-1) + 1 = 0, e.g.
        # a = 1 (several roots -> x_star None); f = 1 at (0, ..., 0, n+1), a stationary
        # point for n >= 3.
        _need(n >= 2, name, "needs n >= 2")
        local = (1.0,) if n >= 3 else ()
        return fixed_m(n), _frozen(np.full(n, 0.5)), 0.0, None, local
    if name == "discrete_boundary_value":  # #28: f* = 0 (no closed-form x*)
        return fixed_m(n), _frozen(_grid_start(n)), 0.0, None, ()
    if name == "discrete_integral_equation":  # #29: f* = 0 (no closed-form x*)
        return fixed_m(n), _frozen(_grid_start(n)), 0.0, None, ()
    if name == "broyden_tridiagonal":  # #30: f* = 0 (no closed-form x*)
        return fixed_m(n), _frozen(np.full(n, -1.0)), 0.0, None, ()
    if name == "broyden_banded":  # #31: f* = 0 (no closed-form x*)
        return fixed_m(n), _frozen(np.full(n, -1.0)), 0.0, None, ()
    if name == "linear_full_rank":
        # #32: f* = m - n at x = (-1, ..., -1) for any m >= n; m = 2n by default.
        mm = 2 * n if m is None else m
        _need(mm >= n, name, "needs m >= n")
        return mm, _frozen(np.ones(n)), float(mm - n), _frozen(-np.ones(n)), ()
    if name == "linear_rank1":
        # #33: f* = m(m-1) / (2(2m+1)) on the hyperplane sum j x_j = 3/(2m+1) (no unique x*).
        mm = 2 * n if m is None else m
        _need(mm >= n, name, "needs m >= n")
        return mm, _frozen(np.ones(n)), mm * (mm - 1.0) / (2.0 * (2.0 * mm + 1.0)), None, ()
    if name == "linear_rank1_zero":
        # #34: f* = (m^2 + 3m - 6) / (2(2m - 3)) on the hyperplane
        # sum_{j=2}^{n-1} j x_j = 3/(2m-3) (no unique x*).
        mm = 2 * n if m is None else m
        _need(mm >= n and n >= 3, name, "needs m >= n >= 3")
        f_star = (mm * mm + 3.0 * mm - 6.0) / (2.0 * (2.0 * mm - 3.0))
        return mm, _frozen(np.ones(n)), f_star, None, ()
    if name == "chebyquad":
        # #35: m = n here; f* = 0 for n = 1..7 and 9, 3.51687e-3 (n = 8), 6.50395e-3
        # (n = 10) (LM: 3.5168737257e-3, 6.5039548009e-3).
        stars = {1: 0.0, 2: 0.0, 3: 0.0, 4: 0.0, 5: 0.0, 6: 0.0, 7: 0.0, 9: 0.0}
        stars |= {8: 3.51687e-3, 10: 6.50395e-3}
        _need(n in stars, name, f"f* is known for n in {sorted(stars)}")
        x0 = np.arange(1, n + 1, dtype=np.float64) / (n + 1.0)
        return fixed_m(n), _frozen(x0), stars[n], None, ()
    raise AssertionError(name)  # unreachable: names come from _CATALOGUE


def problem(name: str, n: int | None = None, m: int | None = None) -> MGHProblem:
    """The MGH problem ``name`` with n unknowns (default: its standard n).

    ``m`` may be given only where MGH leave it free and f* is known for every m
    (gulf, box_3d, linear_*); otherwise it is fixed and a different value is refused.

    Raises:
        ValueError: Unknown name, an n for a fixed-size problem other than its own, or
            an (n, m) for which f* is not known.
    """
    if name not in _CATALOGUE:
        raise ValueError(f"unknown MGH problem {name!r}; known: {', '.join(NAMES)}")
    number, default_n, variable = _CATALOGUE[name]
    nn = default_n if n is None else int(n)
    _need(variable or nn == default_n, name, f"n is fixed at {default_n}")
    _need(nn >= 1, name, "n must be positive")
    mm, x0, f_star, x_star, local = _spec(name, nn, m)
    return MGHProblem(
        name=name,
        number=number,
        pid=number,
        n=nn,
        m=mm,
        x0=x0,
        f_star=float(f_star),
        x_star=x_star,
        local_minima=local,
    )


# The standard instances: every problem at its default size, plus the sizes MGH
# tabulate f* for (Watson n = 9, extended Rosenbrock n = 2 and 100, extended Powell
# n = 40, Penalty I n = 10).
_STANDARD: tuple[tuple[str, int | None], ...] = (
    *((name, None) for name in NAMES),
    ("watson", 9),
    ("extended_rosenbrock", 2),
    ("extended_rosenbrock", 100),
    ("extended_powell_singular", 40),
    ("penalty1", 10),
)
PROBLEMS: tuple[MGHProblem, ...] = tuple(problem(name, n) for name, n in _STANDARD)

__all__ = [
    "MGHProblem",
    "NAMES",
    "PROBLEMS",
    "mgh_jacobian",
    "mgh_objective",
    "mgh_residuals",
    "problem",
]
