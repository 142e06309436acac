"""Engine coordinate conventions at the boundary: client <-> the chain's native frame.

A convention is an up axis, a handedness and a length unit. Each maps to glTF's frame
(Y up, right-handed, metres) by a fixed signed permutation ``A`` (det +-1), the one the
engines' own glTF importers use:

  Y up, right (glTF, Godot, three.js)   identity
  Y up, left  (Unity)                   X mirrored: (x, y, z) -> (-x, y, z)
                                        (glTFast, UnityGLTF: position (-x, y, z),
                                        rotation (w, x, -y, -z))
  Z up, right (ROS, Blender, URDF)      (x, y, z) -> (x, z, -y) (Blender's glTF exporter)
  Z up, left  (Unreal)                  Y and Z swapped: (x, y, z) -> (x, z, y)
                                        (Unreal's glTF importer: position (x, z, y),
                                        rotation (w, -x, -z, -y))

From client to native: ``M = A_native^T A_client`` and ``s = unit_client / unit_native``;
``p_native = s M p_client``, directions ``M d``, rotations ``M R M^T`` (a proper
rotation even when det M = -1). Back: ``p_client = M^T p_native / s``, ``M^T R M``.
A bone's local rotation converts like any rotation: the engine's importer converts
every node's local transform by the same change of basis.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

import schemas as S
from solver.arrays import Matrix, Vector
from solver.ik import GIVEN_DIRECTION, GIVEN_POSITION, GIVEN_ROTATION
from solver.ik import Pole as SolverPole
from solver.ik import Target as SolverTarget

_TO_GLTF: dict[tuple[str, str], Matrix] = {
    ("y", "right"): np.eye(3),
    ("y", "left"): np.diag([-1.0, 1.0, 1.0]),
    ("z", "right"): np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]),
    ("z", "left"): np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]),
}
_UNIT_M = {"m": 1.0, "cm": 0.01}
PRESETS: dict[str, tuple[str, str, str]] = {
    # preset: (up, handedness, unit)
    "unity": ("y", "left", "m"),
    "unreal": ("z", "left", "cm"),
    "godot": ("y", "right", "m"),
    "gltf": ("y", "right", "m"),
    "threejs": ("y", "right", "m"),
    "ros": ("z", "right", "m"),
}


@dataclass(frozen=True, slots=True)
class Frame:
    """A coordinate convention: up axis, handedness, metres per length unit."""

    up: str = "z"
    handedness: str = "right"
    unit_m: float = 1.0


Z_UP_METRES = Frame("z", "right", 1.0)  # hierarchy, URDF, examples
Y_UP_METRES = Frame("y", "right", 1.0)  # glTF, BVH (after unit_m)


@dataclass(frozen=True, slots=True)
class Convention:
    """Client -> native: ``p_native = scale * matrix @ p_client``; ``identity`` when
    nothing changes (the hot paths then skip the conversion)."""

    matrix: Matrix
    scale: float
    client: Frame
    identity: bool

    @classmethod
    def between(cls, client: Frame, native: Frame) -> Convention:
        a_client = _TO_GLTF[(client.up, client.handedness)]
        a_native = _TO_GLTF[(native.up, native.handedness)]
        m = a_native.T @ a_client
        s = client.unit_m / native.unit_m
        identity = bool(np.array_equal(m, np.eye(3)) and s == 1.0)
        return cls(m, s, client, identity)

    # -- in --------------------------------------------------------------------------
    def target_in(self, t: SolverTarget) -> SolverTarget:
        """The target in the native frame."""
        row = t.packed.copy()
        m = self.matrix
        if t.given & GIVEN_POSITION:
            row[0:3] = self.scale * (m @ row[0:3])
        if t.given & GIVEN_ROTATION:
            row[3:12] = (m @ row[3:12].reshape(3, 3) @ m.T).reshape(9)
        if t.given & GIVEN_DIRECTION:
            row[12:15] = m @ row[12:15]
        if t.plain:
            return SolverTarget.from_row(t.effector, row, t.given)
        pole = t.pole
        if pole is not None:
            pole = SolverPole(self.scale * (m @ pole.point), pole.link)
        return SolverTarget.from_row(
            t.effector,
            row,
            t.given,
            position_weight=t.position_weight,
            rotation_weight=t.rotation_weight,
            pole=pole,
        )

    def targets_in(self, ts: Sequence[SolverTarget]) -> Sequence[SolverTarget]:
        return ts if self.identity else [self.target_in(t) for t in ts]

    # -- out -------------------------------------------------------------------------
    def position_out(self, p: Vector) -> Vector:
        return (self.matrix.T @ p) / self.scale

    def direction_out(self, d: Vector) -> Vector:
        """A native direction -> the client's (``target_in``'s ``M d`` undone: no scale)."""
        return self.matrix.T @ d

    def rotation_out(self, r: Matrix) -> Matrix:
        return self.matrix.T @ r @ self.matrix

    def quaternions_out(self, quats: Matrix) -> Matrix:
        """Rows (w, x, y, z) of native rotations -> the client's. A change of basis
        by a signed permutation acts on the vector part as the pseudovector it is:
        ``v' = det(M) M^T v``, w unchanged (no sign flip, so streams stay continuous)."""
        if self.identity:
            return quats
        out = quats.copy()
        det = float(np.linalg.det(self.matrix))
        out[:, 1:] = det * (quats[:, 1:] @ self.matrix)  # rows: (M^T v)^T = v^T M
        return out


NATIVE = Convention(np.eye(3), 1.0, Z_UP_METRES, identity=True)


def frame_of(spec: S.Conventions | None, native: Frame) -> Frame:
    """The client's frame: the preset's, then the fields given, else the native one."""
    if spec is None:
        return native
    up, hand, unit_m = native.up, native.handedness, native.unit_m
    if spec.preset is not None:
        up, hand, unit = PRESETS[spec.preset]
        unit_m = _UNIT_M[unit]
    if spec.up is not None:
        up = spec.up
    if spec.handedness is not None:
        hand = spec.handedness
    if spec.unit is not None:
        unit_m = _UNIT_M[spec.unit]
    return Frame(up, hand, unit_m)
