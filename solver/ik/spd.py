"""Inverses of symmetric positive definite matrices in place, with no allocation
(compiled): the Cholesky factor, the whole inverse, and the inverse block by block
where the matrix is block diagonal up to a permutation (a tree's limbs that share no
variable). The Gauss-Newton metric (``metric``) and the planner's kernels use them."""

from __future__ import annotations

import math

from .._jit import jit_inline, jit_leaf


@jit_inline
def cholesky_in_place(m, rows):  # type: ignore[no-untyped-def]
    """m's leading rows x rows block (symmetric; its lower triangle is read) <- its
    lower Cholesky factor L, in the lower triangle; False if not positive definite."""
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
def invert_spd_in_place(m):  # type: ignore[no-untyped-def]
    """m <- m^-1 for a symmetric positive definite m (Cholesky); False if not SPD.

    Allocation-free, as LAPACK's potrf + potri: L goes into the lower triangle, is
    inverted there, and inv(L)^T inv(L) is written column by column into the upper
    triangle (each column's diagonal last: it is the only inv(L) entry that column
    still reads), then mirrored. It runs once per solver iteration; an n x n
    scratch allocation per call cost more than the arithmetic at 6-7 joints.
    """
    n = m.shape[0]
    if not cholesky_in_place(m, n):
        return False
    # inv(L) in place (lower triangle).
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
    return True


@jit_leaf  # a call, not inlined: the metric of a 7-joint arm never takes it
def invert_spd_by_blocks(m, root, order):  # type: ignore[no-untyped-def]
    """``invert_spd_in_place`` on each diagonal block of m separately; False if not SPD.

    A tree's limbs that share no variable give J^T W J exact zeros between them (g1,
    its pelvis the base: each leg's 6 variables couple with nothing else), so m is
    block diagonal up to a permutation and so is its inverse. The blocks are the
    components of the graph of m's nonzero entries (``root[i]``: the smallest index
    in i's; ``order``: the indices, block by block, ascending within each). Each
    block runs the same three loops as the whole matrix, in the same index order,
    minus the terms with a factor from another block: those are exact zeros (their
    Cholesky and inverse entries come out +0.0, and adding +-0.0 to a sum that is
    never -0.0 changes nothing), so every entry is the same, bit for bit, and the
    work falls from n^3 to the sum of the blocks' cubes (g1: 29^3 -> 17^3 + 2 x 6^3).
    One block: ``invert_spd_in_place`` itself.
    """
    n = m.shape[0]
    for i in range(n):
        root[i] = i
    for i in range(n):
        for j in range(i):
            if m[i, j] != 0.0:
                a = int(root[i])
                while root[a] != a:
                    a = int(root[a])
                b = int(root[j])
                while root[b] != b:
                    b = int(root[b])
                if a < b:
                    root[b] = a
                elif b < a:
                    root[a] = b
    blocks = 0
    for i in range(n):  # root[i] < i is final already: point i straight at it
        root[i] = root[int(root[i])]
        if root[i] == i:
            blocks += 1
    if blocks == 1:
        return invert_spd_in_place(m)
    count = 0
    for r in range(n):
        if root[r] != r:
            continue
        start = count
        for i in range(r, n):
            if root[i] == r:
                order[count] = i
                count += 1
        if not _invert_block(m, order, start, count):
            return False
    for i in range(n):
        for j in range(n):
            if root[i] != root[j]:
                m[i, j] = 0.0
    return True


@jit_inline
def _invert_block(m, order, s, e):  # type: ignore[no-untyped-def]
    """``invert_spd_in_place``'s loops on the rows and columns order[s:e] of m."""
    # Cholesky (``cholesky_in_place``).
    for a in range(s, e):
        j = int(order[a])
        acc = m[j, j]
        for b in range(s, a):
            k = int(order[b])
            acc -= m[j, k] * m[j, k]
        if not acc > 0.0:
            return False
        d = math.sqrt(acc)
        m[j, j] = d
        for c in range(a + 1, e):
            i = int(order[c])
            acc = m[i, j]
            for b in range(s, a):
                k = int(order[b])
                acc -= m[i, k] * m[j, k]
            m[i, j] = acc / d
    # inv(L) in place (lower triangle).
    for a in range(s, e):
        j = int(order[a])
        m[j, j] = 1.0 / m[j, j]
        for c in range(a + 1, e):
            i = int(order[c])
            acc = 0.0
            for b in range(a, c):
                k = int(order[b])
                acc -= m[i, k] * m[k, j]
            m[i, j] = acc / m[i, i]
    # inv(L)^T inv(L) into the upper triangle, each column's diagonal last.
    for a in range(s, e):
        j = int(order[a])
        for c in range(s, a + 1):
            i = int(order[c])
            acc = 0.0
            for b in range(a, e):
                k = int(order[b])
                acc += m[k, i] * m[k, j]
            m[i, j] = acc
    for a in range(s, e):
        j = int(order[a])
        for c in range(s, a):
            i = int(order[c])
            m[j, i] = m[i, j]
    return True
