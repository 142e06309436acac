"""service.convert: quaternion convention, field naming helpers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.testing import assert_allclose

import schemas as S
from service import convert
from service.convert.geometry import rotation_matrix
from solver.model import matrix_to_quaternion, quaternion_to_matrix


def test_rotation_matches_the_solver_convention_wxyz() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        got = rotation_matrix(S.Quaternion(w=q[0], x=q[1], y=q[2], z=q[3]))
        assert_allclose(got, quaternion_to_matrix(q), rtol=0.0, atol=1e-12)


def test_rotation_normalises_slightly_off_quaternions() -> None:
    r = rotation_matrix(S.Quaternion(w=1.0004, x=0.0, y=0.0, z=0.0))
    assert_allclose(r, np.eye(3), rtol=0.0, atol=1e-12)
    # 90 degrees about z: x -> y.
    s = 0.5**0.5
    rz = rotation_matrix(S.Quaternion(w=s, x=0.0, y=0.0, z=s))
    assert_allclose(rz @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], rtol=0.0, atol=1e-12)
    assert_allclose(matrix_to_quaternion(rz), [s, 0.0, 0.0, s], rtol=0.0, atol=1e-12)


def test_result_dict_effectors_match_ikresult_effectors() -> None:
    """result_dict reads the raw error rows; IKResult.effectors is the reference."""
    from solver.ik import IKSolver, pose_targets
    from solver.model.examples import EXAMPLES

    for factory in EXAMPLES.values():
        chain = factory()
        solver = IKSolver(chain)
        targets = pose_targets(chain, chain.mid_limits() + 0.1)
        far = [replace(targets[0], position=np.array([50.0, 0.0, 0.0]))]
        for ts in (targets, targets[:1], far):  # all, some (others untargeted), missed
            r = solver.track(ts)
            out = convert.result_dict(r, 5, 1.0)
            want = [
                {
                    "name": e.name,
                    "position_error_m": e.position_error_m,
                    "rotation_error_rad": e.rotation_error_rad,
                    "within_tolerance": e.within_tolerance,
                }
                for e in r.effectors
            ]
            assert out["effectors"] == want
            assert out["joints"] == r.joint_values
            assert S.FrameResult.model_validate(out).id == 5
