"""Pole (hint) targets: where a limb bends, chosen by a point, without ever making a
reachable frame fail.

A frame with poles is solved in three calls of the compiled solve
(``frame.solve_frame``), the article's method unchanged in each:

1. Plain: the usual solve from the frame's seed, as if it had no pole (without the
   null-space step, which would pull the self-motion the pole chose towards the rest
   pose).
2. Shaping: the IK objective plus w |o_k - pole|^2 for each pole (``pole_term``: o_k
   the origin of the pulled link, a knee or an elbow; w = ``POLE_WEIGHT``), from the
   frame's seed, with the goal switched off (f_goal = -inf: the pass does not stop
   when the targets are first met, so the pole gets to swing the limb round), no
   restarts (a random restart would pick the bend side by chance) and at most
   ``SHAPING_MAX_ITER`` iterations (``SHAPING_FIRST_MAX_ITER`` on a frame with no
   previous answer) and half the time budget left.
3. The usual solve without the pole term, from the shaping pass's answer: it converges
   to the targets on the side the pole chose (a local method stays in the basin it
   starts in), and success is judged as in any frame.

The third call's answer is the frame's where it brings the pulled links nearer their
poles than the plain answer by more than ``SHAPED_GAIN`` of the distance (or where the
plain solve missed); else the plain answer, which continues the last one. So a pole
never turns a frame the plain solve reaches into a failure (it only costs the time), a
stream's bend side follows a pole that moves smoothly (each frame starts from the last
answer, and the shaping pass moves the limb continuously with the pole), and a limb
whose pole and target stand still stands still (``PoleShaper.solve`` says why the
shaped answer alone did not).

The pulled link, when the client names none (``default_pole_link``): the middle of the
effector's limb. The limb is the effector's path towards the root up to the first link
that is one of these (its top): a link where the chain branches into another part that
moves on variables this effector does not read (the hips for a foot, the chest for a
hand, a hand for a finger; not a fixed sensor frame, nor the other finger of a gripper
that mimics this one), a link another effector's path shares (an effector's link above
this one's), or a link none of the effector's variables moves
(``CompiledChain.eff_dofs``: above the topmost moving joint of a session whose
``moving`` is the arm, above a terminator; a joint locked by lower = upper moves
nothing); else the root. The middle is the link origin on that path, moved by the
effector's variables, whose distance along the bones from the limb's top is nearest
half the limb's length (the knee of hip-knee-ankle-toe, the elbow of
clavicle-shoulder-elbow-wrist; the shoulder where the clavicle is long).
The branch and the still link make the default the elbow or knee whatever the other
effectors: a limb that ran to the root put a lone hand's middle in the spine (and a
pole on a bone an arm-only session never moves does nothing).
"""

from __future__ import annotations

import difflib
import itertools
import math
import operator
from typing import Any

import numpy as np

from ..errors import InvalidProblem
from ..model import Chain
from ..model.forward import effector_poses, link_poses, node_frames
from ..model.layout import (
    ED_ERR_P,
    ED_ERR_R,
    ND_JAXIS,
    ND_R,
    ND_T,
    NI_DOF,
    NI_KIND,
    NI_PARENT,
    NODE_ROTATION,
)
from ..optim import codes as C
from .blend import FrameCall, SolveResult, combined
from .frame import STATUS_SOLVED, TARGETS_OK
from .kinematics import DD_HI, DD_LO, DD_XLAST, MISC_GOAL, MISC_LAST_F
from .pole_term import POLE_NODE, POLE_POINT, POLE_WEIGHT, POLE_WIDTH
from .targets import Pole

# A point whose speed per unit of every variable above it is below this [m/rad] does not
# move: on the axis or at the centre of each turn (roundoff is ~1e-16 m).
_STILL_RATE = 1e-9
# Weight of the pole term in the shaping pass [1/m^2 against the targets' m^2]: strong
# enough to swing a limb in a few dozen iterations, weak enough that the targets stay
# nearly met (the second call then has little to do).
POLE_WEIGHT_VALUE = 0.1
# The shaped answer is a frame's only where it brings the pulled links nearer their
# poles than the plain answer, by more than this share of the distance (a knee 0.44 m
# from its pole: 0.9 mm): a pole that moves is followed within that, and one that
# stands still leaves the limb still (``PoleShaper.solve``).
SHAPED_GAIN = 2e-3
# Iterations of the shaping pass: enough to swing a knee from one side to the other in
# a one-shot solve (tests/solver/test_poles_weights.py), few enough that a stream frame
# with four poles costs ~5x a plain one rather than ~7x with 40 (bench/RESULTS.md); a
# stream's shaping carries on from frame to frame.
SHAPING_MAX_ITER = 15
# The same for a frame with no previous answer (a stream's first frame, a one-shot
# solve): the limb starts wherever the seed put it, often on the far side of the pole,
# and there is no next frame to carry the swing on. 15 left CesiumMan's left arm a
# quarter turn short of a pole behind it (tests/solver/test_poles_weights.py); the cost
# is the first frame's only, or the first few's while they miss (IKSolver.track's
# frames before the stream is anchored, at most 10).
SHAPING_FIRST_MAX_ITER = 60


def limb_path(chain: Chain, effector: int) -> list[str]:
    """The links from the effector's link up to the root (both included)."""
    parent = {j.child: j.parent for j in chain.joints}
    path = [chain.effectors[effector].link]
    while path[-1] in parent:
        path.append(parent[path[-1]])
    return path


def default_pole_link(chain: Chain, effector: int) -> str | None:
    """The middle of the effector's limb (see the module docstring); None when the
    limb has no link between its top and the tip that the effector's variables move."""
    path = limb_path(chain, effector)
    shared: set[str] = set()
    for other in range(len(chain.effectors)):
        if other != effector:
            shared.update(limb_path(chain, other))
    if path[0] in shared:  # another effector below this one (a hand and its finger)
        shared = set()
    limb = LimbMotion(chain, effector, path)
    # A branch or a shared link ends the limb only above one of the effector's own
    # variables: a rigid finger on a gripper whose motor hangs beside it is no limb.
    bends_below = list(itertools.accumulate((bool(v) for v in limb.own), operator.or_))
    top = next(
        (
            k
            for k in range(1, len(path))
            if not limb.frame_moves[k]
            or (bends_below[k - 1] and (path[k] in shared or limb.branches_off(k)))
        ),
        len(path) - 1,
    )
    q = chain.mid_limits()
    poses = link_poses(chain, q)
    tip = effector_poses(chain, q)[effector][:3, 3]
    points = [poses[path[k]][:3, 3] for k in range(top, -1, -1)] + [tip]
    steps = [float(np.linalg.norm(b - a)) for a, b in zip(points, points[1:], strict=False)]
    lengths = np.cumsum([0.0, *steps])
    total = lengths[-1]
    best: str | None = None
    best_gap = math.inf
    for i, k in enumerate(range(top, -1, -1)):
        if i == 0 or not limb.origin_moves(k):
            continue
        if float(np.linalg.norm(points[i] - tip)) < 1e-9:
            continue
        gap = abs(lengths[i] - 0.5 * total)
        if gap < best_gap - 1e-12:
            best, best_gap = path[k], gap
    return best


class LimbMotion:
    """What the effector's own variables move along its path to the root (effector
    link first): ``CompiledChain.eff_dofs``, so a skeleton's ``moving``, a terminator,
    a mimic joint's leader and a free root all count as the solve counts them, less
    the variables locked by their limits (lower = upper). Read
    from the compiled node tree, without recursion (a chain may be a thousand fixed
    joints deep)."""

    def __init__(self, chain: Chain, effector: int, path: list[str]) -> None:
        compiled = chain.compiled
        self.path = path
        # A locked variable (lower = upper: a URDF's way of freezing a joint) moves
        # nothing: counted, it would stretch the limb above it and make a pole on a
        # link only it carries look useful.
        self._free = chain.upper > chain.lower
        self.variables = frozenset(d for d in compiled.eff_dofs[effector].tolist() if self._free[d])
        self._chain = chain
        # The effector's variables in each path link's own joint (its run of nodes).
        self.own = [
            self._segment_variables(link, above) & self.variables
            for link, above in zip(path, path[1:], strict=False)
        ] + [frozenset()]  # the root: no joint
        # frame_moves[k]: a variable of the effector turns or moves path[k]'s frame.
        self.frame_moves = [False] * len(path)
        moves = False
        for k in range(len(path) - 1, -1, -1):
            moves = moves or bool(self.own[k])
            self.frame_moves[k] = moves
        self._foreign: set[int] | None = None
        self._nodes: np.ndarray | None = None  # node frames at the middle of the limits

    def origin_moves(self, k: int) -> bool:
        """Whether the effector's variables move path[k]'s origin, by the velocity each
        gives it at the middle of the limits: not a joint that turns the link about its
        own origin (an arm-only session's shoulder), nor one whose axis runs through it
        (a BVH bone with no offset, Panda's link2 on joint 1's axis): a pole there would
        pull a point nothing can move. A turn's axis through the origin, or a slide, is
        a property of the chain's structure, not of the pose, for every joint at once."""
        compiled = self._chain.compiled
        node = compiled.link_node[self.path[k]]
        if node < 0:
            return False
        if self._nodes is None:
            self._nodes = node_frames(self._chain, self._chain.mid_limits())
        nd, ni = self._nodes, compiled.ni
        point = nd[node, ND_T : ND_T + 3]
        while node >= 0:
            if int(ni[node, NI_DOF]) in self.variables:
                axis = nd[node, ND_R : ND_R + 9].reshape(3, 3) @ nd[node, ND_JAXIS : ND_JAXIS + 3]
                if ni[node, NI_KIND] != NODE_ROTATION:
                    return True  # a slide moves every point it carries
                rate = np.cross(axis, point - nd[node, ND_T : ND_T + 3])
                if float(np.linalg.norm(rate)) > _STILL_RATE:
                    return True
            node = int(ni[node, NI_PARENT])
        return False

    def branches_off(self, k: int) -> bool:
        """Whether the chain branches at path[k] into another part that moves on
        variables this effector does not read (a chest's neck and other arm; not a
        gripper's other finger that mimics this one's, nor a fixed sensor frame)."""
        link, below = self.path[k], self.path[k - 1]
        foreign = self._foreign_nodes()
        for j in self._chain.joints:
            if j.parent != link or j.child == below:
                continue
            if any(n in foreign for n in self._segment(j.child, link)):
                return True
        return False

    def _segment(self, link: str, parent: str) -> list[int]:
        """The nodes of the joint from ``parent`` to ``link`` (child first)."""
        compiled = self._chain.compiled
        n, stop = compiled.link_node[link], compiled.link_node[parent]
        out = []
        while n != stop and n >= 0:
            out.append(n)
            n = int(compiled.ni[n, NI_PARENT])
        return out

    def _segment_variables(self, link: str, parent: str) -> frozenset[int]:
        ni = self._chain.compiled.ni
        return frozenset(int(ni[n, NI_DOF]) for n in self._segment(link, parent)) - {-1}

    def _foreign_nodes(self) -> set[int]:
        """Nodes with a variable the effector does not read, and that is not locked,
        at or below them."""
        if self._foreign is None:
            ni = self._chain.compiled.ni
            marked: set[int] = set()
            for n in range(len(ni)):
                d = int(ni[n, NI_DOF])
                if d < 0 or d in self.variables or not self._free[d]:
                    continue
                while n >= 0 and n not in marked:
                    marked.add(n)
                    n = int(ni[n, NI_PARENT])
            self._foreign = marked
        return self._foreign


def pole_node(chain: Chain, effector: int, link: str | None) -> int:
    """The node whose origin the pole pulls: ``link``'s, or the default link's.

    Raises:
        InvalidProblem: a link not on the effector's path to the root, the root
            (it cannot move), a link whose origin no moving joint moves (a pole on it
            would do nothing), or no default for this effector.
    """
    name = chain.effectors[effector].name
    if link is None:
        link = default_pole_link(chain, effector)
        if link is None:
            raise InvalidProblem(
                f"pole for {name!r}: the limb has no middle link that its moving joints "
                "carry; name one"
            )
    path = limb_path(chain, effector)
    if link not in path:
        near = ", ".join(repr(p) for p in path[:-1][:8])
        if link not in chain.compiled.link_node:  # a typo, not a link of another limb
            close = difflib.get_close_matches(link, list(chain.compiled.link_node), n=1)
            guess = f" (did you mean {close[0]!r}?)" if close else ""
            raise InvalidProblem(
                f"pole for {name!r}: the chain has no link {link!r}{guess}; "
                f"links on the effector's path: {near}"
            )
        raise InvalidProblem(
            f"pole for {name!r}: link {link!r} is not on the effector's path to the root"
            f" (links there: {near})"
        )
    node = chain.compiled.link_node[link]
    if node < 0:
        raise InvalidProblem(f"pole for {name!r}: the root link {link!r} cannot bend")
    limb = LimbMotion(chain, effector, path)
    if not limb.origin_moves(path.index(link)):
        carried = ", ".join(repr(p) for k, p in enumerate(path[:-1]) if limb.origin_moves(k))
        hint = f" (links whose origin moves: {carried})" if carried else ""
        raise InvalidProblem(
            f"pole for {name!r}: no moving joint moves the origin of link {link!r}, so a "
            f"pole on it cannot bend the limb{hint}"
        )
    return node


class PoleShaper:
    """The two calls of a frame with poles, for one solver (it caches the nodes)."""

    def __init__(self, chain: Chain, misc_start: int) -> None:
        self.chain = chain
        self._start = misc_start
        self._nodes: dict[tuple[int, str | None], int] = {}
        # The inputs of the last frame whose plain answer was kept (``_inputs``): the
        # same frame again (a character standing still) keeps it again, unshaped.
        self._held: tuple[Any, ...] | None = None

    def _inputs(
        self, args: tuple[Any, ...], poles: list[tuple[int, Pole]], cap: int
    ) -> tuple[Any, ...]:
        """Everything the shaping and the choice read: the seed and its H, the options,
        the targets (EI, ED), the bounds, MISC's settings, the poles; not what the
        calls write there (each effector's errors, the goal and last f). Equal inputs
        give equal calls, hence the same choice."""
        data, x0, h0, fopt, iopt, policy = args[:6]
        ed = data[3].copy()
        ed[:, ED_ERR_P : ED_ERR_R + 1] = 0.0
        misc = data[5][: self._start].copy()
        misc[[MISC_GOAL, MISC_LAST_F]] = 0.0
        dd = data[4]
        parts = (x0, h0, fopt, iopt, policy, data[2], ed, dd[DD_LO], dd[DD_HI], misc)
        held = tuple((effector, pole.link, pole.point.tobytes()) for effector, pole in poles)
        return (*(a.tobytes() for a in parts), held, cap)

    def solve(
        self,
        args: tuple[Any, ...],
        poles: list[tuple[int, Pole]],
        usual: FrameCall,
        shaping_max_iter: int = SHAPING_MAX_ITER,
    ) -> SolveResult:
        """The frame of ``args`` (``frame.solve_frame``'s arguments): ``usual`` (the
        frame's solve without poles: the compiled call, or ``blend.solve_blended``)
        from the seed, then the poles' shaping pass (at most ``shaping_max_iter``
        iterations) and ``usual`` again from the shaped pose. The shaped answer is the
        frame's only where it brings the pulled links closer to their poles than the
        plain one, by more than ``SHAPED_GAIN`` of the distance (both solved, or both
        short of a target out of reach), or where only it solves the frame; the answer
        is in ``args``' out_x and out. A frame whose inputs are those of the last one
        that kept its plain answer (a character standing still: same seed, H, targets,
        bounds, options and poles) keeps it again without the shaping pass, which
        would choose the same. Iterations, evaluations,
        restarts and time are summed over the calls; passes are the answer's own (its
        pass log is the one in ``out``).

        Why the plain answer first: the shaping pass trades the targets for the pole
        and the second call trades back along the targets' self-motion, which need not
        retrace the first. Where the pulled link is already as near its pole as the
        targets let it be (a still frame), each frame's round trip moved a ball-joint
        knee 1-2 cm and its joints up to the stream's step limit, for ever; a hinge
        knee has no such freedom and kept still (a game developer's trial).
        """
        data, x0, h0, fopt, iopt, policy, out_x, out, step, scratch, ints = args
        # The plain answer without the null-space step: with poles the pull towards
        # the rest pose would fight the pole's, a little every frame.
        plain_x = np.empty_like(out_x)
        plain_out = np.empty_like(out)
        inputs = self._inputs(args, poles, shaping_max_iter)
        plain = usual(data, x0, h0, fopt, iopt, policy, plain_x, plain_out, 0.0, scratch, ints)
        if plain[0] != TARGETS_OK:
            return plain
        if plain[1] == STATUS_SOLVED and inputs == self._held:
            out_x[:] = plain_x  # the frame of the last one, which kept its plain answer
            out[:] = plain_out
            return plain
        misc = data[5]
        dd = data[4]
        self._write(misc, poles)
        dd[DD_XLAST, 0] = math.nan  # f cached by the plain call lacks the pole term
        left = max(0.0, fopt[C.F_BUDGET] - plain[7])
        shaping_f = fopt.copy()
        shaping_f[C.F_F_GOAL] = -math.inf
        shaping_f[C.F_BUDGET] = 0.5 * left
        shaping_i = iopt.copy()
        shaping_i[C.I_MAX_RESTARTS] = 0
        shaping_i[C.I_MAX_ITER] = min(int(iopt[C.I_MAX_ITER]), shaping_max_iter)
        shaped = np.empty_like(x0)
        try:
            first = usual(
                data, x0, h0, shaping_f, shaping_i, policy, shaped, out, 0.0, scratch, ints
            )
        finally:
            misc[self._start] = 0.0  # the pole term off for everything after
            dd[DD_XLAST, 0] = math.nan  # cached f and goal include the pole: stale
        calls: tuple[SolveResult, ...] = (plain, first)
        if first[0] == TARGETS_OK:
            left_f = fopt.copy()
            left_f[C.F_BUDGET] = max(0.0, left - first[7])
            second = usual(data, shaped, h0, left_f, iopt, policy, out_x, out, 0.0, scratch, ints)
            calls = (plain, first, second)
            # The shaped answer where it solves a frame the plain one misses, or where
            # both solve or both miss (a target out of reach) and it is nearer the poles.
            plain_solved = plain[1] == STATUS_SOLVED
            shaped_solved = second[1] == STATUS_SOLVED
            if (shaped_solved and not plain_solved) or (
                shaped_solved == plain_solved and self._nearer(out_x, plain_x, poles)
            ):
                self._held = None
                return combined(second, calls)
        # The plain answer: a pole never fails a frame it would reach.
        self._held = inputs if plain[1] == STATUS_SOLVED else None
        out_x[:] = plain_x
        out[:] = plain_out
        return combined(plain, calls)

    def _nearer(self, x: np.ndarray, than: np.ndarray, poles: list[tuple[int, Pole]]) -> bool:
        """Whether ``x`` puts the pulled links nearer their poles than ``than`` does,
        by more than ``SHAPED_GAIN`` of the distance (summed over the poles)."""
        nd_x = node_frames(self.chain, x)
        nd_than = node_frames(self.chain, than)
        near = far = 0.0
        for effector, pole in poles:
            node = self._nodes[(effector, pole.link)]
            near += float(np.linalg.norm(nd_x[node, ND_T : ND_T + 3] - pole.point))
            far += float(np.linalg.norm(nd_than[node, ND_T : ND_T + 3] - pole.point))
        return near < (1.0 - SHAPED_GAIN) * far

    def _write(self, misc: np.ndarray, poles: list[tuple[int, Pole]]) -> None:
        start = self._start
        for p, (effector, pole) in enumerate(poles):
            key = (effector, pole.link)
            node = self._nodes.get(key)
            if node is None:
                node = self._nodes[key] = pole_node(self.chain, effector, pole.link)
            b = start + 1 + POLE_WIDTH * p
            misc[b + POLE_NODE] = node
            misc[b + POLE_WEIGHT] = POLE_WEIGHT_VALUE
            misc[b + POLE_POINT : b + POLE_POINT + 3] = pole.point
        misc[start] = len(poles)
