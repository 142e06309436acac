"""Bound-constrained multi-pass BFGS with an analyzer, and the IK built on it.

numpy + a numba-compiled core; no web, logging or environment access here.
"""

from .analyzer import AnalyzerPolicy
from .bfgs import minimize
from .errors import DimensionMismatch, IKError, InvalidModel, InvalidProblem
from .termination import TERMINATION_MESSAGES, Action, GoalStatus, PassStart, Termination
from .types import GradientMode, MinimizeOptions, MinimizeResult, PassRecord

__all__ = [
    "Action",
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
