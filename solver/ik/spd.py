"""Inverses of symmetric positive definite matrices in place, with no allocation
(compiled): the whole inverse (from ``optim.cholesky``'s factor), and the inverse
block by block where the matrix is block diagonal up to a permutation (a tree's
limbs that share no variable). The Gauss-Newton metric (``metric``) and the
planner's kernels use them."""

from __future__ import annotations

import math

from .._jit import jit_inline, jit_leaf
from ..optim.cholesky import cholesky_in_place, inverse_from_cholesky

__all__ = [
    "block_cubes",
    "cholesky_in_place",
    "find_blocks",
    "invert_blocks",
    "invert_spd_by_blocks",
    "invert_spd_in_place",
    "join_roots",
]


@jit_inline
def invert_spd_in_place(m):  # type: ignore[no-untyped-def]
    """m <- m^-1 for a symmetric positive definite m (Cholesky); False if not SPD.

    Allocation-free, as LAPACK's potrf + potri (``optim.cholesky``): L goes into the
    lower triangle, is inverted there, and inv(L)^T inv(L) fills the matrix. It runs
    once per solver iteration; an n x n scratch allocation per call cost more than
    the arithmetic at 6-7 joints.
    """
    if not cholesky_in_place(m, m.shape[0]):
        return False
    inverse_from_cholesky(m)
    return True


@jit_leaf  # a call, not inlined: the metric of a 7-joint arm never takes it
def invert_spd_by_blocks(m, root, order):  # type: ignore[no-untyped-def]
    """``invert_spd_in_place`` on each diagonal block of m separately; False if not SPD.

    A tree's limbs that share no variable give J^T W J exact zeros between them (g1,
    its pelvis the base: each leg's 6 variables couple with nothing else), so m is
    block diagonal up to a permutation and so is its inverse. The blocks are the
    components of the graph of m's nonzero entries (``find_blocks``). Each block
    runs the same three loops as the whole matrix, in the same index order, minus
    the terms with a factor from another block: those are exact zeros (their
    Cholesky and inverse entries come out +0.0, and adding +-0.0 to a sum that is
    never -0.0 changes nothing), so every entry is the same, bit for bit, and the
    work falls from n^3 to the sum of the blocks' cubes (g1: 29^3 -> 17^3 + 2 x 6^3).
    One block: ``invert_spd_in_place`` itself.
    """
    if find_blocks(m, root) == 1:
        return invert_spd_in_place(m)
    return invert_blocks(m, root, order)


@jit_inline
def join_roots(root, i, j):  # type: ignore[no-untyped-def]
    """Union-find: i's and j's components joined under the smaller of their roots
    (so that every pointer goes to a smaller index, which ``find_blocks``'s last
    pass relies on)."""
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


@jit_leaf
def find_blocks(m, root):  # type: ignore[no-untyped-def]
    """The diagonal blocks of m up to a permutation: the components of the graph of
    its nonzero entries (its lower triangle is read). ``root[i]`` <- the smallest
    index in i's component; returns how many there are."""
    n = m.shape[0]
    for i in range(n):
        root[i] = i
    for i in range(n):
        for j in range(i):
            if m[i, j] != 0.0:
                join_roots(root, i, j)
    blocks = 0
    for i in range(n):  # root[i] < i is final already: point i straight at it
        root[i] = root[int(root[i])]
        if root[i] == i:
            blocks += 1
    return blocks


@jit_inline
def block_cubes(root, counts):  # type: ignore[no-untyped-def]
    """The sum of the cubes of the blocks' sizes (``find_blocks``'s roots; ``counts``
    is scratch): the work of inverting them one by one, in units of n^3 / 2."""
    n = root.shape[0]
    for i in range(n):
        counts[i] = 0.0
    for i in range(n):
        counts[int(root[i])] += 1.0
    total = 0.0
    for i in range(n):
        total += counts[i] * counts[i] * counts[i]
    return total


@jit_leaf
def invert_blocks(m, root, order):  # type: ignore[no-untyped-def]
    """``invert_spd_by_blocks`` given ``find_blocks``'s roots (``order``: the indices,
    block by block, ascending within each); False if not SPD."""
    n = m.shape[0]
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
