"""Bound-constrained multi-pass BFGS with an analyzer, and the IK built on it.

numpy + a numba-compiled core; no web, logging or environment access here.
"""

from .analyzer import AnalyzerPolicy
from .bfgs import minimize
from .chain import Chain, Effector, EffectorMode, Joint, JointKind, Transform, build_chain
from .errors import DimensionMismatch, IKError, InvalidModel, InvalidProblem
from .ik import IKOptions, IKResult, IKSolver, IKStatus, Target, solve
from .termination import TERMINATION_MESSAGES, Action, GoalStatus, PassStart, Termination
from .types import AcceptedStep, GradientMode, MinimizeOptions, MinimizeResult, PassRecord
from .warmup import warmup

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
    "Target",
    "Transform",
    "build_chain",
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
