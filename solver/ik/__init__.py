"""Inverse kinematics on the optimizer: targets, options, results, the compiled
kinematics and per-frame solve, and the solver object.

Depends on ``solver.model`` (chains) and ``solver.optim`` (the optimizer). Where
things are:
    solver.py       ``IKSolver`` (solve, track, and the surface the planner uses)
    task.py         loading targets into the compiled arrays; what they leave free
    frame.py        the compiled per-frame solve (validate, solve, report errors)
    kinematics.py   the IK objective, its exact gradient, the goal measure, errors
    metric.py       the Gauss-Newton metric handed to the optimizer; null-space step
    targets.py      ``Target`` and its packed row
    options.py      ``IKOptions``, ``STREAM_DEFAULTS``
    continuity.py   a stream's continuity policy (``Continuity``) and ``FrameStep``
    result.py       ``IKResult``, ``IKStatus``, ``EffectorError``
"""

from .continuity import Continuity, FrameStep
from .options import STREAM_DEFAULTS, IKOptions
from .result import EffectorError, IKResult, IKStatus
from .solver import IKData, IKSolver, StreamState, solve
from .targets import (
    GIVEN_DIRECTION,
    GIVEN_POSITION,
    GIVEN_ROTATION,
    TARGET_PLACEHOLDER_ROW,
    TARGET_ROW,
    Target,
    pose_targets,
)

__all__ = [
    "GIVEN_DIRECTION",
    "GIVEN_POSITION",
    "GIVEN_ROTATION",
    "STREAM_DEFAULTS",
    "Continuity",
    "TARGET_PLACEHOLDER_ROW",
    "TARGET_ROW",
    "EffectorError",
    "FrameStep",
    "IKData",
    "IKOptions",
    "IKResult",
    "IKSolver",
    "IKStatus",
    "StreamState",
    "Target",
    "pose_targets",
    "solve",
]
