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

Guarantees, by construction: every frame the tracker solves is solved by the plan, and
when the tracker solves every frame the plan's largest step is at most the tracker's.
Frames that no node reaches keep the tracker's answer (its closest pose).

Cost: about frames x nodes x a few Gauss-Newton steps; nodes grow with the
self-motion's length over ``spacing_rad`` (a 7-DOF arm: hundreds to a few thousand per
frame), and memory with frames x nodes x joints; ``PathOptions.max_work`` bounds both.
``bench/ik.py`` part (c) measures it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ._path_kernels import dp_step, frame_nodes, project_onto
from .ik import IKOptions, IKResult, IKSolver, Target
from .types import Vector


@dataclass(frozen=True)
class PathOptions:
    """How densely the planner looks (``bench/RESULTS.md`` has what the defaults give
    on the benchmark's streams, and what they cost)."""

    spacing_rad: float = 0.01  # between walked self-motion nodes (largest joint)
    window_rad: float = 0.25  # longer steps are ranked only where nothing shorter reaches
    # (nor longer than 3x the best path's largest step so far, at least 4 spacings)
    max_nodes_per_frame: int = 8192
    # Bounds a whole plan's time and memory: answers x DOF^3 (a 7-DOF answer costs
    # 343, so ~2.9 million of them; a 600-frame iiwa clip uses about 1 million). Each
    # frame may use up to 4x its even share of what is left.
    max_work: float = 1e9
    carried: int = 16  # previous frame's nodes carried onto the next targets
    perturbed: int = 8  # random neighbours of carried nodes, per frame
    perturbation_rad: float = 0.08  # their spread (standard deviation per joint)
    smoothing_sweeps: int = 20
    seed: int = 0  # of the neighbours' generator: a plan is reproducible

    def __post_init__(self) -> None:
        # The compiled kernels get exactly one type per field (an int where a float is
        # expected would fail to compile mid-plan).
        for name in ("spacing_rad", "window_rad", "perturbation_rad", "max_work"):
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("max_nodes_per_frame", "carried", "perturbed", "smoothing_sweeps", "seed"):
            value = getattr(self, name)
            if isinstance(value, float) and not value.is_integer():
                raise ValueError(f"{name} must be an integer")
            object.__setattr__(self, name, int(value))
        if not (math.isfinite(self.spacing_rad) and self.spacing_rad > 0.0):
            raise ValueError("spacing_rad must be a positive number")
        if not self.window_rad > 0.0:
            raise ValueError("window_rad must be positive")
        if self.max_nodes_per_frame < 1 or self.carried < 1:
            raise ValueError("max_nodes_per_frame and carried must be at least 1")
        if not self.max_work > 0.0:
            raise ValueError("max_work must be positive")
        if self.perturbed < 0 or self.smoothing_sweeps < 0:
            raise ValueError("perturbed and smoothing_sweeps must be >= 0")
        if not (math.isfinite(self.perturbation_rad) and self.perturbation_rad >= 0.0):
            raise ValueError("perturbation_rad must be a non-negative number")


@dataclass(frozen=True)
class PlannedPath:
    """A planned clip: one result per frame, in order.

    A frame whose planned answer is the tracker's carries the tracker's result (its
    iterations and solve time); any other frame's result judges the planned pose as
    it is (no iterations), with ``solve_us`` the plan's time shared over the frames.
    """

    results: tuple[IKResult, ...]
    largest_step: float  # of the plan, the first frame's from the start pose included
    tracked_largest_step: float  # of the tracker on the same frames (what ``track`` gives)
    nodes: int  # answers considered, over all frames
    plan_us: float  # wall time of the whole plan

    @property
    def q(self) -> np.ndarray:
        """Joint values, frames x DOF."""
        return np.array([r.q for r in self.results])

    @property
    def success(self) -> bool:
        """Every frame within tolerance."""
        return all(r.success for r in self.results)


def _largest_step(start: Vector, path: np.ndarray) -> float:
    return float(np.abs(np.diff(np.vstack([start, path]), axis=0)).max()) if len(path) else 0.0


def _anchors(
    nodes: np.ndarray,
    worst: np.ndarray,
    total: np.ndarray,
    tracked: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    rng: np.random.Generator,
    popts: PathOptions,
) -> np.ndarray:
    """Where this frame's nodes start from: the previous frame's cheapest nodes, the
    tracker's answer, a spread of the previous nodes, then random neighbours of some
    of these. Order matters: a node walked first claims its self-motion, and when the
    node budget runs out, what comes last is cut: the cheapest paths go first."""
    order = np.lexsort((total, worst))
    half = max(1, popts.carried // 2)
    best = [nodes[i] for i in order[:half]]
    # The spread covers the nodes a good path may still use: those reached with steps
    # not far above the best's (a self-motion reached only by a jump is dropped,
    # unless the tracker is on it).
    cheap = np.flatnonzero(worst <= max(3.0 * worst.min(), worst.min() + 4.0 * popts.spacing_rad))
    spread = [nodes[i] for i in cheap[np.linspace(0, len(cheap) - 1, half).astype(int)]]
    chosen = best[:1] + [tracked] + best[1:] + spread
    if popts.perturbed:
        around = rng.choice(len(chosen), size=popts.perturbed)
        noise = rng.normal(0.0, popts.perturbation_rad, (popts.perturbed, nodes.shape[1]))
        chosen += list(np.clip(np.array(chosen)[around] + noise, lower, upper))
    return np.ascontiguousarray(chosen, dtype=np.float64)


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
    popts = path_options or PathOptions()
    start = solver._check_seed(solver.q).copy()
    carried_h = solver._h
    for targets in frames:  # reject a bad frame before any work
        solver._judge(start, targets, opts, 0.0)
    try:
        if solver.chain.n_dof == 0:  # nothing moves: the frames' errors are the answers
            results = tuple(solver.track(t, options=opts) for t in frames)
            return PlannedPath(results, 0.0, 0.0, len(results), 0.0)
        return _plan(solver, frames, opts, popts, start)
    except BaseException:
        solver.q = start
        solver._h = carried_h
        raise


def _plan(
    solver: IKSolver,
    frames: Sequence[Sequence[Target]],
    opts: IKOptions,
    popts: PathOptions,
    start: np.ndarray,
) -> PlannedPath:
    started = time.perf_counter()
    lower = solver.chain.lower
    upper = solver.chain.upper
    rng = np.random.default_rng(popts.seed)
    data = solver._data
    tracked: list[IKResult] = []
    node_sets: list[np.ndarray] = []
    backs: list[np.ndarray] = []
    boxes: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    prev_nodes = start[None, :]
    worst = np.zeros(1)
    total = np.zeros(1)
    q_track = start
    considered = 0
    budget = popts.max_work / max(1, solver.chain.n_dof) ** 3  # answers, all frames
    for k, targets in enumerate(frames):
        solver.q = q_track
        r = solver.track(targets, options=opts)  # also loads the targets
        q_track = r.q.copy()
        tracked.append(r)
        # Variables outside every targeted chain keep each node's own value (the
        # tracker freezes them at its previous answer; a node carries its own).
        box = (lower, upper, solver._free_mask())
        boxes.append(box)
        anchors = _anchors(prev_nodes, worst, total, q_track, lower, upper, rng, popts)
        walk = solver._free_directions() == 1
        fair = 4.0 * (budget - considered) / (len(frames) - k)
        limit = int(min(popts.max_nodes_per_frame, max(len(anchors), fair)))
        nodes = frame_nodes(anchors, data, box, walk, popts.spacing_rad, limit)
        if r.success:  # the tracker's exact answer: the plan can always follow it
            nodes = np.vstack([q_track[None, :], nodes])
        elif len(nodes) == 0:  # nothing reaches this frame: keep the closest pose
            nodes = q_track[None, :]
        considered += len(nodes)
        # dp_step ranks steps longer than this only for nodes nothing shorter reaches:
        # 3x the best path's largest step so far (at least 4 spacings).
        reach = min(popts.window_rad, max(3.0 * float(worst.min()), 4.0 * popts.spacing_rad))
        worst, total, back = dp_step(prev_nodes, worst, total, nodes, float(reach))
        assert back.min() >= 0  # every node has a predecessor: there is at least one
        node_sets.append(nodes)
        backs.append(back)
        prev_nodes = nodes
    path = np.empty((len(frames), solver.chain.n_dof))
    j = int(np.lexsort((total, worst))[0]) if len(frames) else 0
    for k in range(len(frames) - 1, -1, -1):
        path[k] = node_sets[k][j]
        j = int(backs[k][j])
    # A node is within tolerance unless it is the tracker's answer kept for a frame
    # nothing reaches.
    solved = [
        tracked[k].success or not np.array_equal(path[k], tracked[k].q) for k in range(len(frames))
    ]
    _smooth(solver, frames, opts, start, path, solved, boxes, popts.smoothing_sweeps)
    tracked_path = np.array([r.q for r in tracked]).reshape(path.shape)
    tracked_step = _largest_step(start, tracked_path)
    if all(r.success for r in tracked) and tracked_step <= _largest_step(start, path):
        path = tracked_path  # a safety net: never do worse than tracking
    plan_us = (time.perf_counter() - started) * 1e6
    share = plan_us / max(1, len(frames))
    results = tuple(
        tracked[k]
        if np.array_equal(path[k], tracked[k].q)
        else solver._judge(path[k].copy(), frames[k], opts, share)
        for k in range(len(frames))
    )
    solver._h = None  # the tracker's carried BFGS matrix is not the plan's
    solver.q = results[-1].q.copy() if results else start
    return PlannedPath(results, _largest_step(start, path), tracked_step, considered, plan_us)


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
    """Gauss-Seidel sweeps over the path (in place): each solved frame but the last
    moves towards the middle of its neighbours and back onto its targets; kept only
    if it stays within tolerance and the larger of its two steps does not grow (so
    the path's largest step never grows; one of the two may)."""
    last = len(frames) - 1
    for _ in range(sweeps):
        moved = 0.0
        for k in range(last):
            if not solved[k]:
                continue
            before = start if k == 0 else path[k - 1]
            after = path[k + 1]
            local = max(np.abs(path[k] - before).max(), np.abs(after - path[k]).max())
            q = np.clip(0.5 * (before + after), solver.chain.lower, solver.chain.upper)
            solver._prepare(frames[k], opts, path[k])
            if project_onto(q, solver._data, boxes[k], 30) > 1.0:
                continue
            if max(np.abs(q - before).max(), np.abs(after - q).max()) > local:
                continue
            moved = max(moved, float(np.abs(q - path[k]).max()))
            path[k] = q
        if moved < 1e-7:
            break
