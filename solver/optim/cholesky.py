"""The Cholesky factor of a symmetric positive definite matrix in place, the inverse
from that factor, and the solve with it (compiled, allocation-free).

A metric may hand the optimizer the factor L of its matrix A (A = L L^T) instead of
the inverse H = A^-1 (``codes.METRIC_FACTOR``): the step is then two triangular
solves, n^2 multiply-adds, and the inverse (inv(L), then inv(L)^T inv(L): n^3 / 3
more, two thirds of the whole inverse's work) is completed only when something
needs H itself, a BFGS update or the H handed back at the end (``loop``). On a
27-variable tree (Tiago's three fingertips, re-seeded every iteration) an iteration
of the whole group went from ~31 to 14-16 us (bench/history/2026-11-29-metric-factor.md).
"""

from __future__ import annotations

import math

from .._jit import jit_inline


@jit_inline
def cholesky_in_place(m, rows):  # type: ignore[no-untyped-def]
    """m's leading rows x rows block (symmetric; its lower triangle is read) <- its
    lower Cholesky factor L, in the lower triangle; False if not positive definite.
    The strict upper triangle is left as it was."""
    for j in range(rows):
        s = m[j, j]
        for k in range(j):
            s -= m[j, k] * m[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        m[j, j] = d
        for i in range(j + 1, rows):
            s = m[i, j]
            for k in range(j):
                s -= m[i, k] * m[j, k]
            m[i, j] = s / d
    return True


@jit_inline
def inverse_from_cholesky(m):  # type: ignore[no-untyped-def]
    """m <- (L L^T)^-1 for the factor L in m's lower triangle (``cholesky_in_place``).

    As LAPACK's potri: L is inverted in place (lower triangle), and inv(L)^T inv(L)
    is written column by column into the upper triangle (each column's diagonal
    last: it is the only inv(L) entry that column still reads), then mirrored.
    """
    n = m.shape[0]
    for j in range(n):
        m[j, j] = 1.0 / m[j, j]
        for i in range(j + 1, n):
            s = 0.0
            for k in range(j, i):
                s -= m[i, k] * m[k, j]
            m[i, j] = s / m[i, i]
    # (m^-1)[i, j] = sum_{k >= j} inv(L)[k, i] inv(L)[k, j] for i <= j, into the upper
    # triangle; column j's diagonal overwrites inv(L)[j, j], which later columns do
    # not read (they sum over rows k > j only).
    for j in range(n):
        for i in range(j + 1):
            s = 0.0
            for k in range(j, n):
                s += m[k, i] * m[k, j]
            m[i, j] = s
    for j in range(n):
        for i in range(j):
            m[j, i] = m[i, j]


@jit_inline
def cholesky_solve(m, b, out):  # type: ignore[no-untyped-def]
    """out <- (L L^T)^-1 b for the factor L in m's lower triangle (forward, then back
    substitution; out may be b)."""
    n = m.shape[0]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= m[i, k] * out[k]
        out[i] = s / m[i, i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s -= m[k, i] * out[k]
        out[i] = s / m[i, i]
