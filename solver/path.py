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

_FLOAT_FIELDS = (
    "spacing_rad",
    "window_rad",
    "perturbation_rad",
    "max_work",
    "key_spacing_rad",
    "repair_ratio",
)
_INT_FIELDS = (
    "max_nodes_per_frame",
    "carried",
    "perturbed",
    "smoothing_sweeps",
    "seed",
    "key_every",
)


@dataclass(frozen=True)
class PathOptions:
    """How densely the planner looks (``bench/RESULTS.md`` has what the defaults give
    on the benchmark's streams, and what they cost)."""

    spacing_rad: float = 0.01  # between walked self-motion nodes (largest joint)
    window_rad: float = 0.25  # longer steps are ranked only where nothing shorter reaches
    # (nor longer than 3x the best path's largest step so far, at least 4 spacings)
    max_nodes_per_frame: int = 8192
    # Bounds a whole plan's time and memory: answers x DOF^3 (a 7-DOF answer costs
    # 343, so ~2.9 million of them; a 600-frame iiwa clip planned densely uses about
    # 1 million, with keyframes about 100,000). Each frame planned may use up to 4x its
    # even share of what is left (the keyframes' pass leaves a clip's worth of shares
    # for the repairs).
    max_work: float = 1e9
    carried: int = 16  # previous frame's nodes carried onto the next targets
    perturbed: int = 8  # random neighbours of carried nodes, per frame
    perturbation_rad: float = 0.08  # their spread (standard deviation per joint)
    smoothing_sweeps: int = 3
    # Keyframes (a clip of one kind of task throughout, at least 2 x key_every
    # frames): the programme first runs over every key_every-th frame, a self-motion
    # walked key_spacing_rad apart; the frames between are filled in,
    # and a stretch stepping more than repair_ratio x the keyframes' pace is planned
    # again densely. 1: every frame densely.
    key_every: int = 5
    key_spacing_rad: float = 0.05
    repair_ratio: float = 1.5
    seed: int = 0  # of the neighbours' generator: a plan is reproducible

    def __post_init__(self) -> None:
        # The compiled kernels get exactly one type per field (an int where a float is
        # expected would fail to compile mid-plan). A bool is a number to Python, but
        # never what a caller meant here.
        for name in _FLOAT_FIELDS + _INT_FIELDS:
            if isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be a number, not a bool")
        for name in _FLOAT_FIELDS:
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in _INT_FIELDS:
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
        if not (math.isfinite(self.key_spacing_rad) and self.key_spacing_rad > 0.0):
            raise ValueError("key_spacing_rad must be a positive number")
        if self.key_every < 1:
            raise ValueError("key_every must be at least 1")
        if not (math.isfinite(self.repair_ratio) and self.repair_ratio >= 1.0):
            raise ValueError("repair_ratio must be a finite number, at least 1")
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


def _steps(start: Vector, path: np.ndarray) -> np.ndarray:
    """Each frame's step: the largest change of any variable from the frame before."""
    steps: np.ndarray = np.abs(np.diff(np.vstack([start, path]), axis=0)).max(axis=1)
    return steps


def _anchors(
    nodes: np.ndarray,
    worst: np.ndarray,
    total: np.ndarray,
    must: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    rng: np.random.Generator,
    popts: PathOptions,
) -> np.ndarray:
    """Where a frame's nodes start from: the previous frame's cheapest node, ``must``
    (rows: the tracker's answer, and in a repair the path being repaired), the other
    cheapest nodes, a spread of the previous nodes, then random neighbours of some of
    these. Order matters: a node walked first claims its self-motion, and when the
    node budget runs out, what comes last is cut: the cheapest paths go first."""
    order = np.lexsort((total, worst))
    half = max(1, popts.carried // 2)
    best = [nodes[i] for i in order[:half]]
    # The spread covers the nodes a good path may still use: those reached with steps
    # not far above the best's (a self-motion reached only by a jump is dropped,
    # unless the tracker is on it).
    cheap = np.flatnonzero(worst <= max(3.0 * worst.min(), worst.min() + 4.0 * popts.spacing_rad))
    spread = [nodes[i] for i in cheap[np.linspace(0, len(cheap) - 1, half).astype(int)]]
    chosen = best[:1] + list(must) + best[1:] + spread
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


Box = tuple[np.ndarray, np.ndarray, np.ndarray]


class _Planner:
    """The state one plan shares between its passes: the frames, the tracker's
    answers, each frame's box, and the work spent against ``PathOptions.max_work``."""

    def __init__(
        self,
        solver: IKSolver,
        frames: Sequence[Sequence[Target]],
        opts: IKOptions,
        popts: PathOptions,
        tracked: list[IKResult],
        boxes: list[Box],
    ) -> None:
        self.solver = solver
        self.frames = frames
        self.opts = opts
        self.popts = popts
        self.tracked = tracked
        self.boxes = boxes
        self.rng = np.random.default_rng(popts.seed)
        self.considered = 0
        self.budget = popts.max_work / max(1, solver.chain.n_dof) ** 3  # answers, all frames

    def load(self, k: int, q0: np.ndarray) -> Box:
        """Load frame k's targets into the solver's data (for the kernels)."""
        self.solver._prepare(self.frames[k], self.opts, q0)
        return self.boxes[k]

    def nodes_at(
        self, k: int, anchors: np.ndarray, walk: bool, spacing: float, cap: int, frames_left: int
    ) -> np.ndarray:
        """Frame k's nodes from ``anchors`` (``frame_nodes``), the tracker's answer
        first when it is within tolerance; never empty (no answer found: the
        tracker's closest pose). Each call may use up to 4x its even share of the work
        left, shared over ``frames_left`` (the frames still to plan that count on it)."""
        tracked = self.tracked[k]
        box = self.load(k, tracked.q)
        fair = 4.0 * (self.budget - self.considered) / max(1, frames_left)
        limit = int(min(cap, max(len(anchors), fair)))
        nodes: np.ndarray = frame_nodes(anchors, self.solver._data, box, walk, spacing, limit)
        if tracked.success:  # the tracker's exact answer: the plan can always follow it
            nodes = np.vstack([tracked.q[None, :], nodes])
        elif len(nodes) == 0:
            nodes = tracked.q[None, :]
        self.considered += len(nodes)
        return nodes

    def dense(
        self,
        before: np.ndarray,
        ks: Sequence[int],
        *,
        spacing: float,
        cap: int,
        walk: Sequence[bool],
        along: np.ndarray | None = None,
        end: np.ndarray | None = None,
        span: int = 1,
        first_span: int = 1,
        reserve: int = 0,
    ) -> tuple[np.ndarray, float]:
        """The dynamic programme over frames ``ks`` from the single pose ``before``:
        the path (one row per frame) with the smallest largest step, and that step.
        ``along`` (rows per frame) joins each frame's anchors (a path being repaired);
        ``end`` fixes the last frame's pose (a repair joins the path there); ``walk``
        says, per frame, whether to walk the self-motion (one free direction). ``span``:
        frames between consecutive ks (keyframes), which scales the window;
        ``first_span``: frames the step from ``before`` to ks[0] counts for (the
        step is ranked as ``first_span`` times itself: a keyframe path starting on
        the clip's first frame ranks that one-frame step with its keyframe gaps);
        ``reserve``: frames planned later that the work budget keeps shares for."""
        popts = self.popts
        lower, upper = self.solver.chain.lower, self.solver.chain.upper
        prev = before[None, :]
        worst = np.zeros(1)
        total = np.zeros(1)
        sets: list[np.ndarray] = []
        backs: list[np.ndarray] = []
        after_gap = False  # the previous frame was one nothing reaches
        for i, k in enumerate(ks):
            if end is not None and i == len(ks) - 1:
                nodes = end[None, :]
            else:
                must = [self.tracked[k].q] if along is None else [along[i], self.tracked[k].q]
                anchors = _anchors(
                    prev, worst, total, np.array(must), lower, upper, self.rng, popts
                )
                left = len(ks) - i + reserve
                nodes = self.nodes_at(k, anchors, walk[i], spacing, cap, left)
            unreached = self._unreached(k, nodes)
            if unreached or after_gap:
                # A frame nothing reaches keeps the tracker's closest pose, and the
                # jumps into and out of it are the largest steps whatever else the
                # path does: counted, they would leave the rest of the path ranked
                # by its sum of squares alone. So the path is planned in segments
                # between such frames: the frame before one keeps the best path to
                # it, and the frames on either side start afresh.
                back = np.full(len(nodes), int(np.lexsort((total, worst))[0]))
                worst = np.zeros(len(nodes))
                total = np.zeros(len(nodes))
            else:
                # dp_step ranks steps longer than this only for nodes nothing shorter
                # reaches: 3x the best path's largest step so far (at least 4 spacings).
                window = popts.window_rad * span
                reach = min(window, max(3.0 * float(worst.min()), 4.0 * spacing))
                scale = float(first_span) if i == 0 else 1.0
                worst, total, back = dp_step(
                    prev * scale, worst, total, nodes * scale, float(reach) * scale
                )
            after_gap = unreached
            assert back.min() >= 0  # every node has a predecessor: there is at least one
            sets.append(nodes)
            backs.append(back)
            prev = nodes
        path = np.empty((len(ks), before.shape[0]))
        j = int(np.lexsort((total, worst))[0]) if len(ks) else 0
        best = float(worst[j]) if len(ks) else 0.0
        for i in range(len(ks) - 1, -1, -1):
            path[i] = sets[i][j]
            j = int(backs[i][j])
        return path, best

    def keyed(self, start: np.ndarray, walk: bool) -> np.ndarray:
        """The keyframe plan (``PathOptions.key_every``): a coarse dynamic programme
        over keyframes, the frames between filled in, and the stretches that step
        much more than the keyframes' pace re-planned densely. ``walk``: every
        frame's task has one free direction (else none has)."""
        popts = self.popts
        n = len(self.frames)
        per = max(2, n // popts.key_every)
        span = n / per  # frames per interval
        # The first frame is a keyframe too: the way from the start pose to the clip
        # (a jump, when the clip starts away from it) is then taken in one step, not
        # spread over the frames before the next keyframe. The programme ranks that
        # step as if it were a keyframe gap (span x itself), else a first frame far
        # along the self-motion would cost nothing beside the longer gaps.
        keys = [0] + [((i + 1) * n) // per - 1 for i in range(per)]
        count = len(keys)
        key_path, _ = self.dense(
            start,
            keys,
            spacing=popts.key_spacing_rad,
            cap=popts.max_nodes_per_frame,
            walk=[walk] * len(keys),
            span=round(span),
            first_span=round(span),
            reserve=n,  # the repairs' share
        )
        path = np.empty((n, start.shape[0]))
        self._fill(start, keys, key_path, path)
        # The keyframes' pace: a path through them moving evenly steps about this much
        # per frame. A stretch stepping well above it passed a keyframe badly
        # (interpolation cut a corner of the self-motion, e.g. near a singularity).
        # Measured between keyframes that are reached: a jump to a frame nothing
        # reaches says nothing of the pace elsewhere, nor does the way from the start
        # pose to the first keyframe (a clip may start away from the current pose),
        # nor a jump of the targets themselves (a cut in an animation). No such pair
        # of keyframes: no pace to judge by.
        bounds = [-1, *keys]
        reached = [self._solved_at(k, q) for k, q in zip(keys, key_path, strict=True)]
        gaps = _steps(start, key_path)
        cuts = _target_jumps(self.frames, 2 * round(span))
        both = [i for i in range(1, count) if reached[i] and reached[i - 1]]
        uncut = [i for i in both if not any(keys[i - 1] < k <= keys[i] for k in cuts)]
        paced = [gaps[i] for i in (uncut or both)]  # a cut in every interval: all count
        pace = max(popts.repair_ratio * max(paced, default=math.inf) / span, popts.spacing_rad)
        # Frames no longer judged. Those a dense plan has left unreached: nothing
        # reaches them (the tracker's restarts failed there too). And after the first
        # round, the steps where the targets jump: a repair has spread what it can of
        # the jump, the rest is the targets'. Retrying either widened every such
        # clip's repairs to a dense plan of the whole clip (measured: 2-4x the time
        # of the clip without that frame; a cut, up to 27x).
        given_up: set[int] = set()
        for widen in (1, 3, 9):
            bad = self._bad_intervals(
                start, path, bounds, pace, given_up if widen == 1 else given_up | cuts
            )
            if not bad:
                break
            windows = _windows(bad, widen, count)
            if 2 * sum(hi - lo + 1 for lo, hi in windows) > count:
                # Past half the clip, one dense plan of it all costs less than the
                # stretches, and sees everything they would.
                self._repair(start, path, -1, n - 1, walk)
                break
            for lo, hi in windows:
                self._repair(start, path, bounds[lo], bounds[hi + 1], walk)
                given_up.update(
                    k
                    for k in range(bounds[lo] + 1, bounds[hi + 1] + 1)
                    if not self._solved_at(k, path[k])
                )
        return path

    def _unreached(self, k: int, nodes: np.ndarray) -> bool:
        """Whether ``nodes`` of frame k are only the tracker's closest pose (no
        answer found)."""
        tracked = self.tracked[k]
        return len(nodes) == 1 and not tracked.success and np.array_equal(nodes[0], tracked.q)

    def _solved_at(self, k: int, q: np.ndarray) -> bool:
        """Whether pose q of frame k is within tolerance: every node is, but the
        tracker's answer kept where no answer was found."""
        return self.tracked[k].success or not np.array_equal(q, self.tracked[k].q)

    def _bad_intervals(
        self,
        start: np.ndarray,
        path: np.ndarray,
        bounds: list[int],
        pace: float,
        given_up: set[int],
    ) -> list[int]:
        """Keyframe intervals holding a frame left unreached, or a step above
        ``pace`` between two reached frames (the step from the start pose is whatever
        the first frame needs: not judged); frames in ``given_up`` are not judged."""
        steps = _steps(start, path)
        solved = [self._solved_at(k, path[k]) for k in range(len(path))]
        bad = []
        for i in range(len(bounds) - 1):
            frames = range(bounds[i] + 1, bounds[i + 1] + 1)
            if not all(solved[k] or k in given_up for k in frames) or any(
                steps[k] > pace
                for k in frames
                if k > 0 and solved[k] and solved[k - 1] and k not in given_up
            ):
                bad.append(i)
        return bad

    def _fill(
        self, start: np.ndarray, keys: list[int], key_path: np.ndarray, path: np.ndarray
    ) -> None:
        """Frames between keyframes: the straight line between the two keyframes'
        poses, projected onto each frame's targets; where that fails, the tracker's
        answer."""
        before, q_before = -1, start
        lower, upper = self.solver.chain.lower, self.solver.chain.upper
        for i, k in enumerate(keys):
            path[k] = key_path[i]
            for f in range(before + 1, k):
                a = (f - before) / (k - before)
                q = np.clip((1.0 - a) * q_before + a * key_path[i], lower, upper)
                box = self.load(f, q)
                if project_onto(q, self.solver._data, box, 30) > 1.0:
                    q = self.tracked[f].q.copy()
                path[f] = q
            self.considered += k - before - 1
            before, q_before = k, key_path[i]

    def _repair(
        self, start: np.ndarray, path: np.ndarray, first: int, last: int, walk: bool
    ) -> None:
        """Re-plan frames first+1..last densely, from path[first] (the start pose when
        first is -1), ending on path[last] unless last is the clip's last frame; kept
        where it reaches more frames, or as many with a smaller largest step (see
        ``_stretch_score``)."""
        n = len(self.frames)
        ks = list(range(first + 1, last + 1))
        before = start if first < 0 else path[first]
        end = None if last == n - 1 else path[last]
        popts = self.popts
        new, _ = self.dense(
            before,
            ks,
            spacing=popts.spacing_rad,
            cap=popts.max_nodes_per_frame,
            walk=[walk] * len(ks),
            along=path[first + 1 : last + 1],
            end=end,
        )
        old = path[first + 1 : last + 1]
        if self._stretch_score(before, first, new, path) < self._stretch_score(
            before, first, old, path
        ):
            path[first + 1 : last + 1] = new

    def _stretch_score(
        self, before: np.ndarray, first: int, rows: np.ndarray, path: np.ndarray
    ) -> tuple[int, float, float]:
        """How good ``rows`` are as frames first+1.. of ``path`` (smaller is better):
        the frames they leave unreached; the largest step between two reached frames
        (the stretch's joins included: a jump into or out of an unreached frame, or
        from the start pose, is there whichever way the stretch goes); then the
        largest step of all."""
        last = first + len(rows)
        seq = [before, *rows]
        ok = [first >= 0 and self._solved_at(first, before)]
        ok += [self._solved_at(first + 1 + i, q) for i, q in enumerate(rows)]
        if last + 1 < len(path):  # the join after the stretch
            seq.append(path[last + 1])
            ok.append(self._solved_at(last + 1, path[last + 1]))
        steps = np.abs(np.diff(np.array(seq), axis=0)).max(axis=1)
        between = [steps[i] for i in range(len(steps)) if ok[i] and ok[i + 1]]
        unreached = sum(not x for x in ok[1 : 1 + len(rows)])
        return unreached, max(between, default=0.0), float(steps.max(initial=0.0))


def _target_jumps(
    frames: Sequence[Sequence[Target]], half: int, factor: float = 4.0, floor: float = 1e-3
) -> set[int]:
    """Frames whose targets jump (a cut in an animation): the largest change of any
    target number (position [m], rotation matrix entry, direction) from the frame
    before is above ``factor`` x its median over the frames that move within ``half``
    frames on each side, plus ``floor``; or the targeted effectors or parts change."""
    n = len(frames)
    if n < 2:
        return set()
    motion = np.zeros(n)
    shape = [(t.effector, t.given) for t in frames[0]]
    if all([(t.effector, t.given) for t in f] == shape for f in frames):
        if shape:  # one task throughout: the numbers of all frames as one array
            rows = np.array([[t.packed for t in f] for f in frames])
            motion[1:] = np.nanmax(np.abs(np.diff(rows, axis=0)), axis=(1, 2))
    else:
        for k in range(1, n):
            before = {t.effector: t for t in frames[k - 1]}
            if set(before) != {t.effector for t in frames[k]}:
                motion[k] = math.inf
                continue
            for t in frames[k]:
                if before[t.effector].given != t.given:
                    motion[k] = math.inf
                    break
                change = np.abs(t.packed - before[t.effector].packed)
                motion[k] = max(motion[k], float(np.nanmax(change, initial=0.0)))
    # Typical: the median over the frames around each one that move at all (above
    # floor): a clip that holds still between moves (a gesture between holds, poses
    # held for several frames) moves in only some frames, and a median over all of
    # them would be 0, every move a jump. None moving around it: 0.
    window = np.lib.stride_tricks.sliding_window_view(
        np.pad(motion, half, constant_values=0.0), 2 * half + 1
    ).copy()
    window[:, half] = 0.0  # the frame itself
    window[window <= floor] = math.nan  # still frames, frame 0 and the padding
    window[np.isnan(window).all(axis=1)] = 0.0
    typical = np.nanmedian(window, axis=1)
    return {k for k in range(1, n) if motion[k] > factor * typical[k] + floor}


def _windows(bad: list[int], widen: int, count: int) -> list[tuple[int, int]]:
    """Intervals ``bad`` widened by ``widen`` on each side, overlapping ones merged:
    (first, last) interval indices."""
    out: list[tuple[int, int]] = []
    for i in bad:
        lo, hi = max(0, i - widen), min(count - 1, i + widen)
        if out and lo <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


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
        boxes.append((lower, upper, solver._free_mask()))
        walks.append(solver._free_directions() == 1)
    planner = _Planner(solver, frames, opts, popts, tracked, boxes)
    if popts.key_every > 1 and n >= 2 * popts.key_every and len(set(walks)) == 1:
        path = planner.keyed(start, walks[0])
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
    solved = [planner._solved_at(k, path[k]) for k in range(n)]
    _smooth(solver, frames, opts, start, path, solved, boxes, popts.smoothing_sweeps)
    tracked_path = np.array([r.q for r in tracked]).reshape(path.shape)
    tracked_step = _largest_step(start, tracked_path)
    if all(r.success for r in tracked) and tracked_step <= _largest_step(start, path):
        path = tracked_path  # a safety net: never do worse than tracking
    plan_us = (time.perf_counter() - started) * 1e6
    share = plan_us / max(1, n)
    results = tuple(
        tracked[k]
        if np.array_equal(path[k], tracked[k].q)
        else solver._judge(path[k].copy(), frames[k], opts, share)
        for k in range(n)
    )
    solver._h = None  # the tracker's carried BFGS matrix is not the plan's
    solver.q = results[-1].q.copy() if results else start
    largest = _largest_step(start, path)
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
            solver._prepare(frames[k], opts, path[k])
            if project_onto(q, solver._data, boxes[k], 30) > 1.0:
                continue
            if max(np.abs(q - before).max(), np.abs(after - q).max()) > local:
                continue
            moved = max(moved, float(np.abs(q - path[k]).max()))
            path[k] = q
        if moved < 1e-7:
            break
