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
from dataclasses import dataclass
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
    ) -> IKResult: ...


# The rows of an effector's target: a position's 3, a pose's 6, an aim's 3 + 2.
TASK_ROWS = {EffectorMode.POSITION: 3, EffectorMode.POSE: 6, EffectorMode.AIM: 5}


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

    def groups(self, targets: Sequence[Target]) -> list[tuple[int, ...]] | None:
        """The targeted effectors' indexes in groups that share no free variable (None
        for fewer than two targets, and for targets the whole solve must refuse: an
        unknown effector or two targets for one, whose errors it words)."""
        if len(targets) < 2:
            return None
        groups: list[tuple[int, list[int]]] = []  # (variables as bits, effectors)
        seen: set[int] = set()
        for t in targets:
            i = self._slot.get(t.effector, -1)
            if i < 0 or i in seen:
                return None
            seen.add(i)
            mask, members = self._masks[i], [i]
            rest = []
            for g in groups:
                if g[0] & mask:
                    mask |= g[0]
                    members += g[1]
                else:
                    rest.append(g)
            groups = [*rest, (mask, members)]
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
        by_effector = {t.effector: t for t in targets}
        q = np.clip(q0, self._chain.lower, self._chain.upper)
        n, m = layout.n_dof, layout.n_effectors
        out = np.empty(out_size)
        errors = out[: 3 * m].reshape(m, 3)
        errors[:] = (math.nan, math.nan, 0.0)
        h = out[3 * m : 3 * m + n * n].reshape(n, n)
        h[:] = np.eye(n)
        log = out[layout.log_start :]
        logged = 0
        failed: IKResult | None = None
        last: IKResult | None = None
        work = np.zeros(5)  # iterations, evaluations, passes, restarts, solve time
        budget = opts.time_budget_us
        for group in groups:
            limb = self._limb(group)
            mine = [by_effector[limb.solver.chain.effectors[k].name] for k in range(len(group))]
            seed = q0[limb.variables]
            stages = [mine]
            if opts.inner_first:
                inner = set(self.inner(group))
                if inner:
                    stages.insert(0, [t for t, i in zip(mine, group, strict=True) if i in inner])
            for stage in stages:
                # The budget is counted inside the compiled solves, as a whole solve's
                # is: the Python between them (and a first call's loading) is not.
                left = None if budget is None else budget - work[4]
                r = limb.solver.solve_within(stage, seed, opts, rng, left)
                seed = r.q
                rows = r.raw_pass_log[: r.passes].reshape(-1)[: log.shape[0] - logged]
                log[logged : logged + rows.shape[0]] = rows
                logged += rows.shape[0]
                work += (r.iterations, r.function_evals, r.passes, r.restarts, r.solve_us)
            q[limb.variables] = r.q
            errors[limb.effectors] = r.raw_errors
            h[np.ix_(limb.variables, limb.variables)] = r.inverse_hessian
            last = r
            if failed is None and not r.success:
                failed = r
        decisive = failed or last
        assert decisive is not None
        return IKResult(
            q,
            decisive.status if failed else IKStatus.SOLVED,
            decisive.termination if failed else Termination.GOAL_REACHED,
            int(work[0]),
            int(work[1]),
            int(work[2]),
            int(work[3]),
            float(work[4]),
            out,
            layout,
        )

    def _limb(self, group: tuple[int, ...]) -> LimbGroup:
        limb = self._limbs.get(group)
        if limb is None:
            if len(self._limbs) >= _MAX_GROUPS:  # targets on ever new effector sets
                self._limbs.clear()
            chain, variables = _limb_chain(self._chain, group)
            limb = LimbGroup(self._make_solver(chain), variables, np.array(group, dtype=np.int64))
            self._limbs[group] = limb
        return limb


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
