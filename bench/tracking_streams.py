"""The streams of bench/tracking.py: seeded, drawn at random per run, never tuned to.

Each stream is a reference joint path (600 frames at 60 Hz by default) inside the
limits; its targets are our FK of that path, so every frame is reachable by a
continuous path whose largest per-frame step is known (the "reference's step"). Four
kinds, in turn by stream index so that every kind is in every run:

- ``sines``: q(t) = c + sum of two sinusoids per joint, random amplitudes,
  frequencies in [0.05, 0.5] Hz and phases, c and the amplitudes drawn so that the
  path stays inside the limits.
- ``circle``, ``figure_eight``: the effector traces a circle (radius 5-20 cm) or a
  figure eight (5-20 cm) in a random plane through its start, period 2-6 s, its
  orientation held; ``reach``: the effector moves 0.6 m outwards from the base and
  back (period 4-8 s), towards and, for most starts, beyond the edge of the
  workspace, where the path stops at the stretched arm. These paths are integrated
  from a random start by damped resolved-rate steps (4 per frame, the Jacobian from
  roboticstoolbox's ETS of the chain's URDF, joint limits clipped), so the joint path
  is an independent, continuous solution, not one of ours.

The generator for stream i of chain c is ``default_rng([seed, c, i])``: a stream does
not depend on how many streams or which chains run.
"""

from __future__ import annotations

import io
import math
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from bench.peers.rtb_peer import renumber_joints
from bench.robots import RobotSpec

KINDS: tuple[str, ...] = ("sines", "circle", "figure_eight", "reach")
SUBSTEPS = 4  # resolved-rate steps per frame
DAMPING = 0.05  # lambda of the damped least squares of the resolved-rate steps
MAX_SUBSTEP = 0.02  # rad per resolved-rate step (the reference: <= 0.08 rad per frame)


@dataclass(frozen=True)
class Stream:
    kind: str
    path: np.ndarray  # (frames, n) in the peer's (URDF chain) joint order

    @property
    def largest_step(self) -> float:
        return float(np.abs(np.diff(self.path, axis=0)).max())


class PeerChain:
    """roboticstoolbox's ETS of a chain's URDF: FK and the base-frame Jacobian, in our
    chain's base frame.

    rtb's ``ets(start=link)`` begins with the joint above ``link`` (Baxter's arm mount,
    PR2's torso lift, made fixed by ``PeerSpec``): ``base`` (= ours(q) rtb(q)^-1, a
    constant, checked at a second pose) takes its frame to ours.
    """

    def __init__(self, spec: RobotSpec, ours: Callable[[np.ndarray], np.ndarray]) -> None:
        from roboticstoolbox.models.URDF.URDFRobot import URDF_file
        from roboticstoolbox.robot.Robot import Robot

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            elinks, name, _ = URDF_file(io.StringIO(spec.kinematic_urdf_text()))
            self.ets = Robot(elinks, name=name).ets(start=spec.base_link, end=spec.tip_link)
        renumber_joints(self.ets)
        self.lower = np.where(np.isfinite(spec.lower), spec.lower, -math.pi)
        self.upper = np.where(np.isfinite(spec.upper), spec.upper, math.pi)
        self.base = np.eye(4)
        q0 = 0.5 * (self.lower + self.upper)
        self.base = ours(q0) @ np.linalg.inv(self.fk(q0))
        q1 = self.lower + 0.3 * (self.upper - self.lower)
        if not np.allclose(self.fk(q1), ours(q1), atol=1e-9):
            raise ValueError(f"{spec.name}: rtb's FK differs from ours")

    def fk(self, q: np.ndarray) -> np.ndarray:
        return self.base @ np.asarray(self.ets.eval(q))

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        j = np.asarray(self.ets.jacob0(q))
        r = self.base[:3, :3]
        return np.vstack([r @ j[:3], r @ j[3:]])


@dataclass(frozen=True)
class PeerSpec(RobotSpec):
    """A RobotSpec whose joint above ``base_link`` is fixed in the URDF rtb reads (rtb's
    ETS from ``base_link`` would move with it), and whose continuous joints have rtb's
    limits, +-pi (what rtb's ``ik_LM`` keeps them in)."""

    @property
    def lower(self) -> np.ndarray:
        return np.array([j.lower if j.type != "continuous" else -math.pi for j in self.chain()])

    @property
    def upper(self) -> np.ndarray:
        return np.array([j.upper if j.type != "continuous" else math.pi for j in self.chain()])

    def kinematic_urdf_text(self) -> str:
        text = super().kinematic_urdf_text()
        root = ET.fromstring(text)
        for j in root.findall("joint"):
            child = j.find("child")
            if child is not None and child.get("link") == self.base_link:
                j.set("type", "fixed")
        return ET.tostring(root, encoding="unicode")


def make_stream(
    peer: PeerChain, seed: int, chain_index: int, index: int, frames: int, fps: float
) -> Stream:
    rng = np.random.default_rng([seed, chain_index, index])
    kind = KINDS[index % len(KINDS)]
    lo, hi = peer.lower, peer.upper
    n = lo.shape[0]
    t = np.arange(frames)[:, None] / fps
    if kind == "sines":
        c = lo + (hi - lo) * rng.uniform(0.25, 0.75, n)
        room = 0.9 * np.minimum(c - lo, hi - c)
        share = rng.uniform(0.2, 0.8, n)
        a1 = np.minimum(0.8, room) * share
        a2 = np.minimum(0.8, room) * (1.0 - share)
        f1, f2 = rng.uniform(0.05, 0.5, n), rng.uniform(0.05, 0.5, n)
        p1, p2 = rng.uniform(0, 2 * math.pi, n), rng.uniform(0, 2 * math.pi, n)
        path = c + a1 * np.sin(2 * math.pi * f1 * t + p1) + a2 * np.sin(2 * math.pi * f2 * t + p2)
        return Stream(kind, path)
    q = lo + (hi - lo) * rng.uniform(0.25, 0.75, n)
    start = peer.fk(q)
    p0, r0 = start[:3, 3].copy(), start[:3, :3].copy()
    u, w = _plane(rng)
    tt = t[:, 0]
    if kind == "circle":
        radius, period = rng.uniform(0.05, 0.2), rng.uniform(2.0, 6.0)
        a = 2 * math.pi * tt / period
        points = p0 + radius * (np.cos(a)[:, None] - 1.0) * u + radius * np.sin(a)[:, None] * w
    elif kind == "figure_eight":
        size, period = rng.uniform(0.05, 0.2), rng.uniform(2.0, 6.0)
        a = 2 * math.pi * tt / period
        points = p0 + size * np.sin(a)[:, None] * u + 0.5 * size * np.sin(2 * a)[:, None] * w
    else:  # reach: outwards from the base, a little off radial
        out = p0 / max(np.linalg.norm(p0), 1e-9) + 0.3 * rng.normal(size=3)
        out /= np.linalg.norm(out)
        period = rng.uniform(4.0, 8.0)
        s = 0.6 * 0.5 * (1.0 - np.cos(2 * math.pi * tt / period))
        points = p0 + s[:, None] * out
    return Stream(kind, _resolved_rate(peer, q, points, r0))


def _plane(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Two orthonormal vectors spanning a random plane."""
    m, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return m[:, 0], m[:, 1]


def _resolved_rate(
    peer: PeerChain, q: np.ndarray, points: np.ndarray, rotation: np.ndarray
) -> np.ndarray:
    """The joint path that follows ``points`` with ``rotation`` held, by damped
    resolved-rate steps from q; where the arm cannot follow (the workspace's edge, a
    limit) it stops as close as it gets."""
    lo, hi = peer.lower, peer.upper
    path = np.empty((points.shape[0], q.shape[0]))
    eye6 = np.eye(6)
    for k, target in enumerate(points):
        for _ in range(SUBSTEPS):
            x = peer.fk(q)
            e = np.empty(6)
            e[:3] = target - x[:3, 3]
            e[3:] = _rotation_error(rotation @ x[:3, :3].T)
            j = peer.jacobian(q)
            dq = j.T @ np.linalg.solve(j @ j.T + DAMPING**2 * eye6, e)
            big = np.abs(dq).max()
            if big > MAX_SUBSTEP:
                dq *= MAX_SUBSTEP / big
            q = np.clip(q + dq, lo, hi)
        path[k] = q
    return path


def _rotation_error(r: np.ndarray) -> np.ndarray:
    """The rotation vector of r (small angles: the vee of its skew part)."""
    c = max(-1.0, min(1.0, 0.5 * (np.trace(r) - 1.0)))
    angle = math.acos(c)
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    s = math.sin(angle)
    return v * (0.5 if s < 1e-9 else angle / (2.0 * s))


def min_singular_value(peer: PeerChain, path: np.ndarray, rows: int) -> float:
    """Smallest singular value of the Jacobian (first ``rows`` rows: 3 position, 6
    pose) along the path, every 5th frame: how close the reference passes a singularity."""
    worst = math.inf
    for q in path[::5]:
        s = np.linalg.svd(peer.jacobian(q)[:rows], compute_uv=False)
        worst = min(worst, float(s[-1]))
    return worst
