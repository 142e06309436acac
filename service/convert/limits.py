"""Rotation limits must be radians: the check shared by JSON joints and skeleton bones."""

from __future__ import annotations

import math
from collections.abc import Sequence

from ..errors import invalid_problem

# The largest rotation limit a request may give [rad]: a full turn, plus room for a
# rounded 2*pi (6.2832). Beyond it the number is almost surely degrees (an elbow's
# "upper": [150]), which would otherwise be taken as 24 turns and leave the joint
# practically unlimited. URDF files are not checked: the format is radians by
# definition, and real files give unlimited joints limits such as +-1e16 or 2*pi + eps.
MAX_ROTATION_LIMIT_RAD = 2 * math.pi + 1e-3


def check_radians(
    lower: Sequence[float] | None, upper: Sequence[float] | None, what: str, where: str
) -> None:
    """Refuse a rotation limit beyond a full turn, saying that limits are radians.

    Raises:
        ServiceError: ``invalid_problem`` naming ``<where>.lower`` or ``<where>.upper``.
    """
    for side, limits in (("lower", lower), ("upper", upper)):
        for value in limits or ():
            if abs(value) <= MAX_ROTATION_LIMIT_RAD:
                continue
            message = f"{what}: {side} limit {value:g} is beyond 2*pi: limits are in radians"
            if abs(value) <= 360:
                message += f"; {value:g} degrees is {math.radians(value):.4f}"
            raise invalid_problem(message, f"{where}.{side}")
