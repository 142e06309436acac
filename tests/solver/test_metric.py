"""The Gauss-Newton metric H = (2 J^T W J + c I)^-1 against numpy, on both of its paths:
the direct n x n inverse and the low-rank (Woodbury) form used when the task has at
most half as many rows as variables."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_allclose

from solver import EffectorMode, IKOptions, IKSolver
from solver.ik import pose_targets
from solver.ik.kinematics import DD_HI, DD_LO, ik_objective
from solver.ik.metric import ik_metric, metric_inverse
from solver.ik.spd import invert_spd_by_blocks, invert_spd_in_place
from solver.model import Chain, Effector, build_chain
from solver.model.examples import humanoid_arm, panda_arm, tail, two_arm_torso
from solver.model.forward import effector_poses
from solver.model.layout import ED_WP, ED_WR
from solver.model.urdf import chain_from_urdf
from solver.optim.codes import MetricKind


def _weighted_jacobian_fd(chain: Chain, q: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """sqrt(W) J by central differences of our FK: 3 position rows per effector, plus 3
    angular-velocity rows for pose effectors."""
    blocks = []
    for e, eff in enumerate(chain.effectors):
        jp = np.empty((3, chain.n_dof))
        jw = np.empty((3, chain.n_dof))
        r0 = effector_poses(chain, q)[e][:3, :3]
        for i in range(chain.n_dof):
            dq = np.zeros(chain.n_dof)
            dq[i] = eps
            up = effector_poses(chain, q + dq)[e]
            down = effector_poses(chain, q - dq)[e]
            jp[:, i] = (up[:3, 3] - down[:3, 3]) / (2 * eps)
            w = (up[:3, :3] - down[:3, :3]) / (2 * eps) @ r0.T
            jw[:, i] = [w[2, 1], w[0, 2], w[1, 0]]
        blocks.append(np.sqrt(chain.compiled.ed[e, ED_WP]) * jp)
        if eff.mode is EffectorMode.POSE:
            blocks.append(np.sqrt(chain.compiled.ed[e, ED_WR]) * jw)
    return np.vstack(blocks)


def _tail_with_two_points() -> Chain:
    """The 20-segment tail with a second position effector half-way along: the
    low-rank metric then stacks two effectors' rows."""
    base = tail(20)
    return build_chain(
        list(base.joints),
        [*base.effectors, Effector(name="middle", link="seg10", mode=EffectorMode.POSITION)],
    )


_SERIAL_MIMIC = """<robot name="serial_mimic">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="tip"/>
  <joint name="a" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 1 0"/><limit lower="-2" upper="2"/></joint>
  <joint name="b" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/><limit lower="-2" upper="2"/>
    <mimic joint="a" multiplier="0.5" offset="0.1"/></joint>
  <joint name="c" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0 0 0.3"/><axis xyz="1 0 0"/><limit lower="-2" upper="2"/></joint>
  <joint name="d" type="revolute"><parent link="l3"/><child link="tip"/>
    <origin xyz="0 0 0.2"/><axis xyz="0 0 1"/><limit lower="-2" upper="2"/>
    <mimic joint="c" multiplier="-1.5"/></joint>
</robot>"""


def _serial_mimic() -> Chain:
    """Two leaders, each moving two nodes of one path (a, b = 0.5 a + 0.1; c, d = -1.5 c):
    the metric must count each leader's column once per effector."""
    return chain_from_urdf(_SERIAL_MIMIC, base_link="base", tip_links="tip")


@pytest.mark.parametrize(
    ("factory", "low_rank"),
    [
        (_serial_mimic, False),  # 6 rows, 2 variables, 4 moving nodes
        (lambda: panda_arm(EffectorMode.POSITION), True),  # 3 rows, 7 variables
        (panda_arm, False),  # 6 rows, 7 variables
        (humanoid_arm, False),
        (two_arm_torso, False),  # two position effectors: 6 rows, 7 variables
        (lambda: tail(3, EffectorMode.POSE), False),  # 6 rows, 6 variables
        (lambda: tail(20), True),  # 3 rows, 40 variables
        (_tail_with_two_points, True),  # two position effectors: 6 rows, 40 variables
    ],
)
@pytest.mark.parametrize("damping", [0.0, 1e-3])
@pytest.mark.parametrize("damping_scale", [IKOptions().damping_scale, 1.0])
def test_metric_is_the_damped_gauss_newton_inverse(
    factory, low_rank: bool, damping: float, damping_scale: float
) -> None:  # type: ignore[no-untyped-def]
    chain = factory()
    rows = sum(3 if e.mode is EffectorMode.POSITION else 6 for e in chain.effectors)
    assert (2 * rows <= chain.n_dof) is low_rank
    rng = np.random.default_rng(11)
    lo = np.where(np.isfinite(chain.lower), chain.lower, -np.pi)
    hi = np.where(np.isfinite(chain.upper), chain.upper, np.pi)
    # One solve of the whole chain (two_arm_torso's arms share no variable: split, each
    # arm would be solved on its own limb's solver) loads the options into its arrays.
    options = IKOptions(damping=damping, damping_scale=damping_scale, split_limbs=False)
    solver = IKSolver(chain, options)
    targets = pose_targets(chain, rng.uniform(lo, hi) * 0.5)
    solver.solve(targets)  # loads the targets and options into the compiled arrays
    data = solver.load_frame(targets, chain.mid_limits())  # as the solve loaded them
    q = rng.uniform(lo, hi) * 0.8  # strictly inside the limits: nothing held
    g = np.empty(chain.n_dof)
    f = ik_objective(q, g, True, data)
    h = np.empty((chain.n_dof, chain.n_dof))
    assert metric_inverse(q, np.zeros(chain.n_dof), data[4][DD_LO], data[4][DD_HI], data, h)
    jac = _weighted_jacobian_fd(chain, q)
    # Variables no targeted effector moves (above a terminator) are frozen for the
    # solve: they stay out of the coupling and get 1/c on the diagonal.
    frozen = data[4][DD_LO] == data[4][DD_HI]
    assert frozen.any() == (factory is two_arm_torso)
    jac[:, frozen] = 0.0
    c = max(damping_scale * f + 1e-9, damping)
    expected = np.linalg.inv(2 * jac.T @ jac + c * np.eye(chain.n_dof))
    assert_allclose(h, h.T, rtol=0, atol=1e-9 * np.abs(h).max())
    # Compare the steps the metric gives, -H g, and H itself, relative to their size.
    assert_allclose(h @ g, expected @ g, rtol=1e-5, atol=1e-7 * np.linalg.norm(expected @ g))
    assert_allclose(h, expected, rtol=0, atol=1e-5 * np.abs(expected).max())


def test_the_inverse_by_blocks_is_the_whole_inverse_bit_for_bit() -> None:
    """Limbs that share no variable (g1's legs) make J^T W J block diagonal up to a
    permutation; the metric inverts the blocks one by one, and every entry is the one
    the whole matrix's inverse gives (the skipped terms are exact zeros), the zeros
    between blocks included. Blocks interleaved in the index order, as a URDF's
    breadth-first variable order interleaves limbs, and a lone (held) variable."""
    rng = np.random.default_rng(3)
    n = 13
    label = np.array([0, 1, 2, 0, 1, 2, 0, 1, 2, 3, 2, 2, 1])
    a = rng.normal(size=(n, 2 * n))
    m = a @ a.T * (label[:, None] == label[None, :]) + 1e-3 * np.eye(n)
    whole = m.copy()
    assert invert_spd_in_place(whole)
    blocks = m.copy()
    root = np.zeros(n)
    order = np.zeros(n)
    assert invert_spd_by_blocks(blocks, root, order)
    np.testing.assert_array_equal(blocks, whole)
    np.testing.assert_allclose(blocks @ m, np.eye(n), atol=1e-9)
    np.testing.assert_array_equal(root, [0, 1, 2, 0, 1, 2, 0, 1, 2, 9, 2, 2, 1])
    # One block: the whole matrix's own loops.
    full = a @ a.T + 1e-3 * np.eye(n)
    one = full.copy()
    assert invert_spd_by_blocks(one, root, order)
    expected = full.copy()
    assert invert_spd_in_place(expected)
    np.testing.assert_array_equal(one, expected)
    # Not positive definite: False, as the whole inverse says.
    bad = m.copy()
    bad[9, 9] = -1.0
    assert not invert_spd_by_blocks(bad, root, order)


def _tree(trunk: int, limbs: int, limb_joints: int) -> Chain:
    """A tree: ``trunk`` joints from the base, then ``limbs`` limbs of ``limb_joints``
    joints each, a pose effector at each limb's tip."""
    axes = ("1 0 0", "0 1 0", "0 0 1")
    links = ['<link name="base"/>']
    joints = []
    count = 0

    def joint(parent: str, child: str) -> None:
        nonlocal count
        links.append(f'<link name="{child}"/>')
        joints.append(
            f'<joint name="j{count}" type="revolute"><parent link="{parent}"/>'
            f'<child link="{child}"/><origin xyz="0.05 0 0.2" rpy="0.3 0 0"/>'
            f'<axis xyz="{axes[count % 3]}"/><limit lower="-2" upper="2"/></joint>'
        )
        count += 1

    parent = "base"
    for k in range(trunk):
        joint(parent, f"t{k}")
        parent = f"t{k}"
    tips = []
    for limb in range(limbs):
        up = parent
        for k in range(limb_joints):
            joint(up, f"l{limb}_{k}")
            up = f"l{limb}_{k}"
        tips.append(up)
    urdf = f'<robot name="tree">{"".join(links)}{"".join(joints)}</robot>'
    chain = chain_from_urdf(urdf, base_link="base", tip_links=tips)
    effectors = [dataclasses.replace(e, mode=EffectorMode.POSE) for e in chain.effectors]
    return build_chain(list(chain.joints), effectors)


@pytest.mark.parametrize(
    ("factory", "kind"),
    [
        (panda_arm, MetricKind.FACTOR),  # the direct form
        (humanoid_arm, MetricKind.FACTOR),
        # From 13 variables the blocks decide: one (a torso and two arms) or two
        # that cost less inverted apart than the whole's factor (two legs on the base).
        (lambda: _tree(1, 2, 6), MetricKind.FACTOR),
        (lambda: _tree(0, 2, 7), MetricKind.INVERSE),
        (lambda: tail(20), MetricKind.INVERSE),  # the low-rank form writes H itself
    ],
)
def test_the_registered_metric_hands_over_the_factor_of_the_same_matrix(
    factory, kind: MetricKind
) -> None:  # type: ignore[no-untyped-def]
    """On the direct form (unless its blocks inverted one by one are less work), the
    metric the optimizer receives is the Cholesky factor L of H's inverse (its step is
    then two triangular solves): the lower triangle of what ``ik_metric`` writes, and
    (L L^T)^-1 is the H that ``metric_inverse`` writes at the same point, a held
    variable uncoupled in both."""
    chain = factory()
    rng = np.random.default_rng(5)
    lo = np.where(np.isfinite(chain.lower), chain.lower, -np.pi)
    hi = np.where(np.isfinite(chain.upper), chain.upper, np.pi)
    solver = IKSolver(chain, IKOptions(split_limbs=False))
    targets = pose_targets(chain, rng.uniform(lo, hi) * 0.5)
    solver.solve(targets)
    data = solver.load_frame(targets, chain.mid_limits())
    q = rng.uniform(lo, hi) * 0.8
    g = np.zeros(chain.n_dof)
    # One variable held: on its lower limit, the gradient pushing further down.
    q[1] = data[4][DD_LO][1]
    g[1] = 1.0
    ik_objective(q, np.empty(chain.n_dof), True, data)
    h = np.empty((chain.n_dof, chain.n_dof))
    assert metric_inverse(q, g, data[4][DD_LO], data[4][DD_HI], data, h)
    assert h[1, 1] > 0.0 and not h[1, np.arange(chain.n_dof) != 1].any()  # uncoupled
    written = np.empty_like(h)
    assert ik_metric(q, g, data[4][DD_LO], data[4][DD_HI], data, written) == kind
    if kind is MetricKind.FACTOR:
        low = np.tril(written)
        assert (np.diag(low) > 0).all()
        assert_allclose(np.linalg.inv(low @ low.T), h, rtol=0, atol=1e-9 * np.abs(h).max())
    else:
        np.testing.assert_array_equal(written, h)
