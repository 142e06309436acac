"""The pole term of the IK objective (compiled): w |o_k - pole|^2 per pole, where o_k
is the origin of the pulled link's node k (a knee, an elbow).

It is on only during the shaping pass of a frame with poles (``poles``): the block in
MISC after the IK's own entries holds the count of poles switched on, then per pole
(node, weight, x, y, z); a count of 0 (every frame without poles) costs one read.

The gradient walks k's ancestors as ``kinematics.effector_terms`` walks an effector's:
a revolute node j moves o_k by a_j x (o_k - o_j), a prismatic one by a_j (node k's own
rotation leaves its origin where it is: its column is zero).
"""

from __future__ import annotations

from .._jit import jit_inline
from ..model.forward import axis_and_point_rate
from ..model.layout import ND_T, NI_DOF, NI_PARENT

POLE_WIDTH = 5  # node, weight, point (3)
POLE_NODE = 0
POLE_WEIGHT = 1
POLE_POINT = 2


def pole_block_size(n_effectors: int) -> int:
    """Length of the pole block (count, then one row per effector) in MISC."""
    return 1 + POLE_WIDTH * n_effectors


@jit_inline
def pole_terms(q, g, need_grad, ni, nd, misc, start):  # type: ignore[no-untyped-def]
    """The poles' part of f (and of g) for the frames FK last wrote into nd; the
    block starts at misc[start] (its count)."""
    f = 0.0
    count = int(misc[start])
    for p in range(count):
        b = start + 1 + POLE_WIDTH * p
        k = int(misc[b + POLE_NODE])
        w = misc[b + POLE_WEIGHT]
        ox = nd[k, ND_T]
        oy = nd[k, ND_T + 1]
        oz = nd[k, ND_T + 2]
        rx = ox - misc[b + POLE_POINT]
        ry = oy - misc[b + POLE_POINT + 1]
        rz = oz - misc[b + POLE_POINT + 2]
        f += w * (rx * rx + ry * ry + rz * rz)
        if not need_grad:
            continue
        j = k
        while j >= 0:
            d = ni[j, NI_DOF]
            if d >= 0:
                _, _, _, jx, jy, jz = axis_and_point_rate(nd, ni, j, ox, oy, oz)
                g[d] += 2.0 * w * (jx * rx + jy * ry + jz * rz)
            j = ni[j, NI_PARENT]
    return f
