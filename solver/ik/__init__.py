"""Inverse kinematics on the optimizer: targets, options, results, the compiled
kinematics and per-frame solve, and the solver object.

Depends on ``solver.model`` (chains) and ``solver.optim`` (the optimizer). Where
things are:
    solver.py       ``IKSolver`` (solve, track, and the surface the planner uses)
    task.py         loading targets into the compiled arrays; what they leave free
    frame.py        the compiled per-frame solve (validate, solve, report errors)
    polish.py       Levenberg-Marquardt steps for an answer a few tolerances short
    kinematics.py   the IK objective, its exact gradient, the goal measure, errors
    metric.py       the Gauss-Newton metric handed to the optimizer; null-space step
    spd.py          its inverses: whole, block by block (compiled)
    split.py        a cold solve's independent groups of effectors, solved apart,
                    a group's trunk effectors first
    packing.py      an ``IKOptions`` as the compiled core takes it, once per options
    settled.py      for the optimizer's restarts: how settled each variable is (partial
                    restarts), which variables are angles (turn restarts)
    targets.py      ``Target`` and its packed row, ``TargetRows``, ``Pole``
    blend.py        blend weights between 0 and 1: the goal part of the way there
    poles.py        pole targets: the shaping pass, the default pulled link
    pole_term.py    the pole term of the objective (compiled)
    options.py      ``IKOptions``, ``STREAM_DEFAULTS``
    continuity.py   a stream's continuity policy (``Continuity``) and ``FrameStep``
    result.py       ``IKResult``, ``IKStatus``, ``EffectorError``
"""

from .continuity import Continuity, FrameStep
from .options import STREAM_DEFAULTS, IKOptions
from .poles import default_pole_link, pole_node
from .result import EffectorError, IKResult, IKStatus
from .solver import IKData, IKSolver, StreamState, solve
from .targets import (
    GIVEN_DIRECTION,
    GIVEN_POSITION,
    GIVEN_ROTATION,
    TARGET_PLACEHOLDER_ROW,
    TARGET_ROW,
    Pole,
    Target,
    TargetRows,
    check_weight,
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
    "Pole",
    "StreamState",
    "Target",
    "TargetRows",
    "check_weight",
    "default_pole_link",
    "pole_node",
    "pose_targets",
    "solve",
]
