"""How far each effector can get from the chain's root: a bound that proves a position
target out of reach.

Without it a one-shot solve of a target 2 m beyond a 1 m arm restarted until its time
budget ran out and answered ``budget_exhausted`` (83 of 90 such targets on panda, UR5
and iiwa, a robotics user's trial), which reads as "more time would do" when no time
would. With it such a frame is answered ``not_reached`` (``judged``), its restarts kept:
they find a nearer closest pose than one local solve (``bench.out_of_reach``: without
restarts the humanoid arm's closest pose was up to 20.6 cm farther, 22 of 30 targets
by over 1 mm), and a stream's REACH frame skips its global fallback,
whose answer is only taken if it solves the frame, which it cannot.

The bound, by the triangle inequality: the effector's point is the root's origin plus,
along the effector's path of joints, each joint's origin translation, each prismatic
joint's slide and the tip offset, each turned by rotations (which keep lengths); a
rotation about a pivot c moves a point by at most 2 |c| more. So its distance from
the root's origin is at most the sum of their lengths. A slide without limits makes
it infinite (nothing is ever refused restarts). Targets are in the root's frame.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator, Sequence

import numpy as np

from ..model import Chain, EffectorMode, Joint, JointKind
from .options import IKOptions
from .result import IKResult, IKStatus
from .targets import GIVEN_POSITION, Target

_POSITIONED = frozenset({EffectorMode.POSITION, EffectorMode.POSE})


class ReachBounds:
    """Each effector's reach from the root's origin [m] (``bound``, worked out when
    first needed: a one-shot solve builds a solver per request, and a 256-joint chain
    took 20 ms), and the judgement of a frame whose targets lie beyond it."""

    def __init__(self, chain: Chain) -> None:
        self.chain = chain

    @functools.cached_property
    def bound(self) -> dict[str, float]:
        chain = self.chain
        by_child = {j.child: j for j in chain.joints}
        bound: dict[str, float] = {}
        for e in chain.effectors:
            if e.mode not in _POSITIONED or e.position_weight <= 0.0:
                continue  # its targets pull no point to a place
            total = math.hypot(*e.tip_offset)
            link = e.link
            while (j := by_child.get(link)) is not None:
                total += math.hypot(*j.origin.translation) + 2.0 * math.hypot(*j.pivot)
                if j.kind is JointKind.PRISMATIC:
                    total += _slide(j, chain)
                link = j.parent
            bound[e.name] = total
        return bound

    def beyond(self, targets: Sequence[Target], options: IKOptions) -> bool:
        """Whether a target asks a point further from the root than its effector can
        be (by more than the position tolerance); weighted targets are not judged (a
        blend aims short of its target)."""
        return next(self._beyond(targets, options), None) is not None

    def _beyond(self, targets: Sequence[Target], options: IKOptions) -> Iterator[str]:
        """The effectors whose targets are beyond reach (``beyond``)."""
        bound = self.bound
        tolerance_m = options.position_tolerance_m
        for t in targets:
            reach = bound.get(t.effector)
            position = t.position
            if reach is None or position is None or not (t.plain and t.given & GIVEN_POSITION):
                continue
            if float(np.linalg.norm(position)) > reach + tolerance_m:
                yield t.effector

    def only_beyond_missed(
        self, result: IKResult, targets: Sequence[Target], options: IKOptions
    ) -> bool:
        """Whether ``result`` misses only targets beyond reach: at least one is (its
        closest pose points at it), and every other targeted effector is within its
        tolerances. With a target met by no pose of its own limb (behind a limit) and
        another beyond reach, the frame is no answer to stay near: a stream anchored
        there keeps the first effector at its local minimum for good."""
        far = set(self._beyond(targets, options))
        if not far:
            return False
        return all(e.within_tolerance for e in result.effectors if e.name not in far)

    def judged(self, result: IKResult, targets: Sequence[Target], options: IKOptions) -> IKResult:
        """``result``, ``not_reached`` rather than ``budget_exhausted`` when a target is
        beyond reach: no time would have reached it."""
        if result.status is IKStatus.BUDGET_EXHAUSTED and self.beyond(targets, options):
            return result._replace(status=IKStatus.NOT_REACHED)
        return result


def _slide(joint: Joint, chain: Chain) -> float:
    """The longest slide of a prismatic joint [m]; a follower's from the range of the
    variable it follows (``Chain.followers``: chains of mimics composed, the leader's
    limits as narrowed for its followers; a follower's own limits may be ignored)."""
    if joint.mimic is None:
        if len(joint.lower) != 1 or len(joint.upper) != 1:
            return math.inf
        return max(abs(joint.lower[0]), abs(joint.upper[0]))
    followers = chain.followers
    i = followers.names.index(joint.name)
    m, o = float(followers.multiplier[i]), float(followers.offset[i])
    k = int(followers.leader[i])
    lo, hi = float(chain.lower[k]), float(chain.upper[k])
    if m == 0.0:
        return abs(o)
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return math.inf
    return max(abs(m * lo + o), abs(m * hi + o))
