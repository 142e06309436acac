"""Exceptions raised by ``solver`` for invalid input; outcomes are never exceptions."""

from __future__ import annotations


class IKError(ValueError):
    """Root of the solver's exceptions (a ValueError: the caller passed bad input)."""


class InvalidProblem(IKError):
    """The problem is inconsistent: bad bounds, non-finite start, bad option value."""


class DimensionMismatch(InvalidProblem):
    """An array's shape does not match the problem's dimension."""


class InvalidModel(IKError):
    """A kinematic model failed validation; ``joint`` and ``field`` say where.

    Args:
        message: What is wrong.
        joint: Name of the joint (or link / effector) at fault, if any.
        field: Name of the offending field, e.g. ``"lower"`` or ``"axis"``.
    """

    def __init__(self, message: str, *, joint: str | None = None, field: str | None = None) -> None:
        self.joint = joint
        self.field = field
        where = ".".join(p for p in (joint, field) if p)
        super().__init__(f"{where}: {message}" if where else message)
