"""How far each effector can get from the chain's root: a bound that proves a position
target out of reach.

Without it a one-shot solve of a target 2 m beyond a 1 m arm restarted until its time
budget ran out and answered ``budget_exhausted`` (83 of 90 such targets on panda, UR5
and iiwa, a robotics user's trial), which reads as "more time would do" when no time
would. With it such a frame is answered ``not_reached`` (``judged``), its restarts kept:
they find a nearer closest pose than one local solve (2026-11-30, 30 targets 1.6-3 m
away, 5 ms budget: without restarts the humanoid arm's closest pose was 2.6 cm farther
at the median, up to 46 cm), and a stream's REACH frame skips its global fallback,
whose answer is only taken if it solves the frame, which it cannot.

The bound, by the triangle inequality: the effector's point is the root's origin plus,
along the effector's path of joints, each joint's origin translation, each prismatic
joint's slide and the tip offset, each turned by rotations (which keep lengths); a
rotation about a pivot c moves a point by at most 2 |c| more. So its distance from
the root's origin is at most the sum of their lengths. A slide without limits makes
it infinite (nothing is ever refused restarts). Targets are in the root's frame.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..model import Chain, EffectorMode, Joint, JointKind
from .options import IKOptions
from .result import IKResult, IKStatus
from .targets import GIVEN_POSITION, Target

_POSITIONED = frozenset({EffectorMode.POSITION, EffectorMode.POSE})


class ReachBounds:
    """Each effector's reach from the root's origin [m] (``bound``), and the options a
    frame whose targets lie beyond it is solved with."""

    def __init__(self, chain: Chain) -> None:
        by_child = {j.child: j for j in chain.joints}
        by_name = {j.name: j for j in chain.joints}
        self.bound: dict[str, float] = {}
        for e in chain.effectors:
            if e.mode not in _POSITIONED or e.position_weight <= 0.0:
                continue  # its targets pull no point to a place
            total = float(np.linalg.norm(e.tip_offset))
            link = e.link
            while (j := by_child.get(link)) is not None:
                total += float(np.linalg.norm(j.origin.translation))
                total += 2.0 * float(np.linalg.norm(j.pivot))
                if j.kind is JointKind.PRISMATIC:
                    total += _slide(j, by_name)
                link = j.parent
            self.bound[e.name] = total
        self._without: tuple[IKOptions, IKOptions] | None = None  # (options, no restarts)

    def beyond(self, targets: Sequence[Target], options: IKOptions) -> bool:
        """Whether a target asks a point further from the root than its effector can
        be (by more than the position tolerance); weighted targets are not judged (a
        blend aims short of its target)."""
        bound = self.bound
        tolerance_m = options.position_tolerance_m
        for t in targets:
            reach = bound.get(t.effector)
            position = t.position
            if reach is None or position is None or not (t.plain and t.given & GIVEN_POSITION):
                continue
            if float(np.linalg.norm(position)) > reach + tolerance_m:
                return True
        return False

    def judged(self, result: IKResult, targets: Sequence[Target], options: IKOptions) -> IKResult:
        """``result``, ``not_reached`` rather than ``budget_exhausted`` when a target is
        beyond reach: no time would have reached it."""
        if result.status is IKStatus.BUDGET_EXHAUSTED and self.beyond(targets, options):
            return result._replace(status=IKStatus.NOT_REACHED)
        return result


def _slide(joint: Joint, by_name: dict[str, Joint]) -> float:
    """The longest slide of a prismatic joint [m] (a follower's from its leader's range)."""
    mimic = joint.mimic
    if mimic is None:
        ends = (*joint.lower[:1], *joint.upper[:1])
        return max((abs(v) for v in ends), default=math.inf) if len(ends) == 2 else math.inf
    leader = by_name[mimic.joint]
    if len(leader.lower) != 1 or len(leader.upper) != 1:
        return math.inf
    m, o = mimic.multiplier, mimic.offset
    return max(abs(m * leader.lower[0] + o), abs(m * leader.upper[0] + o))
