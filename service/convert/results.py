"""Solved frames -> the JSON/MessagePack-ready answers (``FrameResult``,
``CompactFrameResult``, ``PlanSummary``).

Rendering runs in the route layer, on the event loop, after the solve: the solving
layer (``service/solving.py``) returns typed ``SolvedFrame``s and never builds JSON.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any, NamedTuple

import numpy as np

import schemas as S
from solver.ik import FrameStep, IKResult, IKStatus
from solver.optim import Termination
from solver.path import PlannedPath

# Each status and termination code's string, looked up by the member (a StrEnum hashes
# as its string): ``member.value`` is a Python-level property, ~6x the lookup's time,
# and a frame's answer reads two of them.
_VALUES: dict[str, str] = {m: m.value for m in (*IKStatus, *Termination)}
_SOLVED = IKStatus.SOLVED  # IKResult.success, without the property's call


class SolvedFrame(NamedTuple):
    """One frame's outcome, as the solving layer hands it to the renderer."""

    frame_id: int | None  # the client's id, echoed (None if it sent none)
    result: IKResult
    server_us: float  # request or message received -> this frame solved [us]
    step: FrameStep | None = None  # from the session's previous answer (None: one-shot)


# Renders one solved frame (result, frame id, server_us, step) as the answer a view asks for.
ResultBuilder = Callable[[IKResult, int | None, float, FrameStep | None], dict[str, Any]]


def result_dict(
    r: IKResult, frame_id: int | None, server_us: float, step: FrameStep | None = None
) -> dict[str, Any]:
    """A FrameResult as a JSON/MessagePack-ready dict (the hot path: no re-validation;
    tests check the shape against ``schemas.FrameResult``).

    The per-effector errors are read from the result's raw rows (position error or NaN,
    rotation error or NaN, targeted flag) with the names and tolerances the solver's
    ``layout`` holds once per session and options, not through ``IKResult.effectors``,
    which builds an object per effector first (the same values; tests compare them).
    """
    # One unpacking instead of an attribute read per field (this is per frame).
    q, status, termination, nit, nfev, npass, nrest, solve_us, raw, layout = r
    values = q.tolist()
    tol_p, tol_r = layout.tolerances
    isnan = math.isnan
    effectors = []
    names = layout.effector_names
    # raw starts with (position error, rotation error, targeted flag) per effector
    # (``IKResult.raw_errors``), read here as one flat list.
    errors = raw[: 3 * len(names)].tolist()
    for k, name in enumerate(names):
        pos, rot, targeted = errors[3 * k : 3 * k + 3]
        if not targeted:
            continue
        p = None if isnan(pos) else pos
        e = None if isnan(rot) else rot
        effectors.append(
            {
                "name": name,
                "position_error_m": p,
                "rotation_error_rad": e,
                "within_tolerance": (p is None or p <= tol_p) and (e is None or e <= tol_r),
            }
        )
    # zip without a keyword: the layout and q come from the same solver, so their lengths
    # agree, and any keyword (strict=True or False alike) took zip's slower call, ~0.3 us
    # of a panda answer's ~2 (timeit, interleaved).
    joints = dict(zip(layout.dof_names, values))  # noqa: B905
    followers = layout.followers
    if followers.names:  # mimic joints: by name only, not in q
        joints.update(zip(followers.names, followers.values(q).tolist(), strict=True))
    return {
        "id": frame_id,
        "success": status is _SOLVED,
        "status": _VALUES[status],
        "termination": _VALUES[termination],
        "joints": joints,
        "q": values,
        "effectors": effectors,
        "iterations": nit,
        "function_evals": nfev,
        "passes": npass,
        "restarts": nrest,
        "solve_us": solve_us,
        "server_us": server_us,
        "largest_step_rad": None if step is None else step.largest_rad,
        "jumped": False if step is None else step.jumped,
    }


def plan_steps(start: np.ndarray, poses: Sequence[np.ndarray], limit: float) -> list[FrameStep]:
    """Each planned frame's step from the frame before (the first: from ``start``, the
    pose before the clip), a jump when over ``limit`` (as ``IKSolver.track`` reports)."""
    steps = []
    before = start
    for q in poses:
        largest = float(np.abs(q - before).max()) if q.size else 0.0
        steps.append(FrameStep(largest, largest > limit + 1e-9))
        before = q
    return steps


def plan_summary(plan: PlannedPath) -> dict[str, Any]:
    """A PlanSummary's fields."""
    return {
        "largest_step_rad": plan.largest_step,
        "tracked_largest_step_rad": plan.tracked_largest_step,
        "candidates": plan.nodes,
        "plan_us": plan.plan_us,
    }


def compact_result_dict(
    r: IKResult, frame_id: int | None, server_us: float, step: FrameStep | None = None
) -> dict[str, Any]:
    """A CompactFrameResult (``?results=compact``): no ``joints`` by name and no
    per-effector errors, which a stream reading ``q`` does not need. About a third of
    a panda answer's bytes and less work to build and encode; tests check the shape
    against ``schemas.CompactFrameResult``.

    Its fields after ``q`` are ``result_dict``'s, written out in both: a helper
    building them once costs an extra dict and its unpacking per frame (compact
    rendering 1.04 -> 1.36 us, full 3.46 -> 3.83 us, CPU time, paired in one run)."""
    return {
        "id": frame_id,
        "success": r.success,
        "status": _VALUES[r.status],
        "termination": _VALUES[r.termination],
        "q": r.q.tolist(),
        "iterations": r.iterations,
        "function_evals": r.function_evals,
        "passes": r.passes,
        "restarts": r.restarts,
        "solve_us": r.solve_us,
        "server_us": server_us,
        "largest_step_rad": None if step is None else step.largest_rad,
        "jumped": False if step is None else step.jumped,
    }


_RESULT_BUILDERS: dict[S.ResultView, ResultBuilder] = {
    S.ResultView.FULL: result_dict,
    S.ResultView.COMPACT: compact_result_dict,
}


def result_builder(view: S.ResultView) -> ResultBuilder:
    """What turns an IKResult into the answer ``view`` asks for."""
    return _RESULT_BUILDERS[view]


def render_frames(frames: Iterable[SolvedFrame], build: ResultBuilder) -> list[dict[str, Any]]:
    """The answers of solved frames, in order, as ``build`` renders them."""
    return [build(f.result, f.frame_id, f.server_us, f.step) for f in frames]
