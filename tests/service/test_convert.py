"""convert.py: quaternion convention, field naming helpers."""

from __future__ import annotations

import numpy as np
from numpy.testing import assert_allclose

import schemas as S
from service import convert
from solver.chain import matrix_to_quaternion, quaternion_to_matrix


def test_rotation_matches_the_solver_convention_wxyz() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        got = convert._rotation(S.Quaternion(w=q[0], x=q[1], y=q[2], z=q[3]))
        assert_allclose(got, quaternion_to_matrix(q), rtol=0.0, atol=1e-12)


def test_rotation_normalises_slightly_off_quaternions() -> None:
    r = convert._rotation(S.Quaternion(w=1.0004, x=0.0, y=0.0, z=0.0))
    assert_allclose(r, np.eye(3), rtol=0.0, atol=1e-12)
    # 90 degrees about z: x -> y.
    s = 0.5**0.5
    rz = convert._rotation(S.Quaternion(w=s, x=0.0, y=0.0, z=s))
    assert_allclose(rz @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], rtol=0.0, atol=1e-12)
    assert_allclose(matrix_to_quaternion(rz), [s, 0.0, 0.0, s], rtol=0.0, atol=1e-12)
