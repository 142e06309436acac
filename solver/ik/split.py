"""A frame whose effectors fall into groups that share no free variable, solved one
group at a time (``IKSolver.solve``; ``IKOptions.split_limbs``).

The IK objective is a sum of one term per targeted effector, each a function of the
variables on that effector's path to the root, plus terms of one variable each
(posture, limits): where the targeted effectors form groups whose paths share no
free variable (a humanoid whose pelvis is the base: each leg, and the torso with
the arms and head), it is a sum of functions of disjoint sets of variables, and
their minimisations are independent problems. Solved as one, every iteration pays
for forward kinematics, the metric and the BFGS update of the whole tree, and
every random restart re-enters a pass of the whole tree for one group's miss.
Solved apart (each group on its limb's own chain, ``model.limbs.limb_chain``, with
its own restarts), a leg iterates at a leg's cost and restarts alone. On the URDF
sweep's g1 (29 variables, 9 effectors: two legs and a torso with arms, 3 groups)
the median solve fell from ~1.2 ms to ~0.3 ms at the same iterations
(bench/history/2026-11-28-limb-split.md).

Within a group, the effectors that place its trunk go first (``inner``); where
their targets fix the variables they move, the trunk stays there and the group's
other effectors split again into the groups that leaves (``limbs_given_trunk``:
tiago_pro's and PR2's two arms given the torso lift and head that the head markers
placed; g1's arms given the waist its torso markers placed), each on its own limb
with the trunk frozen, and the whole group is the fallback (``_solve_parts``).

The groups share the frame's time budget: each gets what the ones before it left
(their time inside the compiled solve, as a whole solve counts its own).
The result is the whole chain's: its q (variables in no group at the seed, as a
whole solve freezes them), each effector's errors, the work summed, the status of
the first group that failed (else SOLVED), the groups' inverse Hessians as the
blocks of one, and their pass logs one after another.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np

from ..arrays import Vector
from ..model import Chain, EffectorMode
from ..model.limbs import limb_chain
from ..optim import Termination
from .options import IKOptions
from .result import IKResult, IKStatus, ResultLayout
from .targets import Target


class GroupSolver(Protocol):
    """What ``LimbSplit`` needs of a limb's solver (an ``IKSolver``: passed in, so
    that this module does not import the solver that uses it)."""

    chain: Chain

    def solve_within(
        self,
        targets: Sequence[Target],
        seed: Vector,
        options: IKOptions,
        rng: np.random.Generator | None,
        time_left_us: float | None,
        *,
        frozen: np.ndarray | None = None,
    ) -> IKResult: ...


# Restarts of a part solved with its trunk frozen (``LimbSplit._solve_parts``): under
# a trunk its targets fix, FIRST before the whole group is tried from there with
# none, MORE after; under one they do not fix, LOOSE before the same, and then the
# whole group (the trunk is the likely cause). Interleaved A/Bs of 600 targets
# (bench/history/2026-11-29-freeze-trunk.md): the human's hands and head within 5 ms
# 98.8% with 8, 99.2% with 2, 99.5% with 4 loose restarts.
FIRST_PART_RESTARTS = 8
MORE_PART_RESTARTS = 24
LOOSE_PART_RESTARTS = 4

# The rows of an effector's target: a position's 3, a pose's 6, an aim's 3 + 2.
TASK_ROWS = {EffectorMode.POSITION: 3, EffectorMode.POSE: 6, EffectorMode.AIM: 5}


def _pulls(target: Target, rotation_rows: int) -> bool:
    """Whether a target has a part with weight above 0 (a position effector's rotation
    weight has no rows to weigh)."""
    position = target.position is not None and target.position_weight > 0.0
    return position or (rotation_rows > 0 and target.rotation_weight > 0.0)


@dataclass(frozen=True, slots=True)
class LimbGroup:
    """One group of effectors and the solver of its limb chain."""

    solver: GroupSolver
    variables: np.ndarray  # the limb's variables' indexes in the whole q
    effectors: np.ndarray  # the limb's effectors' indexes in the whole chain


class LimbSplit:
    """Finds a frame's independent groups of effectors and solves them one by one."""

    def __init__(self, chain: Chain, make_solver: Callable[[Chain], GroupSolver]) -> None:
        self._chain = chain
        self._make_solver = make_solver
        movable = chain.lower < chain.upper
        # Each effector's free variables as a bit set: two effectors interact only
        # through a variable both can move (a locked joint moves neither).
        self._masks = tuple(
            sum(1 << int(d) for d in dofs if movable[d]) for dofs in chain.compiled.eff_dofs
        )
        self._slot = {name: i for i, name in enumerate(chain.effector_names)}
        self._rows = tuple(TASK_ROWS[e.mode] for e in chain.effectors)
        self._limbs: dict[tuple[int, ...], LimbGroup] = {}
        self._variants_of: dict[bool, tuple[IKOptions, tuple[IKOptions, IKOptions, IKOptions]]] = {}

    def groups(self, targets: Sequence[Target]) -> list[tuple[int, ...]] | None:
        """The targeted effectors' indexes in groups that share no free variable (None
        for fewer than two targets, for targets the whole solve must refuse: an
        unknown effector or two targets for one, whose errors it words, and for a
        target that pulls nothing, every part at weight 0: the whole solve holds its
        limb, as ``Task.pulling`` says, where a group here would place the trunk by
        it)."""
        if len(targets) < 2:
            return None
        groups: list[tuple[int, list[int]]] = []  # (variables as bits, effectors)
        seen: set[int] = set()
        for t in targets:
            i = self._slot.get(t.effector, -1)
            if i < 0 or i in seen:
                return None
            if not t.plain and not _pulls(t, self._rows[i] - 3):
                return None
            seen.add(i)
            groups = _joined(groups, self._masks[i], i)
        return sorted(tuple(sorted(members)) for _, members in groups)

    def inner(self, group: tuple[int, ...]) -> tuple[int, ...]:
        """The effectors of a group that place its trunk, which ``solve`` takes first.

        The trunk is the variables that move every effector of the group (a torso, a
        lift column). An effector with fewer variables beyond the trunk than its
        target has rows cannot meet its target unless the trunk moves for it: its
        target places the trunk (a humanoid's torso markers; a head's pose on a
        2-joint neck; a head's two position markers on pan and tilt). One whose own
        limb can meet it (a hand behind a 7-joint arm) comes second. They are taken
        nearest the trunk first (fewest variables beyond it), as long as together
        they move at most half of the group's variables: the first stage must stay
        a small problem, or it is nearly the whole solve twice (Baxter's arm, whose
        visual frames and cameras all qualify and move 7 of its 8 variables: 1.8%
        of 600 targets past 5 ms with all of them first, none without). If every
        effector would be first, or none, there is nothing to take first.
        """
        masks = self._masks
        trunk = -1
        every = 0
        for i in group:
            trunk &= masks[i]
            every |= masks[i]
        beyond = {i: (masks[i] & ~trunk).bit_count() for i in group}
        candidates = sorted((i for i in group if beyond[i] < self._rows[i]), key=beyond.__getitem__)
        inner: list[int] = []
        moved = 0
        for k, i in enumerate(candidates):
            moved |= masks[i]
            last_of_its_depth = k + 1 == len(candidates) or beyond[candidates[k + 1]] > beyond[i]
            if 2 * moved.bit_count() > every.bit_count():
                break
            if last_of_its_depth:
                inner = candidates[: k + 1]
        if len(inner) == len(group):
            return ()
        return tuple(sorted(inner))

    def solve(
        self,
        groups: list[tuple[int, ...]],
        targets: Sequence[Target],
        q0: Vector,
        opts: IKOptions,
        rng: np.random.Generator | None,
        layout: ResultLayout,
        out_size: int,
    ) -> IKResult:
        """Each group's solve from q0 in turn, as one result of the whole chain."""
        n, m = layout.n_dof, layout.n_effectors
        run = _Run(
            {t.effector: t for t in targets},
            opts,
            rng,
            np.clip(q0, self._chain.lower, self._chain.upper),
            np.empty(out_size),
            layout.log_start,
        )
        run.errors(m)[:] = (math.nan, math.nan, 0.0)
        run.hessian(n, m)[:] = np.eye(n)
        failed: IKResult | None = None
        last: IKResult | None = None
        for group in groups:
            r = self._solve_group(group, run, n, m)
            last = r
            if failed is None and not r.success:
                failed = r
        decisive = failed or last
        assert decisive is not None
        work = run.work
        return IKResult(
            run.q,
            decisive.status if failed else IKStatus.SOLVED,
            decisive.termination if failed else Termination.GOAL_REACHED,
            int(work[0]),
            int(work[1]),
            int(work[2]),
            int(work[3]),
            float(work[4]),
            run.out,
            layout,
        )

    def _solve_group(self, group: tuple[int, ...], run: _Run, n: int, m: int) -> IKResult:
        """One group: its trunk effectors first (``inner``), then with the trunk they
        placed frozen, the rest in the groups that leaves (``limbs_given_trunk``);
        the whole group from there if that split does not apply or a part fails."""
        limb = self._limb(group)
        inner = self.inner(group) if run.opts.inner_first else ()
        if inner:
            r = run.solve(limb, [i for i in group if i in inner], None)
            run.q[limb.variables] = r.q
            if r.success and run.opts.freeze_trunk:
                parts = self.limbs_given_trunk(group, inner)
                if parts:
                    solved = self._solve_parts(limb, group, inner, parts, r, run, n, m)
                    if solved is not None:
                        return solved
        r = run.solve(limb, list(group), None)
        run.keep(limb, r, n, m)
        return r

    def limbs_given_trunk(
        self, group: tuple[int, ...], inner: tuple[int, ...]
    ) -> list[tuple[int, ...]]:
        """The group's other effectors in groups that share no variable once the inner
        effectors' variables are frozen (tiago_pro's and PR2's two arms, given the
        torso lift the head markers placed). Under a trunk its targets fix, one such
        group too: the rest of the limb then moves without undoing the trunk
        (Baxter's arm, its elbow and upper forearm frames placing the first four
        of its joints: 99.5% -> 100% of 600 targets within 5 ms, p99 4.4 -> 2.4
        ms); under one they leave open, [] for fewer than two.

        Also [] where the inner targets leave the trunk more directions open (its
        variables minus their rows) than some part has spare joints of its own (its
        variables beyond the trunk minus its rows): frozen at one place of that
        family, the part could not make up for the choice. Tiago's thumb pose
        leaves 7 of the torso's, arm's and thumb's 13 variables open, and each other
        finger has 1 spare joint: frozen there, nearly every finger missed (median
        solve 0.3 -> 1.3 ms); the human's head pose leaves 2 of the spine's and
        neck's 8 open, and each arm has 2 spare joints.
        """
        trunk = self._trunk_bits(inner)
        parts: list[tuple[int, list[int]]] = []
        for i in group:
            if i in inner:
                continue
            parts = _joined(parts, self._masks[i] & ~trunk, i)
        if not parts or (len(parts) < 2 and not self.trunk_is_fixed(inner)):
            return []
        if any(mask == 0 for mask, _ in parts):  # moved by the trunk alone: it must move
            return []
        open_directions = trunk.bit_count() - sum(self._rows[i] for i in inner)
        spare = min(mask.bit_count() - sum(self._rows[i] for i in m) for mask, m in parts)
        if open_directions > max(spare, 0):
            return []
        return sorted(tuple(sorted(members)) for _, members in parts)

    def trunk_is_fixed(self, inner: tuple[int, ...]) -> bool:
        """Do the inner targets have as many rows as the variables they move? Then
        they fix the trunk (up to a few discrete choices); with fewer (the human's
        head pose on a 5-joint spine and a 3-joint neck) they leave it a family of
        places, and the one the inner stage found is one of many."""
        return sum(self._rows[i] for i in inner) >= self._trunk_bits(inner).bit_count()

    def _trunk_bits(self, inner: tuple[int, ...]) -> int:
        trunk = 0
        for i in inner:
            trunk |= self._masks[i]
        return trunk

    def _solve_parts(
        self,
        limb: LimbGroup,
        group: tuple[int, ...],
        inner: tuple[int, ...],
        parts: list[tuple[int, ...]],
        placed: IKResult,
        run: _Run,
        n: int,
        m: int,
    ) -> IKResult | None:
        """The parts of a group on their own limbs, its trunk frozen where the inner
        stage (``placed``) left it; None if one misses (the whole group then goes on
        from where they left it).

        A part that misses in its first few restarts has one of two causes. The
        trunk may be off: one place of a family the inner targets leave open (the
        human's spine under its head), or where they fix it, met within their
        tolerance but just off for a part with more target rows than joints (PR2's
        arm under eight frames). The whole group from there, with the trunk free and
        no restart, then mostly solves at once (PR2: in 40-110 us, where frozen parts
        ran out of 32 restarts each; the human: 171 of 189 parts that missed). Or,
        under a trunk its targets fix, the part is a hard problem of its own
        (tiago_pro's arm under four finger poses): it restarts on its own limb
        (``MORE_PART_RESTARTS``), cheaper than restarts of the whole group (~0.1 ms
        against ~0.5 ms).
        """
        trunk = np.zeros(self._chain.n_dof, dtype=bool)
        for i in inner:
            trunk[self._chain.compiled.eff_dofs[i]] = True
        fixed = self.trunk_is_fixed(inner)
        first, more, local = self._variants(run.opts, fixed)
        solved: dict[tuple[int, ...], tuple[LimbGroup, IKResult]] = {}
        missed: list[tuple[int, ...]] = []
        for part in parts:
            sub = self._limb(part)
            r = run.solve(sub, list(part), trunk[sub.variables], first)
            run.q[sub.variables] = r.q  # kept when it misses: the nearest it came
            if r.success:
                solved[part] = (sub, r)
            else:
                missed.append(part)
        if missed:
            before = run.q[limb.variables].copy()
            r = run.solve(limb, list(group), None, local)
            if r.success:
                run.keep(limb, r, n, m)
                return r
            if not fixed or run.opts.max_restarts <= FIRST_PART_RESTARTS:
                return None  # (or the first try had every restart the options allow)
            run.q[limb.variables] = before
            for part in missed:
                sub = self._limb(part)
                r = run.solve(sub, list(part), trunk[sub.variables], more)
                run.q[sub.variables] = r.q
                if not r.success:
                    return None
                solved[part] = (sub, r)
        # The inner effectors' errors and the trunk, then each part's own.
        run.keep(limb, placed, n, m, moved=trunk[limb.variables])
        for sub, r in solved.values():
            run.keep(sub, r, n, m, moved=~trunk[sub.variables])
        return placed

    def _variants(self, opts: IKOptions, fixed: bool) -> tuple[IKOptions, IKOptions, IKOptions]:
        """``opts`` with a part's first and further restarts under a trunk its targets
        fix or not, and with none; one object each (a solver packs its options once
        per object)."""
        hit = self._variants_of.get(fixed)
        if hit is None or hit[0] is not opts:
            restarts = (
                FIRST_PART_RESTARTS if fixed else LOOSE_PART_RESTARTS,
                MORE_PART_RESTARTS,
                0,
            )
            first, more, local = (
                replace(opts, max_restarts=min(opts.max_restarts, k)) for k in restarts
            )
            hit = self._variants_of[fixed] = (opts, (first, more, local))
        return hit[1]

    def _limb(self, group: tuple[int, ...]) -> LimbGroup:
        limb = self._limbs.get(group)
        if limb is None:
            if len(self._limbs) >= _MAX_GROUPS:  # targets on ever new effector sets
                self._limbs.clear()
            chain, variables = _limb_chain(self._chain, group)
            limb = LimbGroup(self._make_solver(chain), variables, np.array(group, dtype=np.int64))
            self._limbs[group] = limb
        return limb


def _joined(
    groups: list[tuple[int, list[int]]], mask: int, effector: int
) -> list[tuple[int, list[int]]]:
    """``groups`` (variables as bits, effectors) with ``effector``, which moves the
    variables of ``mask``, joined to every group it shares one with."""
    members = [effector]
    rest = []
    for g in groups:
        if g[0] & mask:
            mask |= g[0]
            members += g[1]
        else:
            rest.append(g)
    return [*rest, (mask, members)]


class _Run:
    """A split frame's running state: the whole q, the result's array, the work and
    the budget the groups share."""

    def __init__(
        self,
        by_effector: dict[str, Target],
        opts: IKOptions,
        rng: np.random.Generator | None,
        q: Vector,
        out: np.ndarray,
        log_start: int,
    ) -> None:
        self.by_effector = by_effector
        self.opts = opts
        self.rng = rng
        self.q = q
        self.out = out
        self.log = out[log_start:]
        self.logged = 0
        self.work = np.zeros(5)  # iterations, evaluations, passes, restarts, solve time

    def errors(self, m: int) -> np.ndarray:
        return self.out[: 3 * m].reshape(m, 3)

    def hessian(self, n: int, m: int) -> np.ndarray:
        return self.out[3 * m : 3 * m + n * n].reshape(n, n)

    def solve(
        self,
        limb: LimbGroup,
        effectors: list[int],
        frozen: np.ndarray | None,
        opts: IKOptions | None = None,
    ) -> IKResult:
        """The targets of ``effectors`` (whole-chain indexes) on ``limb`` from the
        current q, in what the budget has left; its work and pass log counted."""
        names = limb.solver.chain.effectors
        index = {int(e): k for k, e in enumerate(limb.effectors)}
        targets = [self.by_effector[names[index[i]].name] for i in effectors]
        budget = self.opts.time_budget_us
        # The budget is counted inside the compiled solves, as a whole solve's is: the
        # Python between them (and a first call's loading) is not.
        left = None if budget is None else budget - self.work[4]
        r = limb.solver.solve_within(
            targets, self.q[limb.variables], opts or self.opts, self.rng, left, frozen=frozen
        )
        rows = r.raw_pass_log[: r.passes].reshape(-1)[: self.log.shape[0] - self.logged]
        self.log[self.logged : self.logged + rows.shape[0]] = rows
        self.logged += rows.shape[0]
        self.work += (r.iterations, r.function_evals, r.passes, r.restarts, r.solve_us)
        return r

    def keep(
        self, limb: LimbGroup, r: IKResult, n: int, m: int, moved: np.ndarray | None = None
    ) -> None:
        """``r`` as the answer of ``limb``'s variables and targeted effectors; of the
        inverse Hessian, the block of the variables ``moved`` marks (default all).
        Under a frozen trunk, the trunk's block comes from the solve that placed it
        and each part's from its own solve, with nothing between them (as between
        groups): a solve's rows for variables it could not move are not curvature,
        and mixed in they made the whole matrix indefinite."""
        self.q[limb.variables] = r.q
        targeted = r.raw_errors[:, 2] != 0.0
        self.errors(m)[limb.effectors[targeted]] = r.raw_errors[targeted]
        own = np.arange(limb.variables.shape[0]) if moved is None else np.flatnonzero(moved)
        variables = limb.variables[own]
        self.hessian(n, m)[np.ix_(variables, variables)] = r.inverse_hessian[np.ix_(own, own)]


# Limb chains built so far, by whole chain and group: building one is ~1 ms for a
# humanoid's limb (validation, compiled arrays), and the service's stateless solve
# builds a new IKSolver for each request on the same chain object.
_LIMB_CHAINS: OrderedDict[tuple[int, tuple[int, ...]], tuple[Chain, Chain, np.ndarray]] = (
    OrderedDict()
)
_LIMB_CHAINS_LOCK = threading.Lock()
_MAX_GROUPS = 64


def _limb_chain(chain: Chain, group: tuple[int, ...]) -> tuple[Chain, np.ndarray]:
    key = (id(chain), group)
    with _LIMB_CHAINS_LOCK:
        hit = _LIMB_CHAINS.get(key)
        if hit is not None and hit[0] is chain:  # the entry holds chain: its id is its own
            _LIMB_CHAINS.move_to_end(key)
            return hit[1], hit[2]
    limb, variables = limb_chain(chain, group)
    with _LIMB_CHAINS_LOCK:
        _LIMB_CHAINS[key] = (chain, limb, variables)
        while len(_LIMB_CHAINS) > 4 * _MAX_GROUPS:
            _LIMB_CHAINS.popitem(last=False)
    return limb, variables
