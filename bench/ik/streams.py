"""The targets: uniform random joint vectors for parts (a) and (b), the reference joint
paths of part (c), both through our FK; one generator per (chain, part)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from bench.ik_chains import CHAINS, BenchChain, load
from solver.ik import Target
from solver.model.forward import effector_poses

from .config import Config


def chain_rng(cfg: Config, chain: str, part: str) -> np.random.Generator:
    """One generator per (chain, part), independent of which chains or solvers run."""
    return np.random.default_rng(
        [cfg.seed, CHAINS.index(chain), {"targets": 0, "track": 1, "warm": 2, "order": 3}[part]]
    )


def uniform_q(rng: np.random.Generator, bc: BenchChain, n: int) -> np.ndarray:
    lo = np.where(np.isfinite(bc.pose.lower), bc.pose.lower, -math.pi)
    hi = np.where(np.isfinite(bc.pose.upper), bc.pose.upper, math.pi)
    return rng.uniform(lo, hi, size=(n, bc.pose.n_dof))


def target_q(chain: str, index: int, seed: int = 0) -> np.ndarray:
    """Joint vector behind target `index` of parts (a)/(b), for reproducing a case (the
    generator yields the same first rows whatever N is)."""
    bc = load(chain, peer_urdf=False)
    cfg = Config(index + 1, 0, seed, 0.0, 0, 0.0, 0, (), ())
    q: np.ndarray = uniform_q(chain_rng(cfg, chain, "targets"), bc, index + 1)[index]
    return q


def fk_poses(bc: BenchChain, qs: np.ndarray) -> np.ndarray:
    return np.array([effector_poses(bc.pose, q)[0] for q in qs])


def targets_for(bc: BenchChain, poses: np.ndarray, position_only: bool) -> list[list[Target]]:
    """Our targets for effector poses ``poses`` (shape (n, 4, 4)): one per pose."""
    e = bc.effector
    if position_only:
        return [[Target(effector=e, position=p[:3, 3].copy())] for p in poses]
    return [
        [Target(effector=e, position=p[:3, 3].copy(), rotation=p[:3, :3].copy())] for p in poses
    ]


def make_stream(rng: np.random.Generator, bc: BenchChain, frames: int, fps: float) -> np.ndarray:
    """q(t) = c + A sin(2 pi f t + phi): c uniform in the middle half of each range,
    A = min(0.6 rad, 0.8 x room to the nearer limit), f in [0.05, 0.3] Hz."""
    lo = np.where(np.isfinite(bc.pose.lower), bc.pose.lower, -math.pi)
    hi = np.where(np.isfinite(bc.pose.upper), bc.pose.upper, math.pi)
    n = bc.pose.n_dof
    c = lo + (hi - lo) * rng.uniform(0.25, 0.75, n)
    amp = np.minimum(0.6, 0.8 * np.minimum(c - lo, hi - c))
    f = rng.uniform(0.05, 0.3, n)
    phi = rng.uniform(0.0, 2 * math.pi, n)
    t = np.arange(frames)[:, None] / fps
    q: np.ndarray = c + amp * np.sin(2 * math.pi * f * t + phi)
    assert np.all(q >= lo) and np.all(q <= hi)
    return q


@dataclass(frozen=True)
class ReferenceStream:
    """One stream of part (c): the reference joint path, its FK poses and targets."""

    path: np.ndarray
    poses: np.ndarray
    targets: list[list[Target]]


def reference_streams(cfg: Config, bc: BenchChain) -> Iterator[ReferenceStream]:
    """Part (c)'s ``cfg.streams`` streams for ``bc``, in the benchmark's order (the
    probes in bench/ use it to reproduce the benchmark's streams)."""
    rng = chain_rng(cfg, bc.name, "track")
    for _ in range(cfg.streams):
        path = make_stream(rng, bc, cfg.frames, cfg.fps)
        poses = fk_poses(bc, path)
        yield ReferenceStream(path, poses, targets_for(bc, poses, False))


def max_step(qs: np.ndarray) -> float:
    return float(np.abs(np.diff(qs, axis=0)).max()) if len(qs) > 1 else 0.0
