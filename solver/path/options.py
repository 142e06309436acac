"""The planner's settings (``PathOptions``) and what it returns (``PlannedPath``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..ik import IKResult

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
