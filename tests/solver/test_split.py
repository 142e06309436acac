"""A cold solve takes the targeted effectors in groups that share no free variable one
group at a time, each on its limb's own chain (``ik.split``, ``model.limbs``)."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from solver import (
    Chain,
    IKOptions,
    IKSolver,
    IKStatus,
    InvalidProblem,
    Target,
    Transform,
    build_chain,
)
from solver.ik import pose_targets
from solver.model import Effector, EffectorMode, Joint, JointKind, Mimic
from solver.model.limbs import limb_chain

X, Y, Z = np.eye(3)


def _joint(spec: tuple, **kw: object) -> Joint:  # type: ignore[type-arg]
    """A joint from (name, parent, child, origin, kind, axes or axis, lower, upper)."""
    name, parent, child, at, kind, axes, lower, upper = spec
    motion = {"axes": axes} if isinstance(axes, str) else {"axis": axes}
    if kind is JointKind.FIXED:
        motion = {}
    return Joint(
        name=name,
        parent=parent,
        child=child,
        origin=Transform(np.array(at, dtype=float)),
        kind=kind,
        lower=lower,
        upper=upper,
        **motion,
        **kw,  # type: ignore[arg-type]
    )


def biped(
    *,
    knees_mimic: bool = False,
    lock_waist: bool = False,
    neck: bool = False,
    bending_waist: bool = False,
) -> Chain:
    """A pelvis (the base) with two 6-DOF legs under foot poses and, above a waist
    joint, a head (position) and two 4-DOF arms (hand positions): three groups, legs
    and upper body, whose head is inside both hands' paths. ``knees_mimic``: the
    right knee follows the left (one leg group); ``lock_waist``: the waist cannot
    move (the head and hands share no free variable); ``neck``: the head is a pose
    on a 2-joint neck; ``bending_waist``: the waist turns and bends (2 variables)."""
    w = 0.0 if lock_waist else 2.0
    r, rot, fixed = JointKind.REVOLUTE, JointKind.ROTATIONAL, JointKind.FIXED
    specs = [
        (
            "waist",
            "pelvis",
            "chest",
            [0, 0, 0.2],
            *((rot, "zy", (-w, -0.5), (w, 0.5)) if bending_waist else (r, Z, (-w,), (w,))),
        ),
        (
            "neck",
            "chest",
            "head",
            [0.05, 0, 0.5],
            *((rot, "zy", (-1.0, -0.5), (1.0, 0.5)) if neck else (fixed, "", (), ())),
        ),
    ]
    effectors = [
        Effector(
            name="head", link="head", mode=EffectorMode.POSE if neck else EffectorMode.POSITION
        )
    ]
    for side, y in (("left", 1.0), ("right", -1.0)):
        specs += [
            (
                f"{side}_hip",
                "pelvis",
                f"{side}_thigh",
                [0, 0.1 * y, -0.1],
                rot,
                "zxy",
                (-1.0, -0.6, -1.5),
                (1.0, 0.6, 1.0),
            ),
            (f"{side}_knee", f"{side}_thigh", f"{side}_shin", [0, 0, -0.4], r, Y, (0.0,), (2.2,)),
            (
                f"{side}_ankle",
                f"{side}_shin",
                f"{side}_foot",
                [0, 0, -0.4],
                rot,
                "yx",
                (-0.8, -0.4),
                (0.6, 0.4),
            ),
            (
                f"{side}_shoulder",
                "chest",
                f"{side}_upper",
                [0, 0.2 * y, 0.4],
                rot,
                "xyz",
                (-2.0,) * 3,
                (2.0,) * 3,
            ),
            (f"{side}_elbow", f"{side}_upper", f"{side}_fore", [0, 0, -0.3], r, Y, (0.0,), (2.5,)),
            (f"{side}_wrist", f"{side}_fore", f"{side}_hand", [0, 0, -0.25], fixed, "", (), ()),
        ]
        effectors += [
            Effector(name=f"{side}_foot", link=f"{side}_foot", mode=EffectorMode.POSE),
            Effector(name=f"{side}_hand", link=f"{side}_hand", mode=EffectorMode.POSITION),
        ]
    follows = {"right_knee": Mimic("left_knee")} if knees_mimic else {}
    return build_chain([_joint(j, mimic=follows.get(j[0])) for j in specs], effectors)


def _groups(chain: Chain, targets: list[Target]) -> list[list[str]] | None:
    groups = IKSolver(chain)._split.groups(targets)
    names = chain.effector_names
    return None if groups is None else [[names[i] for i in g] for g in groups]


def test_effectors_that_share_no_free_variable_form_groups() -> None:
    chain = biped()
    targets = pose_targets(chain, chain.mid_limits())
    assert _groups(chain, targets) == [
        ["head", "left_hand", "right_hand"],
        ["left_foot"],
        ["right_foot"],
    ]
    # A follower moves with its leader: the right foot moves with the left knee.
    mimic = biped(knees_mimic=True)
    assert _groups(mimic, pose_targets(mimic, mimic.mid_limits()))[1:] == [  # type: ignore[index]
        ["left_foot", "right_foot"]
    ]
    # A locked joint moves nothing: the head and the hands no longer interact.
    locked = biped(lock_waist=True)
    assert _groups(locked, pose_targets(locked, locked.mid_limits())) == [
        ["head"],
        ["left_foot"],
        ["left_hand"],
        ["right_foot"],
        ["right_hand"],
    ]
    # One target: nothing to split.
    assert _groups(chain, targets[:1]) is None


def test_a_groups_trunk_effectors_come_first() -> None:
    for chain in (biped(), biped(neck=True)):
        split = IKSolver(chain)._split
        head, left, right = (chain.effector_index(n) for n in ("head", "left_hand", "right_hand"))
        # The waist (the trunk: it moves every effector) alone moves the head; on a
        # neck, the head's two joints cannot turn it to a pose (6 rows): the waist must.
        assert split.inner((head, left, right)) == (head,)
        # Each hand has 4 joints beyond the waist for its 3 rows: neither is inner.
        assert split.inner((left, right)) == ()
    # Every effector inner (the head alone; the feet share no trunk): nothing first.
    assert IKSolver(biped())._split.inner((0,)) == ()
    chain = biped()
    feet = tuple(chain.effector_index(n) for n in ("left_foot", "right_foot"))
    assert IKSolver(chain)._split.inner(feet) == ()


def test_a_limb_chain_keeps_the_paths_the_whole_chains_limits_and_mimic_leaders() -> None:
    chain = biped(knees_mimic=True)
    right_foot = chain.effector_index("right_foot")
    limb, variables = limb_chain(chain, [right_foot])
    # The right leg, and the left knee that its knee follows (with the path to it).
    assert {j.name for j in limb.joints} == {
        "right_hip",
        "right_knee",
        "right_ankle",
        "left_hip",
        "left_knee",
    }
    assert [chain.dof_names[i] for i in variables] == list(limb.dof_names)
    assert "left_knee" in limb.dof_names
    np.testing.assert_array_equal(limb.lower, chain.lower[variables])
    np.testing.assert_array_equal(limb.upper, chain.upper[variables])
    assert limb.effector_names == ("right_foot",)


@pytest.mark.parametrize("inner_first", [False, True])
def test_a_split_solve_answers_for_the_whole_chain(inner_first: bool) -> None:
    chain = biped()
    options = IKOptions(time_budget_us=None, inner_first=inner_first)
    solver = IKSolver(chain, options)
    rng = np.random.default_rng(5)
    for _ in range(10):
        goal = rng.uniform(chain.lower, chain.upper)
        r = solver.solve(pose_targets(chain, goal))
        assert r.status is IKStatus.SOLVED
        assert [e.name for e in r.effectors] == list(chain.effector_names)
        assert all(e.within_tolerance for e in r.effectors)
        # The errors reported are those of the answer, judged on the whole chain.
        again = solver.judge(r.q, pose_targets(chain, goal))
        np.testing.assert_allclose(
            [e.position_error_m for e in r.effectors],
            [e.position_error_m for e in again.effectors],
            rtol=1e-9,
            atol=1e-15,
        )
        # Each group's passes, one after another; the work is the groups' sum.
        assert len(r.pass_log) == r.passes >= 3
        assert sum(p.iterations for p in r.pass_log) == r.iterations


def test_variables_of_no_targeted_group_stay_at_the_seed() -> None:
    chain = biped()
    solver = IKSolver(chain)
    seed = chain.mid_limits() + 0.1
    goal = np.random.default_rng(2).uniform(chain.lower, chain.upper)
    feet = [t for t in pose_targets(chain, goal) if t.effector.endswith("_foot")]
    r = solver.solve(feet, seed=seed)
    assert r.success
    legs = np.array(
        [
            n.startswith(
                ("left_hip", "left_knee", "left_ankle", "right_hip", "right_knee", "right_ankle")
            )
            for n in chain.dof_names
        ]
    )
    np.testing.assert_array_equal(r.q[~legs], seed[~legs])
    assert not np.array_equal(r.q[legs], seed[legs])
    # Untargeted effectors are not reported.
    assert {e.name for e in r.effectors} == {"left_foot", "right_foot"}


def test_the_groups_share_the_budget() -> None:
    """With no time left the first group stops at once and the rest get nothing: the
    frame ends BUDGET_EXHAUSTED, as the whole solve would."""
    chain = biped()
    goal = np.random.default_rng(4).uniform(chain.lower, chain.upper)
    for split in (True, False):
        r = IKSolver(chain, IKOptions(time_budget_us=0.0, split_limbs=split)).solve(
            pose_targets(chain, goal)
        )
        assert r.status is IKStatus.BUDGET_EXHAUSTED, split


def test_split_limbs_off_solves_the_whole_tree_at_once() -> None:
    chain = biped()
    goal = np.random.default_rng(6).uniform(chain.lower, chain.upper)
    targets = pose_targets(chain, goal)
    split = IKSolver(chain, IKOptions(time_budget_us=None))
    whole = IKSolver(chain, IKOptions(time_budget_us=None, split_limbs=False))
    assert split.solve(targets).success and whole.solve(targets).success
    # Split: one solver per group's limb chain (each leg, the upper body), and with
    # the waist the head placed frozen, each arm's (waist and arm); whole: none.
    limbs = split._split._limbs.values()
    assert sorted(len(g.solver.chain.dof_names) for g in limbs) == [5, 5, 6, 6, 9]
    assert not whole._split._limbs


@pytest.mark.parametrize(
    ("targets", "message"),
    [
        (lambda t: [*t, t[0]], "two targets for effector 'head'"),
        (lambda t: [*t, dataclasses.replace(t[1], effector="nose")], "unknown effector 'nose'"),
    ],
)
def test_bad_target_sets_are_refused_as_before(targets: object, message: str) -> None:
    chain = biped()
    base = pose_targets(chain, chain.mid_limits())
    with pytest.raises(InvalidProblem, match=message):
        IKSolver(chain).solve(targets(base))  # type: ignore[operator]


def test_a_bad_target_in_a_later_group_names_its_effector() -> None:
    chain = biped()
    targets = pose_targets(chain, chain.mid_limits())
    i = chain.effector_index("right_foot")
    targets[i] = Target(effector="right_foot", position=[np.nan, 0.0, 0.0], rotation=np.eye(3))
    with pytest.raises(InvalidProblem, match="right_foot"):
        IKSolver(chain).solve(targets)


def test_time_outside_the_compiled_solves_is_not_budget() -> None:
    """The groups' budget is what the compiled solves used, as a whole solve counts
    its own: building a limb's solver (here made 10 ms slow; a first call in a
    process loads the compiled code) leaves the 5 ms of the next group intact."""
    chain = biped()
    solver = IKSolver(chain)

    def slow_solver(limb: Chain) -> IKSolver:
        time.sleep(0.01)
        return IKSolver(limb)

    solver._split._make_solver = slow_solver
    goal = np.random.default_rng(2).uniform(chain.lower, chain.upper)
    r = solver.solve(pose_targets(chain, goal))
    assert r.status is IKStatus.SOLVED
    assert r.solve_us < 5000.0


def test_a_placed_trunk_leaves_the_limbs_it_separates() -> None:
    for chain in (biped(), biped(neck=True)):
        split = IKSolver(chain)._split
        head, left, right = (chain.effector_index(n) for n in ("head", "left_hand", "right_hand"))
        # The head's target fixes the waist (3 rows for 1 variable; a pose for the
        # waist and the 2-joint neck): given it, the arms share nothing.
        assert split.limbs_given_trunk((head, left, right), (head,)) == [(left,), (right,)]
        # One limb left, under a trunk its targets fix: it is solved under it too.
        assert split.limbs_given_trunk((head, left), (head,)) == [(left,)]
        assert split.trunk_is_fixed((head,))
        # A left hand's position (3 rows) leaves its 5 variables a family of places.
        assert not split.trunk_is_fixed((left,))
    # The head's position on a bending waist and a 2-joint neck: 3 rows, 4 variables.
    loose = _head_position(biped(neck=True, bending_waist=True))
    split = IKSolver(loose)._split
    head, left, right = (loose.effector_index(n) for n in ("head", "left_hand", "right_hand"))
    assert split.inner((head, left, right)) == (head,)
    assert split.limbs_given_trunk((head, left, right), (head,)) == [(left,), (right,)]
    assert not split.trunk_is_fixed((head,))
    # One limb under a trunk its targets leave open: solved with the trunk free.
    assert split.limbs_given_trunk((head, left), (head,)) == []
    # Hand poses: 6 rows on 4 arm joints leave an arm no spare joint to make up for
    # the one direction the head's position leaves the trunk: no freezing there.
    stiff = build_chain(
        list(loose.joints),
        [
            dataclasses.replace(e, mode=EffectorMode.POSE) if e.name.endswith("_hand") else e
            for e in loose.effectors
        ],
    )
    assert IKSolver(stiff)._split.limbs_given_trunk((head, left, right), (head,)) == []


def test_solve_within_keeps_frozen_variables_at_the_seed() -> None:
    chain = biped()
    solver = IKSolver(chain, IKOptions(time_budget_us=None))
    goal = np.random.default_rng(8).uniform(chain.lower, chain.upper)
    hands = [t for t in pose_targets(chain, goal) if t.effector.endswith("_hand")]
    waist = np.array([name == "waist" for name in chain.dof_names])
    seed = chain.mid_limits()
    seed[waist] = goal[waist]
    r = solver.solve_within(hands, seed, solver.options, None, None, frozen=waist)
    assert r.success
    np.testing.assert_array_equal(r.q[waist], seed[waist])
    # Moved from elsewhere, the waist must move for the hands (their own arms
    # cannot reach): frozen there, they miss.
    seed[waist] = goal[waist] + 1.5
    frozen = solver.solve_within(hands, seed, solver.options, None, None, frozen=waist)
    free = solver.solve_within(hands, seed, solver.options, None, None)
    assert free.success and not np.array_equal(free.q[waist], seed[waist])
    assert not frozen.success
    np.testing.assert_array_equal(frozen.q[waist], seed[waist])


class _Recorder:
    """A limb's real solver whose calls are written down: (limb variables, targeted
    effectors, frozen variables, restarts allowed, solved, the answer by variable)."""

    def __init__(self, limb: Chain, calls: list[tuple[object, ...]]) -> None:
        self._solver = IKSolver(limb)
        self.chain = limb
        self._calls = calls

    def solve_within(self, targets, seed, options, rng, time_left_us, *, frozen=None):  # type: ignore[no-untyped-def]
        r = self._solver.solve_within(targets, seed, options, rng, time_left_us, frozen=frozen)
        frozen_names = (
            tuple(n for n, f in zip(self.chain.dof_names, frozen, strict=True) if f)
            if frozen is not None
            else ()
        )
        self._calls.append(
            (
                len(self.chain.dof_names),
                tuple(t.effector for t in targets),
                frozen_names,
                options.max_restarts,
                r.success,
                dict(zip(self.chain.dof_names, r.q.tolist(), strict=True)),
            )
        )
        return r


def test_the_trunk_is_placed_first_then_frozen_under_each_limb() -> None:
    chain = biped()
    solver, calls, upper = _recorded(chain)
    r = solver.solve(upper)
    assert r.success
    assert [c[:3] for c in calls] == [
        (9, ("head",), ()),  # the head alone places the waist
        (5, ("left_hand",), ("waist",)),
        (5, ("right_hand",), ("waist",)),
    ]
    # The answer keeps the waist where the head's solve put it (the arms' solves
    # could not move it), and the pass logs of the three solves, one after another.
    placed = calls[0][5]["waist"]  # type: ignore[index]
    assert r.q[chain.dof_names.index("waist")] == placed
    assert calls[1][5]["waist"] == calls[2][5]["waist"] == placed  # type: ignore[index]
    assert len(r.pass_log) == r.passes >= 3
    # The inverse Hessian: the waist's block from the head's solve, each arm's own
    # block from its solve, nothing between them; positive definite as a whole.
    h = r.inverse_hessian
    np.testing.assert_allclose(h, h.T, rtol=1e-12)
    assert np.linalg.eigvalsh(h).min() > 0.0
    arm = [i for i, name in enumerate(chain.dof_names) if name.startswith("left_")]
    np.testing.assert_array_equal(h[np.ix_(arm, [chain.dof_names.index("waist")])], 0.0)


def test_an_effector_only_the_trunk_moves_keeps_the_trunk_free() -> None:
    chain = biped()
    split = IKSolver(chain)._split
    head, left, right = (chain.effector_index(n) for n in ("head", "left_hand", "right_hand"))
    # With the left hand's variables (the waist among them) frozen, nothing would be
    # left to move the head.
    assert split.limbs_given_trunk((head, left, right), (left,)) == []


def test_a_limb_that_misses_under_the_placed_trunk_falls_back_to_the_whole_group() -> None:
    chain = biped()
    solver, calls, upper = _recorded(chain)
    far = _right_hand_out_of_reach(upper)
    r = solver.solve(far)
    assert r.status is IKStatus.NOT_REACHED
    everyone = ("head", "left_hand", "right_hand")
    assert [c[:5] for c in calls] == [
        (9, ("head",), (), 126, True),
        (5, ("left_hand",), ("waist",), 8, True),
        (5, ("right_hand",), ("waist",), 8, False),
        (9, everyone, (), 0, False),  # the trunk given back for one local solve
        (5, ("right_hand",), ("waist",), 24, False),  # the limb's own further restarts
        (9, everyone, (), 126, False),  # the whole group, as without the split
    ]
    assert not {e.name: e for e in r.effectors}["right_hand"].within_tolerance


def test_under_a_trunk_its_targets_leave_open_a_missed_limb_goes_to_the_whole_group() -> None:
    """No further restarts of the limb alone: the trunk is the likely cause."""
    chain = _head_position(biped(neck=True, bending_waist=True))
    solver, calls, upper = _recorded(chain)
    far = _right_hand_out_of_reach(upper)
    assert solver.solve(far).status is IKStatus.NOT_REACHED
    everyone = ("head", "left_hand", "right_hand")
    trunk = ("waist.z", "waist.y")  # an arm's limb holds the waist, not the neck
    assert [c[:5] for c in calls] == [
        (12, ("head",), (), 126, True),
        (6, ("left_hand",), trunk, 4, True),
        (6, ("right_hand",), trunk, 4, False),
        (12, everyone, (), 0, False),
        (12, everyone, (), 126, False),
    ]
    # Reachable, the limbs solve under the trunk the head's solve placed.
    calls.clear()
    assert solver.solve(upper).success
    assert [c[:3] for c in calls[1:3]] == [
        (6, ("left_hand",), trunk),
        (6, ("right_hand",), trunk),
    ]


def _recorded(chain: Chain) -> tuple[IKSolver, list[tuple[object, ...]], list[Target]]:
    """A solver whose limbs' calls are recorded, and head and hand targets of a pose."""
    solver = IKSolver(chain, IKOptions(time_budget_us=None))
    calls: list[tuple[object, ...]] = []
    solver._split._make_solver = lambda limb: _Recorder(limb, calls)
    goal = np.random.default_rng(6).uniform(chain.lower, chain.upper)
    upper = [t for t in pose_targets(chain, goal) if not t.effector.endswith("_foot")]
    return solver, calls, upper


def _right_hand_out_of_reach(upper: list[Target]) -> list[Target]:
    head, left, right = upper
    return [head, left, dataclasses.replace(right, position=np.array([3.0, 0.0, 0.0]))]


def _head_position(chain: Chain) -> Chain:
    """The chain with its head as a position effector."""
    effectors = [
        dataclasses.replace(e, mode=EffectorMode.POSITION) if e.name == "head" else e
        for e in chain.effectors
    ]
    return build_chain(list(chain.joints), effectors)
