"""The dynamic programme over frames x nodes that picks a clip's path, and the state
one plan shares between its passes (``Planner``).

For every frame the planner gathers answers ("nodes", ``kernels.frame_nodes``) from
anchors (``anchors``); ``Planner.dense`` then ranks paths through them, frame by frame
(``kernels.dp_step``), by their largest step, ties broken by the sum of squared steps.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..arrays import Vector
from ..ik import IKData, IKOptions, IKResult, IKSolver, Target
from .kernels import dp_step, frame_nodes
from .options import PathOptions


def largest_step(start: Vector, path: np.ndarray) -> float:
    return float(np.abs(np.diff(np.vstack([start, path]), axis=0)).max()) if len(path) else 0.0


def frame_steps(start: Vector, path: np.ndarray) -> np.ndarray:
    """Each frame's step: the largest change of any variable from the frame before."""
    steps: np.ndarray = np.abs(np.diff(np.vstack([start, path]), axis=0)).max(axis=1)
    return steps


def gather_anchors(
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


Box = tuple[np.ndarray, np.ndarray, np.ndarray]


class Planner:
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

    def load(self, k: int, q0: np.ndarray) -> tuple[IKData, Box]:
        """Load frame k's targets into the solver's data (for the kernels), as a solve
        from q0 would; the data and the frame's box."""
        return self.solver.load_frame(self.frames[k], q0, options=self.opts), self.boxes[k]

    def nodes_at(
        self, k: int, anchors: np.ndarray, walk: bool, spacing: float, cap: int, frames_left: int
    ) -> np.ndarray:
        """Frame k's nodes from ``anchors`` (``frame_nodes``), the tracker's answer
        first when it is within tolerance; never empty (no answer found: the
        tracker's closest pose). Each call may use up to 4x its even share of the work
        left, shared over ``frames_left`` (the frames still to plan that count on it)."""
        tracked = self.tracked[k]
        data, box = self.load(k, tracked.q)
        fair = 4.0 * (self.budget - self.considered) / max(1, frames_left)
        limit = int(min(cap, max(len(anchors), fair)))
        nodes: np.ndarray = frame_nodes(anchors, data, box, walk, spacing, limit)
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
                anchors = gather_anchors(
                    prev, worst, total, np.array(must), lower, upper, self.rng, popts
                )
                left = len(ks) - i + reserve
                nodes = self.nodes_at(k, anchors, walk[i], spacing, cap, left)
            unreached = self.unreached(k, nodes)
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

    def unreached(self, k: int, nodes: np.ndarray) -> bool:
        """Whether ``nodes`` of frame k are only the tracker's closest pose (no
        answer found)."""
        tracked = self.tracked[k]
        return len(nodes) == 1 and not tracked.success and np.array_equal(nodes[0], tracked.q)

    def solved_at(self, k: int, q: np.ndarray) -> bool:
        """Whether pose q of frame k is within tolerance: every node is, but the
        tracker's answer kept where no answer was found."""
        return self.tracked[k].success or not np.array_equal(q, self.tracked[k].q)
