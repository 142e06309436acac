"""Registering an objective, and how the compiled core reaches it without receiving
it as a value.

numba can pass a compiled function as an argument, but a caller that receives one
whose body uses libm (cos, sqrt, ...) cannot be written to the on-disk cache, so the
IK core would recompile (tens of seconds) in every process. Instead an objective is
*registered* for the numba type of its ``data`` tuple, and the core calls
``call_objective(None, ...)``: at compile time the overload below looks the data
type up and binds the registered function statically, which caches like any
direct call. Passing a compiled function as ``fg`` still works (the generic
``minimize`` path for user objectives); it is compiled per process.

``register_objective`` is public (``solver.optim``): ``minimize`` of a registered
objective loads the core from numba's cache instead of compiling it in every
process. An objective registered from outside solver/ is compiled into that cache
under solver/'s source stamp: see ``solver._jit`` for what to do after editing one.
"""

from __future__ import annotations

from typing import Any

import numba
from numba.core import types
from numba.extending import overload

# (numba type of data, fg, goal_fn, metric_fn, restart_keep_fn, restart_period_fn),
# each function None when not given
_REGISTRY: list[tuple[Any, Any, Any, Any, Any, Any]] = []


def register_objective(
    fg: Any,
    goal_fn: Any,
    data_example: tuple[Any, ...],
    metric_fn: Any = None,
    restart_keep_fn: Any = None,
    restart_period_fn: Any = None,
) -> None:
    """Bind ``fg`` to the numba type of ``data_example``.

    Args:
        fg: ``fg(x, g, need_grad, data) -> f``.
        goal_fn: Optional ``goal_fn(f, x, data) -> m``: the goal is m <= f_goal.
        data_example: A data tuple of the type the objective will receive.
        metric_fn: Optional ``metric_fn(x, g, lower, upper, data, h) -> int`` that
            writes a metric for the free variables into h and says what it wrote
            (``codes.MetricKind``): 0 nothing, 1 the inverse Hessian H, 2 the lower
            Cholesky factor L of H's inverse (H = (L L^T)^-1, L in h's lower
            triangle: the optimizer solves with it, ``cholesky``).
        restart_keep_fn: Optional ``restart_keep_fn(x, data, keep) -> int`` for random
            restarts (``restart``): writes into keep[i] how settled variable i is at
            x, from 0.0 (re-draw it) to 1.0 (keep its value: for the IK, a variable
            that moves only effectors already on target), and returns how many
            variables have a share above 0 (0: re-draw every variable).
        restart_period_fn: Optional ``restart_period_fn(data, period) -> int`` for
            turn restarts (``restart.turn_values``): writes into period[i] the period
            of f in variable i (f(x + period[i] e_i) = f(x); for the IK 2 pi for the
            angle of a revolute joint) or 0.0 where f is not periodic in it, and
            returns how many are periodic.
    """
    data_type = numba.typeof(data_example)
    for ty, f, *_ in _REGISTRY:
        if ty == data_type and f is not fg:
            raise ValueError(f"another objective is registered for data type {data_type}")
    _REGISTRY.append((data_type, fg, goal_fn, metric_fn, restart_keep_fn, restart_period_fn))


def registered_for(fg: Any) -> bool:
    return any(f is fg for _, f, *_ in _REGISTRY)


def _lookup(data_type: Any) -> tuple[Any, Any, Any, Any, Any]:
    for ty, fg, goal, metric, keep, period in _REGISTRY:
        if ty == data_type:
            return fg, goal, metric, keep, period
    raise TypeError(f"no objective registered for data of type {data_type}")


def call_objective(fg: Any, x: Any, g: Any, need_grad: bool, data: Any) -> float:
    """f(x) (and g) from ``fg``, or from the objective registered for ``data``."""
    if fg is None:
        fg = _lookup(numba.typeof(data))[0]
    return float(fg(x, g, need_grad, data))


def call_goal(fg: Any, f: float, x: Any, data: Any) -> float:
    """The goal measure at x: the registered goal function, else f itself."""
    if fg is None:
        goal = _lookup(numba.typeof(data))[1]
        if goal is not None:
            return float(goal(f, x, data))
    return f


@overload(call_objective, inline="always")
def _call_objective_compiled(fg, x, g, need_grad, data):  # type: ignore[no-untyped-def]
    # No annotations: numba compares the overload's parameters with the impl's.
    if isinstance(fg, types.NoneType):
        bound = _lookup(data)[0]

        def impl_registered(fg, x, g, need_grad, data):  # type: ignore[no-untyped-def]
            return bound(x, g, need_grad, data)

        return impl_registered

    def impl_value(fg, x, g, need_grad, data):  # type: ignore[no-untyped-def]
        return fg(x, g, need_grad, data)

    return impl_value


@overload(call_goal, inline="always")
def _call_goal_compiled(fg, f, x, data):  # type: ignore[no-untyped-def]
    if isinstance(fg, types.NoneType):
        goal = _lookup(data)[1]
        if goal is not None:

            def impl_goal(fg, f, x, data):  # type: ignore[no-untyped-def]
                return goal(f, x, data)

            return impl_goal

    def impl_f(fg, f, x, data):  # type: ignore[no-untyped-def]
        return f

    return impl_f


def call_metric(fg: Any, x: Any, g: Any, lo: Any, hi: Any, data: Any, h: Any) -> int:
    """Write the registered metric at x into h; what it wrote (``codes.MetricKind``),
    0 if there is none."""
    if fg is None:
        metric = _lookup(numba.typeof(data))[2]
        if metric is not None:
            return int(metric(x, g, lo, hi, data, h))
    return 0


@overload(call_metric, inline="always")
def _call_metric_compiled(fg, x, g, lo, hi, data, h):  # type: ignore[no-untyped-def]
    if isinstance(fg, types.NoneType):
        metric = _lookup(data)[2]
        if metric is not None:

            def impl_metric(fg, x, g, lo, hi, data, h):  # type: ignore[no-untyped-def]
                return metric(x, g, lo, hi, data, h)

            return impl_metric

    def impl_none(fg, x, g, lo, hi, data, h):  # type: ignore[no-untyped-def]
        return 0

    return impl_none


def call_restart_keep(fg: Any, x: Any, data: Any, keep: Any) -> int:
    """The registered restart shares at x into ``keep`` (see ``register_objective``);
    returns how many are above 0, 0 when there is no such function."""
    if fg is None:
        restart_keep = _lookup(numba.typeof(data))[3]
        if restart_keep is not None:
            return int(restart_keep(x, data, keep))
    return 0


@overload(call_restart_keep, inline="always")
def _call_restart_keep_compiled(fg, x, data, keep):  # type: ignore[no-untyped-def]
    if isinstance(fg, types.NoneType):
        restart_keep = _lookup(data)[3]
        if restart_keep is not None:

            def impl_keep(fg, x, data, keep):  # type: ignore[no-untyped-def]
                return restart_keep(x, data, keep)

            return impl_keep

    def impl_none(fg, x, data, keep):  # type: ignore[no-untyped-def]
        return 0

    return impl_none


def call_restart_period(fg: Any, data: Any, period: Any) -> int:
    """The registered periods of the variables into ``period`` (see
    ``register_objective``); returns how many are periodic, 0 when there is no such
    function (``period`` is then untouched)."""
    if fg is None:
        restart_period = _lookup(numba.typeof(data))[4]
        if restart_period is not None:
            return int(restart_period(data, period))
    return 0


@overload(call_restart_period, inline="always")
def _call_restart_period_compiled(fg, data, period):  # type: ignore[no-untyped-def]
    if isinstance(fg, types.NoneType):
        restart_period = _lookup(data)[4]
        if restart_period is not None:

            def impl_period(fg, data, period):  # type: ignore[no-untyped-def]
                return restart_period(data, period)

            return impl_period

    def impl_none(fg, data, period):  # type: ignore[no-untyped-def]
        return 0

    return impl_none
