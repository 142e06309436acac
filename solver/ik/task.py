"""The targets loaded into a solver's compiled arrays, and what they leave free.

A ``Task`` belongs to one ``IKSolver`` and writes into its arrays: the active flags
(EI), the target rows and tolerances (ED) and the frame's bounds (DD). It keeps what
the last frame loaded, so that a stream's usual frame (one target for the effector
of the frame before) costs one row copy.

Blend weights (``Target.position_weight`` / ``rotation_weight``) enter here: a part's
weight multiplies the model's weight in ED (so 0 takes its rows out of the objective
and the metric), and a part at weight 0 gets an infinite tolerance, so the goal measure
(max error / tolerance) never counts it. An effector whose every part weighs 0 pulls
nothing, so it frees nothing either: its limb is held at the frame's start pose unless
another target moves it, as if the target were left out (``pulling``), and it is still
listed, with no error, in the result. Parts strictly between 0 and 1 ("soft") keep
their tolerance until ``relax_soft_parts`` (``blend.solve_blended``: first the optimizer
aims at them, then only full-weight parts decide success); their targets are moved
towards the frame's start pose by ``blend.blend_rows`` (it needs the seed). Poles are
kept for ``poles``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..arrays import Vector
from ..errors import InvalidProblem
from ..model import Chain, EffectorMode
from ..model.layout import ED_TDIR, ED_TOL_P, ED_TOL_R, ED_TPOS, ED_WP, ED_WR, EI_ACTIVE
from .kinematics import DD_HI, DD_LO
from .options import IKOptions
from .targets import (
    GIVEN_DIRECTION,
    GIVEN_POSITION,
    GIVEN_ROTATION,
    TARGET_PLACEHOLDER_ROW,
    TARGET_ROW,
    Pole,
    Target,
    TargetRows,
)

# What a target must give for each effector mode.
NEEDS = {
    EffectorMode.POSITION: GIVEN_POSITION,
    EffectorMode.POSE: GIVEN_ROTATION,
    EffectorMode.AIM: GIVEN_DIRECTION,
}
# Task rows a mode adds to a targeted position's three (an aim fixes a direction: two).
MODE_ROWS = {EffectorMode.POSITION: 0, EffectorMode.POSE: 3, EffectorMode.AIM: 2}


class Task:
    """Loads targets into ``ei``, ``ed`` and bounds into ``dd`` (one solver's arrays).

    Attributes read by the solver on every frame: ``active`` (effector indexes with a
    target), ``redundant`` (more free joints than target rows), ``bounds_are_limits``
    and ``every_effector_moves_all`` (when both hold, the bounds need no update),
    ``blended`` (effector index, position weight, rotation weight, GIVEN_* bits) for
    each target with a part strictly between 0 and 1, ``poles`` (effector index, Pole),
    ``target_rows`` (one packed row per effector, views of ED).
    """

    def __init__(self, chain: Chain, ei: np.ndarray, ed: np.ndarray, dd: np.ndarray) -> None:
        cc = chain.compiled
        n = chain.n_dof
        self.chain = chain
        self._n = n
        self._ei = ei
        self._ed = ed
        self._dd = dd
        self._chain_dofs = cc.eff_dofs
        # One row per effector: what a Target's ``packed`` row is copied into.
        self.target_rows = ed[:, ED_TPOS : ED_TDIR + 3]
        assert self.target_rows.shape[1] == TARGET_ROW
        self.target_rows[:] = TARGET_PLACEHOLDER_ROW
        assert np.shares_memory(self.target_rows, ed)
        self._effector_names = chain.effector_names
        self._effector_slot = {name: i for i, name in enumerate(self._effector_names)}
        self._needs = tuple(NEEDS[e.mode] for e in chain.effectors)
        # Rows each effector's orientation part adds, for the redundancy test (a part
        # whose weight in ED is zero, in the model or this frame, constrains nothing).
        static = cc.ed
        self._mode_rows = tuple(MODE_ROWS[e.mode] for e in chain.effectors)
        self._movable = chain.lower < chain.upper  # a joint with lower == upper is locked
        self.redundant = True  # more free joints than target rows (set per target set)
        self._static_position_weights = static[:, ED_WP].copy()
        self._static_rotation_weights = static[:, ED_WR].copy()
        self.active: list[int] = []
        # The active effectors with a part that weighs more than 0: the joints of their
        # chains are the frame's free variables (``set_free_bounds``).
        self.pulling: list[int] = []
        # Effectors whose ED weights or tolerances this frame changed (restored next load).
        self._touched: list[int] = []
        self.blended: list[tuple[int, float, float, int]] = []
        self.poles: list[tuple[int, Pole]] = []
        self._tol_for: IKOptions | None = None
        self.bounds_are_limits = True
        self.every_effector_moves_all = all(d.shape[0] == n for d in cc.eff_dofs)

    def load(self, targets: Sequence[Target], opts: IKOptions) -> None:
        """Copy targets into the compiled arrays (shapes were checked by Target, values
        are checked in compiled code)."""
        if self._tol_for is not opts:
            self._ed[:, ED_TOL_P] = opts.position_tolerance_m
            self._ed[:, ED_TOL_R] = opts.rotation_tolerance_rad
            self._tol_for = opts
        active = self.active
        if type(targets) is TargetRows:
            # Rows packed by the caller (plain targets): the stream's usual frame copies
            # its row without building a Target; any other frame reads them as Targets.
            if len(active) == 1 and not self._touched and not self.poles:
                i = active[0]
                need = self._needs[i]
                given = targets.given
                if (
                    len(given) == 1
                    and given[0] & need == need
                    and given[0] & GIVEN_POSITION
                    and targets.effectors[0] == self._effector_names[i]
                ):
                    self.target_rows[i] = targets.rows[0]
                    return
        elif len(targets) == 1 and len(active) == 1 and not self._touched and not self.poles:
            # A stream's usual frame: one target for the effector of the last frame.
            t = targets[0]
            i = active[0]
            need = self._needs[i]
            if (
                t.effector == self._effector_names[i]
                and t.given & need == need
                and t.given & GIVEN_POSITION
                and t.plain
            ):
                self.target_rows[i] = t.packed
                return
        ei = self._ei
        ed = self._ed
        for i in active:
            ei[i, EI_ACTIVE] = 0
        for i in self._touched:
            ed[i, ED_WP] = self._static_position_weights[i]
            ed[i, ED_WR] = self._static_rotation_weights[i]
            ed[i, ED_TOL_P] = opts.position_tolerance_m
            ed[i, ED_TOL_R] = opts.rotation_tolerance_rad
        self.active = active = []
        self.pulling = pulling = []
        self._touched = []
        self.blended = []
        self.poles = []
        try:
            for t in targets:
                i = self._effector_slot.get(t.effector, -1)
                if i < 0:
                    self.chain.effector_index(t.effector)  # raises with the list of names
                if ei[i, EI_ACTIVE]:
                    raise InvalidProblem(f"two targets for effector {t.effector!r}")
                need = self._needs[i]
                if t.given & need != need:
                    part = {GIVEN_POSITION: "a position", GIVEN_ROTATION: "a rotation"}.get(
                        need, "a direction"
                    )
                    mode = self.chain.effectors[i].mode.value
                    raise InvalidProblem(f"target for {t.effector!r} ({mode}) needs {part}")
                if not (t.plain and t.given & GIVEN_POSITION):
                    self._weigh(i, t)
                self.target_rows[i] = t.packed
                ei[i, EI_ACTIVE] = 1
                active.append(i)
                if self._rows(i) > 0:
                    pulling.append(i)
        finally:
            # Also when a target is rejected: the effectors loaded before it stay active,
            # and the next frame's fast path keeps this answer.
            self.redundant = self.free_directions() > 0

    def _weigh(self, i: int, t: Target) -> None:
        """Effector i's ED weights and tolerances for target t's weights (a part not
        given weighs 0 and keeps its tolerance); remembers what to blend and poles."""
        ed = self._ed
        wp = t.position_weight
        wr = t.rotation_weight
        ed[i, ED_WP] = self._static_position_weights[i] * (wp if t.given & GIVEN_POSITION else 0.0)
        ed[i, ED_WR] = self._static_rotation_weights[i] * wr
        if wp == 0.0:
            ed[i, ED_TOL_P] = math.inf  # a free part is never judged
        if wr == 0.0:
            ed[i, ED_TOL_R] = math.inf
        self._touched.append(i)
        # Soft parts, among those the target gives (a rotation weight on a position
        # target, say, has nothing to blend): their weights, 1.0 for the others.
        soft_p = wp if 0.0 < wp < 1.0 and t.given & GIVEN_POSITION else 1.0
        soft_r = wr if 0.0 < wr < 1.0 and t.given & (GIVEN_ROTATION | GIVEN_DIRECTION) else 1.0
        if soft_p < 1.0 or soft_r < 1.0:
            self.blended.append((i, soft_p, soft_r, t.given))
        if t.pole is not None and self._rows(i) > 0:  # a held limb has nothing to bend
            self.poles.append((i, t.pole))

    def relax_soft_parts(self) -> None:
        """Infinite tolerances for the soft parts (weight strictly between 0 and 1) of
        the loaded targets: from now on they pull but are never judged."""
        ed = self._ed
        for i, wp, wr, _ in self.blended:
            if wp < 1.0:
                ed[i, ED_TOL_P] = math.inf
            if wr < 1.0:
                ed[i, ED_TOL_R] = math.inf

    def free_mask(self) -> np.ndarray:
        """1.0 for each variable the loaded targets may move: unlocked, and in the
        chain of a targeted effector that pulls (``pulling``); else 0.0."""
        if not self.active or (self.every_effector_moves_all and self.pulling):
            reach = self._movable
        else:
            reach = np.zeros(self._n, dtype=bool)
            for i in self.pulling:
                reach[self._chain_dofs[i]] = True
            reach &= self._movable
        return reach.astype(np.float64)

    def free_directions(self) -> int:
        """Free (unlocked) joints of the pulling effectors minus their target rows: the
        dimension of the self-motion where the Jacobian has full rank (a 7-DOF arm
        under a 6-D pose: 1; <= 0: no self-motion)."""
        active = self.active
        rows = sum(self._rows(i) for i in active)
        pulling = self.pulling
        if not active or (self.every_effector_moves_all and pulling):
            free = int(self._movable.sum())
        elif not pulling:
            free = 0
        else:
            dofs = np.unique(np.concatenate([self._chain_dofs[i] for i in pulling]))
            free = int(self._movable[dofs].sum())
        return free - rows

    def _rows(self, i: int) -> int:
        """The rows effector i's loaded target adds to the task (a part whose weight in
        ED is zero, in the model or this frame, adds none; a position effector has no
        orientation rows whatever its rotation weight)."""
        ed = self._ed
        return (self._mode_rows[i] if ed[i, ED_WR] > 0.0 else 0) + (3 if ed[i, ED_WP] > 0.0 else 0)

    def set_free_bounds(self, q0: Vector, frozen: np.ndarray | None = None) -> None:
        """Limits for this frame (DD rows): variables outside every pulling target's
        chain (``pulling``), and those ``frozen`` marks, are fixed at q0."""
        lo = self.chain.lower
        hi = self.chain.upper
        if frozen is None and self.every_effector_moves_all and self.pulling:
            if not self.bounds_are_limits:
                self._dd[DD_LO] = lo
                self._dd[DD_HI] = hi
                self.bounds_are_limits = True
            return
        free = np.zeros(self._n, dtype=bool)
        for i in self.pulling:
            free[self._chain_dofs[i]] = True
        if frozen is not None:
            free &= ~frozen
        q = np.clip(q0, lo, hi)
        self._dd[DD_LO] = np.where(free, lo, q)
        self._dd[DD_HI] = np.where(free, hi, q)
        self.bounds_are_limits = False
