"""Solver options: the server's defaults, a request's patch on them, and their JSON view."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any, Final

import schemas as S
from solver.errors import IKError
from solver.ik import STREAM_DEFAULTS, IKOptions

from ..config import Settings
from ..errors import invalid_problem


def _with_server_defaults(base: IKOptions, settings: Settings) -> IKOptions:
    """``base`` with the tolerances, budget and limits the server is configured with
    (``base``'s own restart count unless IK_DEFAULT_MAX_RESTARTS is set)."""
    restarts = settings.default_max_restarts
    return replace(
        base,
        time_budget_us=settings.default_time_budget_us,
        position_tolerance_m=settings.default_position_tolerance_m,
        rotation_tolerance_rad=settings.default_rotation_tolerance_rad,
        max_iter=settings.default_max_iter,
        max_restarts=base.max_restarts if restarts is None else restarts,
    )


# A character's limbs turn faster than a robot arm's joints: walk.bvh played at 2x steps
# up to 0.27 rad per 60 Hz frame, where smooth's 0.1 rad left the limbs lagging the
# targets, up to 5 cm, on 1.3-1.4% of frames with every bone moving; at 0.3 no frame
# missed at the step limit, and no joint or bone turned more than 0.31 rad in a frame
# (bench.character_tracking, bench/RESULTS.md). Far below the pops it stops (radians).
SKELETON_MAX_JOINT_STEP_RAD: Final = 0.3


def session_defaults(settings: Settings, *, skeleton: bool = False) -> IKOptions:
    """Stream defaults (local restarts, light limit pull) with the server's settings;
    ``skeleton``: a game character's (glTF, BVH), whose smooth step limit is larger."""
    base = _with_server_defaults(STREAM_DEFAULTS, settings)
    return replace(base, max_joint_step_rad=SKELETON_MAX_JOINT_STEP_RAD) if skeleton else base


def oneshot_defaults(settings: Settings) -> IKOptions:
    """One-shot defaults (restarts anywhere in the limits) with the server's settings."""
    return _with_server_defaults(IKOptions(), settings)


def apply_options(
    patch: S.OptionsPatch | None, base: IKOptions, settings: Settings, *, field: str = "options"
) -> IKOptions:
    """``base`` with the fields ``patch`` sets, validated by the solver and the server caps.
    ``field``: where the options sit in the request ("" for a request that is them).

    Raises:
        ServiceError: ``invalid_problem`` naming ``<field>.time_budget_us`` (over
            IK_MAX_TIME_BUDGET_US) or ``<field>`` (a value the solver refuses; the
            request's ``body`` when it is the options).
    """
    if patch is None:
        return base
    changes = patch.model_dump(exclude_none=True)
    budget = changes.get("time_budget_us")
    if budget is not None and budget > settings.max_time_budget_us:
        raise invalid_problem(
            f"time_budget_us must be at most {settings.max_time_budget_us:g} "
            "(IK_MAX_TIME_BUDGET_US)",
            f"{field}.time_budget_us" if field else "time_budget_us",
        )
    try:
        return replace(base, **changes)
    except IKError as e:
        raise invalid_problem(str(e), field or "body") from None


# The options a client sees (schema ``SolverOptions``), each an ``IKOptions`` field of
# the same name.
_OPTION_NAMES: Final = tuple(S.SolverOptions.model_fields)


def options_dict(o: IKOptions) -> dict[str, Any]:
    """The SolverOptions view of IKOptions (JSON-ready)."""
    out = {name: getattr(o, name) for name in _OPTION_NAMES}
    if not math.isfinite(o.restart_radius_rad):  # JSON has no infinity: the schema's cap
        out["restart_radius_rad"] = 1e9
    out["continuity"] = o.continuity.value
    return out
