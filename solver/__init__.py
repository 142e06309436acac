"""Bound-constrained multi-pass BFGS with an analyzer, and the IK built on it.

numpy + a numba-compiled core; no web, logging or environment access here.
Layers (each imports only those above it; see ARCHITECTURE.md):
    optim/    the article's optimizer (knows no kinematics)
    model/    chains, joints, rotations, forward kinematics, importers (knows no optimizer)
    ik/       inverse kinematics on both: targets, options, results, the solver object
    path/     planned clips, on ik's documented surface
    precompile.py   ``warmup``: load or compile every compiled path before serving
"""

from .errors import DimensionMismatch, IKError, InvalidModel, InvalidProblem
from .ik import IKOptions, IKResult, IKSolver, IKStatus, Target, solve
from .model import Chain, Effector, EffectorMode, Joint, JointKind, Transform, build_chain
from .optim import (
    TERMINATION_MESSAGES,
    AcceptedStep,
    Action,
    AnalyzerPolicy,
    GoalStatus,
    GradientMode,
    MinimizeOptions,
    MinimizeResult,
    PassRecord,
    PassStart,
    Termination,
    minimize,
)
from .path import PathOptions, PlannedPath, plan_path
from .precompile import warmup

__all__ = [
    "AcceptedStep",
    "Action",
    "Chain",
    "Effector",
    "EffectorMode",
    "IKOptions",
    "IKResult",
    "IKSolver",
    "IKStatus",
    "Joint",
    "JointKind",
    "PathOptions",
    "PlannedPath",
    "Target",
    "Transform",
    "build_chain",
    "plan_path",
    "solve",
    "warmup",
    "AnalyzerPolicy",
    "DimensionMismatch",
    "GoalStatus",
    "GradientMode",
    "IKError",
    "InvalidModel",
    "InvalidProblem",
    "MinimizeOptions",
    "MinimizeResult",
    "PassRecord",
    "PassStart",
    "TERMINATION_MESSAGES",
    "Termination",
    "minimize",
]
