"""The answer to one frame: ``IKResult``, its status, and its per-effector errors.

An ``IKResult`` is a NamedTuple over the compiled solve's output block (``frame``):
the few values every caller reads are fields, the rest is read from the block on
access.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..arrays import Matrix, Vector
from ..model.mimic import Followers
from ..optim import PassRecord, Termination
from ..optim import codes as C
from ..optim.minimize import unpack_pass_log


class IKStatus(enum.StrEnum):
    """The IK outcome a client acts on."""

    SOLVED = "solved"  # every effector within its tolerances
    # Converged outside tolerance (unreachable, or a local minimum): closest pose returned.
    NOT_REACHED = "not_reached"
    BUDGET_EXHAUSTED = "budget_exhausted"  # time or iterations ran out first; best pose returned
    NONFINITE = "nonfinite"  # the model produced NaN/inf (bad numbers); best finite pose returned


# In the order of ``frame.STATUS_*``.
STATUSES: tuple[IKStatus, ...] = (
    IKStatus.SOLVED,
    IKStatus.NOT_REACHED,
    IKStatus.BUDGET_EXHAUSTED,
    IKStatus.NONFINITE,
)


@dataclass(frozen=True, slots=True)
class EffectorError:
    """Pose error of one effector after a solve.

    Attributes:
        name: Effector name.
        position_error_m: Distance from the target position (None if not targeted).
        rotation_error_rad: Orientation / aim error (None for position-only).
        within_tolerance: Both errors within the tolerances.
    """

    name: str
    position_error_m: float | None
    rotation_error_rad: float | None
    within_tolerance: bool


@dataclass(frozen=True, slots=True)
class ResultLayout:
    """What every result of one solver under one set of options shares: names,
    tolerances, and where the parts of the core's output block lie."""

    dof_names: tuple[str, ...]
    effector_names: tuple[str, ...]
    tolerances: tuple[float, float]  # position [m], rotation [rad]
    n_dof: int
    n_effectors: int
    followers: Followers = Followers()  # the chain's mimic joints (values from q)

    @property
    def hessian_start(self) -> int:
        return 3 * self.n_effectors

    @property
    def log_start(self) -> int:
        return 3 * self.n_effectors + self.n_dof * self.n_dof


class IKResult(NamedTuple):
    """Answer to one frame (immutable).

    A NamedTuple of the few values every caller reads; the rest (errors per effector,
    the final H, the pass log) stay in the core's output block ``raw`` and are built on
    access. Building a frozen dataclass per frame cost ~8 us, and a 15-field tuple
    with converted arrays another ~5 us, of a ~40 us solve (bench/ik/).

    Attributes:
        q: Joint values, shape (n_dof,), in ``dof_names`` order, inside the limits.
        status: SOLVED / NOT_REACHED / BUDGET_EXHAUSTED / NONFINITE.
        termination: How the optimizer's last pass ended; ``GOAL_REACHED`` also when
            the polish after it met the goal (``polish``).
        iterations, function_evals, passes, restarts: Work done (iterations and
            evaluations include the polish's steps and objective calls, which the
            pass log, the optimizer's record, does not).
        solve_us: Time inside the compiled solve [us].
        raw: The core's output block (layout in ``ResultLayout`` / ``frame.solve_frame``).
        layout: Names and tolerances shared by this solver's results.

    Properties: success (status is SOLVED), dof_names, effector_names, tolerances,
    effectors (errors of the targeted effectors), raw_errors, inverse_hessian (final
    BFGS matrix, carried between frames if asked), pass_log (the analyzer's
    decisions, pass by pass), joint_values.
    """

    q: Vector
    status: IKStatus
    termination: Termination
    iterations: int
    function_evals: int
    passes: int
    restarts: int
    solve_us: float
    raw: np.ndarray
    layout: ResultLayout

    @property
    def success(self) -> bool:
        return self.status is IKStatus.SOLVED

    @property
    def dof_names(self) -> tuple[str, ...]:
        return self.layout.dof_names

    @property
    def effector_names(self) -> tuple[str, ...]:
        return self.layout.effector_names

    @property
    def tolerances(self) -> tuple[float, float]:
        return self.layout.tolerances

    @property
    def raw_errors(self) -> np.ndarray:
        """Rows of (position error, rotation error, targeted flag), one per effector."""
        m = self.layout.n_effectors
        return self.raw[: 3 * m].reshape(m, 3)

    @property
    def inverse_hessian(self) -> Matrix:
        n = self.layout.n_dof
        start = self.layout.hessian_start
        return self.raw[start : start + n * n].reshape(n, n)

    @property
    def raw_pass_log(self) -> np.ndarray:
        return self.raw[self.layout.log_start :].reshape(-1, C.N_LOG)

    @property
    def pass_log(self) -> tuple[PassRecord, ...]:
        return unpack_pass_log(self.raw_pass_log, self.passes)

    @property
    def effectors(self) -> tuple[EffectorError, ...]:
        tol_p, tol_r = self.layout.tolerances
        out = []
        for name, (pos, rot, targeted) in zip(
            self.layout.effector_names, self.raw_errors.tolist(), strict=True
        ):
            if not targeted:
                continue
            p = None if math.isnan(pos) else pos
            r = None if math.isnan(rot) else rot
            ok = (p is None or p <= tol_p) and (r is None or r <= tol_r)
            out.append(EffectorError(name, p, r, ok))
        return tuple(out)

    @property
    def joint_values(self) -> dict[str, float]:
        return dict(zip(self.layout.dof_names, self.q.tolist(), strict=True))

    @property
    def max_position_error_m(self) -> float:
        return max((e.position_error_m or 0.0 for e in self.effectors), default=0.0)

    @property
    def max_rotation_error_rad(self) -> float:
        return max((e.rotation_error_rad or 0.0 for e in self.effectors), default=0.0)
