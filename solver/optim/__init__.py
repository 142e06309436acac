"""The article's optimizer alone: bound-constrained multi-pass BFGS with the
Dennis-Schnabel line search, Hessian resets and the analyzer of termination codes.

Knows nothing of kinematics. Where things are:
    minimize.py     the public entry point ``minimize`` (validation, packing, results)
    loop.py         the compiled pass loop (termination check, step, analyzer call)
    line_search.py  the cubic backtrack and the article's curvature phase
    bfgs.py         the inverse BFGS update and the projected descent direction
    cholesky.py     the Cholesky factor a metric may hand over instead of H, its solve, H from it
    evaluate.py     f and g (analytic or finite differences), box projection
    restart.py      the seeded random restarts, partial restarts (keep what is settled),
                    turn restarts (a periodic variable a bound stops, the other way round)
    analyzer.py     the analyzer's policy table and its guards (``decide``)
    termination.py  termination codes, actions, goal statuses (the JSON strings)
    codes.py        their integer mirrors and the option / log layouts for the core
    objective.py    ``register_objective``: binding an objective for numba's cache
    options.py, result.py   ``MinimizeOptions``; ``MinimizeResult`` and its records
"""

from .analyzer import DEFAULT_TABLE, AnalyzerPolicy, PolicyTable
from .minimize import minimize
from .objective import register_objective
from .options import GradientMode, MinimizeOptions
from .result import AcceptedStep, MinimizeResult, PassRecord
from .termination import TERMINATION_MESSAGES, Action, GoalStatus, PassStart, Termination

__all__ = [
    "DEFAULT_TABLE",
    "TERMINATION_MESSAGES",
    "AcceptedStep",
    "Action",
    "AnalyzerPolicy",
    "GoalStatus",
    "GradientMode",
    "MinimizeOptions",
    "MinimizeResult",
    "PassRecord",
    "PassStart",
    "PolicyTable",
    "Termination",
    "minimize",
    "register_objective",
]
