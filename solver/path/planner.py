"""Planning a clip of frames as a whole: the joint path with the smallest largest step.

Why. ``IKSolver.track`` answers each frame from the previous answer, knowing only the
past. A redundant arm (a 7-DOF arm under a 6-D pose) can reach each target along a
one-dimensional self-motion, and which point of it the tracker holds drifts from frame
to frame. Where the targets carry the arm through a singularity (the iiwa's shoulder:
joint 2 through 0), a path that crosses it exactly, or passes far from it, moves
smoothly; a tracker that passes *near* it must turn two joints by about pi within a few
frames, or jump (``bench/RESULTS.md``, "iiwa tracking"). Which side to take is decided
seconds before any sign of the singularity shows in the targets, so no causal rule
holds it; with the clip known, a plan does.

How. For every frame the planner gathers answers ("nodes"):
- the tracker's own answer (``track`` with the same options), so the plan is never
  worse than tracking (below);
- the previous frame's cheapest and a spread of its other nodes, carried onto this
  frame's targets by minimum-norm Gauss-Newton, plus random neighbours of some (they
  find the other branch where two meet, e.g. an arm passing through straight);
- for a task with exactly one free direction, the whole self-motion through each of
  them, walked ``spacing_rad`` apart (largest joint) up to the limits.
A dynamic programme over frames x nodes then picks, from the current pose, the path
whose largest step (largest change of any joint between consecutive frames, the first
frame's measured from the current pose) is smallest, ties broken (per node, a
heuristic) by the smallest sum of squared steps; a few sweeps of smoothing (each frame
moved towards the middle of its neighbours and put back on its targets, kept only where
the larger of its two steps does not grow) take out the sampling's jitter. Every node
is judged by the solver's own error measure: a frame counts as solved exactly when
``solve`` would say so.

Keyframes. Gathering nodes for every frame is what costs (a walked self-motion is
hundreds per frame). For a clip of at least two keyframes whose frames all walk, or
all do not (the same kind of task throughout), the programme first runs over keyframes
only (the first frame and every ``key_every``-th frame, a self-motion walked
``key_spacing_rad`` apart),
and the frames between are filled in: the straight line
between the two keyframes' poses, projected onto each frame's targets. Where the line
cuts a corner of the self-motion (near a singularity, where joints turn fast), the
filled frames step well above the keyframes' pace (``repair_ratio`` x the keyframe
path's largest step per frame between keyframes that are reached, leaving out the
gaps where the targets jump, at least ``spacing_rad``; the step from the start pose
is not judged: a clip may start away from the current pose; nor, after a first
repair, a step where the targets jump: a cut in an animation), or hold a frame left
unreached; those stretches, widened by
one keyframe on each side, are planned again frame by frame as above, from the path's
pose before them onto its pose after them (left free at the clip's end), and kept
where they reach more frames, or as many with a smaller largest step (steps into and
out of an unreached frame, and from the start pose, apart; then all); what is still
bad is tried again over 3, then 9 keyframes on each side (but a frame a dense plan left
unreached: nothing reaches it), and once the stretches would cover more than half the
clip, the whole clip is planned densely instead. On the benchmark's
streams this is about 10x cheaper than planning every frame densely, and holds the
same streams within 2x of the reference's step; a 6-DOF arm's (no walk), about 2x
(``bench/RESULTS.md``, "Planned clips").

Guarantees, by construction: every frame the tracker solves is solved by the plan, and
when the tracker solves every frame the plan's largest step is at most the tracker's.
Frames where no answer is found keep the tracker's answer (its closest pose); the jumps
into and out of them are not ranked (they would be the largest steps whatever the rest
of the path did), so the path between such frames is planned as a clip of its own.

Cost: about frames x nodes x a few Gauss-Newton steps; nodes grow with the
self-motion's length over the spacing (a 7-DOF arm: hundreds to a few thousand per
walked frame), and memory with frames x nodes x joints. ``PathOptions.max_work`` bounds
the answers gathered beyond each frame's anchors (which every frame planned keeps:
about carried + perturbed + 2); with keyframes, the frames planned are the keyframes,
the filled-in frames and the repaired stretches (the latter at most about twice the
clip: past half the clip, one dense plan of the whole clip replaces the stretches).
``bench/ik/`` part (c) measures it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ..ik import Continuity, IKOptions, IKResult, IKSolver, StreamState, Target
from .kernels import project_onto
from .keyframes import plan_keyed
from .options import PathOptions, PlannedPath
from .programme import Box, Planner, largest_step


def plan_path(
    solver: IKSolver,
    frames: Sequence[Sequence[Target]],
    *,
    options: IKOptions | None = None,
    path_options: PathOptions | None = None,
) -> PlannedPath:
    """Plan ``frames`` from ``solver.q`` (see the module docstring); ``solver.q``
    becomes the last frame's answer. Every frame's targets are checked first (the
    errors of ``solve``: InvalidProblem); a rejected clip leaves the solver's pose and
    carried state as they were. ``options`` (default: the solver's) give the
    tolerances, and the tracker's settings."""
    opts = options or solver.options
    if opts.continuity is not Continuity.REACH:
        # The plan chooses among every frame's answers for the smallest largest step;
        # its tracker must answer every frame it can (a SMOOTH tracker would not).
        opts = replace(opts, continuity=Continuity.REACH)
    popts = path_options or PathOptions()
    start = solver.check_seed(solver.q).copy()
    carried = solver.stream_state()
    for targets in frames:  # reject a bad frame before any work
        solver.judge(start, targets, options=opts)
    try:
        if solver.chain.n_dof == 0:  # nothing moves: the frames' errors are the answers
            results = tuple(solver.track(t, options=opts) for t in frames)
            return PlannedPath(results, 0.0, 0.0, len(results), 0.0)
        return _plan(solver, frames, opts, popts, start)
    except BaseException:
        solver.restore(carried._replace(q=start))
        raise


def _plan(
    solver: IKSolver,
    frames: Sequence[Sequence[Target]],
    opts: IKOptions,
    popts: PathOptions,
    start: np.ndarray,
) -> PlannedPath:
    started = time.perf_counter()
    n = len(frames)
    tracked: list[IKResult] = []
    boxes: list[Box] = []
    walks: list[bool] = []
    q_track = start
    lower, upper = solver.chain.lower, solver.chain.upper
    for targets in frames:
        solver.q = q_track
        r = solver.track(targets, options=opts)  # also loads the targets
        q_track = r.q.copy()
        tracked.append(r)
        # Variables outside every targeted chain keep each node's own value (the
        # tracker freezes them at its previous answer; a node carries its own).
        boxes.append((lower, upper, solver.free_mask()))
        walks.append(solver.free_directions() == 1)
    tracked_state = solver.stream_state()  # the stream's anchoring, frame by frame
    planner = Planner(solver, frames, opts, popts, tracked, boxes)
    if popts.key_every > 1 and n >= 2 * popts.key_every and len(set(walks)) == 1:
        path = plan_keyed(planner, start, walks[0])
    else:
        path, _ = planner.dense(
            start,
            range(n),
            spacing=popts.spacing_rad,
            cap=popts.max_nodes_per_frame,
            walk=walks,
        )
        path = path.reshape(n, solver.chain.n_dof)
    # A node is within tolerance unless it is the tracker's answer kept for a frame
    # where no answer was found.
    solved = [planner.solved_at(k, path[k]) for k in range(n)]
    _smooth(solver, frames, opts, start, path, solved, boxes, popts.smoothing_sweeps)
    tracked_path = np.array([r.q for r in tracked]).reshape(path.shape)
    tracked_step = largest_step(start, tracked_path)
    if all(r.success for r in tracked) and tracked_step <= largest_step(start, path):
        path = tracked_path  # a safety net: never do worse than tracking
    plan_us = (time.perf_counter() - started) * 1e6
    share = plan_us / max(1, n)
    results = tuple(
        tracked[k]
        if np.array_equal(path[k], tracked[k].q)
        else solver.judge(path[k].copy(), frames[k], options=opts, solve_us=share)
        for k in range(n)
    )
    # The tracker's carried BFGS matrix is not the plan's. The stream is anchored as its
    # frames tracked one by one left it (IKSolver.track), or by a frame the plan solved.
    anchored = tracked_state.anchored or any(r.success for r in results)
    misses = 0 if anchored else tracked_state.misses
    q_end = results[-1].q.copy() if results else start
    solver.restore(StreamState(q_end, None, anchored, misses))
    largest = largest_step(start, path)
    return PlannedPath(results, largest, tracked_step, planner.considered, plan_us)


def _smooth(
    solver: IKSolver,
    frames: Sequence[Sequence[Target]],
    opts: IKOptions,
    start: np.ndarray,
    path: np.ndarray,
    solved: list[bool],
    boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    sweeps: int,
) -> None:
    """Gauss-Seidel sweeps over the path (in place): each solved frame but the last,
    between two solved ones, moves towards the middle of its neighbours and back onto
    its targets; kept only
    if it stays within tolerance and the larger of its two steps does not grow (so
    the path's largest step never grows; one of the two may)."""
    last = len(frames) - 1
    for _ in range(sweeps):
        moved = 0.0
        for k in range(last):
            # Next to a frame nothing reaches, the midpoint would pull the frame
            # towards that frame's closest pose, off its own segment.
            if not (solved[k] and solved[k + 1] and (k == 0 or solved[k - 1])):
                continue
            before = start if k == 0 else path[k - 1]
            after = path[k + 1]
            local = max(np.abs(path[k] - before).max(), np.abs(after - path[k]).max())
            q = np.clip(0.5 * (before + after), solver.chain.lower, solver.chain.upper)
            data = solver.load_frame(frames[k], path[k], options=opts)
            if project_onto(q, data, boxes[k], 30) > 1.0:
                continue
            if max(np.abs(q - before).max(), np.abs(after - q).max()) > local:
                continue
            moved = max(moved, float(np.abs(q - path[k]).max()))
            path[k] = q
        if moved < 1e-7:
            break
