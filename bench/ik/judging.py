"""Judging an answer (our FK, the limits, the clock) and recording the verdicts of one
solver on one chain in one part."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bench.ik_chains import BenchChain
from solver.model.forward import effector_poses

from .config import POS_TOL, ROT_TOL


def rotation_angle(r: np.ndarray) -> float:
    """Angle of a rotation matrix, accurate near 0 (atan2 of sin and cos parts)."""
    s = 0.5 * math.sqrt(
        (r[2, 1] - r[1, 2]) ** 2 + (r[0, 2] - r[2, 0]) ** 2 + (r[1, 0] - r[0, 1]) ** 2
    )
    c = 0.5 * (r[0, 0] + r[1, 1] + r[2, 2] - 1.0)
    return math.atan2(s, c)


@dataclass
class Verdict:
    ok: bool
    reason: (
        str  # "ok", "none" (no answer), "limits", "error" (outside tolerance), "late" (> budget)
    )
    dp: float  # position error [m] (nan if no answer)
    dr: float  # rotation error [rad] (nan if no answer or position only)


def judge(
    bc: BenchChain,
    q: np.ndarray | None,
    target: np.ndarray,
    position_only: bool,
    wall_s: float,
    budget_s: float,
) -> Verdict:
    if q is None:
        return Verdict(False, "none", math.nan, math.nan)
    if q.shape != (bc.pose.n_dof,) or not np.isfinite(q).all():
        return Verdict(False, "error", math.inf, math.inf)
    pose = effector_poses(bc.pose, q)[0]
    dp = float(np.linalg.norm(pose[:3, 3] - target[:3, 3]))
    dr = math.nan if position_only else rotation_angle(target[:3, :3].T @ pose[:3, :3])
    if np.any(q < bc.pose.lower) or np.any(q > bc.pose.upper):
        return Verdict(False, "limits", dp, dr)
    if not (dp <= POS_TOL and (position_only or dr <= ROT_TOL)):
        return Verdict(False, "error", dp, dr)
    if wall_s > budget_s:
        return Verdict(False, "late", dp, dr)
    return Verdict(True, "ok", dp, dr)


REASONS = ("ok", "late", "none", "limits", "error")


@dataclass
class Row:
    """One solver on one chain in one part. Results go to preallocated arrays, so the
    timed loop leaves no per-solve Python objects behind for the garbage collector."""

    chain: str
    key: str
    name: str
    settings: str
    n: int = 0  # attempts planned (solves) / made (tracking frames)
    cap: int = 0
    skipped: str = ""
    flag_mismatch: list[int] = field(default_factory=list)  # ours: own flag != our FK judge
    failed: list[tuple[int, str]] = field(default_factory=list)  # (target or frame index, reason)
    # tracking
    max_step: float = 0.0
    ref_step: float = 0.0
    step_ratio: float = 0.0  # worst over streams of max step / reference max step
    streams: int = 0
    # streams answered at every frame whose max step is at most twice the reference's
    streams_within_2x: int = 0

    def __post_init__(self) -> None:
        self.count = 0
        self._wall = np.empty(self.cap)
        self._core = np.empty(self.cap)
        self._reason = np.empty(self.cap, dtype=np.int8)
        self._dp = np.empty(self.cap)
        self._dr = np.empty(self.cap)

    def record(self, wall: float, core: float, v: Verdict, index: int) -> None:
        i = self.count
        if not v.ok and len(self.failed) < 1000:
            self.failed.append((index, v.reason))
        self._wall[i], self._core[i], self._dp[i], self._dr[i] = wall, core, v.dp, v.dr
        self._reason[i] = REASONS.index(v.reason)
        self.count = i + 1

    @property
    def wall(self) -> np.ndarray:
        return self._wall[: self.count]

    @property
    def n_ok(self) -> int:
        return int(np.count_nonzero(self._reason[: self.count] == 0))

    @property
    def n_within(self) -> int:
        """Answers within tolerance and limits, late or not."""
        r = self._reason[: self.count]
        return int(np.count_nonzero((r == 0) | (r == REASONS.index("late"))))

    @property
    def rate(self) -> float:
        return self.n_ok / max(1, self.count)

    def median_us(self) -> float:
        return 1e6 * float(np.median(self.wall)) if self.count else math.nan

    def p99_us(self) -> float:
        return 1e6 * float(np.percentile(self.wall, 99)) if self.count else math.nan

    def core_median_us(self) -> float:
        c = self._core[: self.count]
        c = c[np.isfinite(c)]
        return float(np.median(c)) if c.size else math.nan

    def fails(self) -> str:
        r = self._reason[: self.count]
        return " / ".join(str(int(np.count_nonzero(r == REASONS.index(x)))) for x in REASONS[1:])

    def max_errors(self) -> tuple[float, float]:
        answered = self._reason[: self.count] != REASONS.index("none")
        dp, dr = self._dp[: self.count][answered], self._dr[: self.count][answered]
        dr = dr[~np.isnan(dr)]
        return (float(dp.max()) if dp.size else math.nan), (
            float(dr.max()) if dr.size else math.nan
        )
