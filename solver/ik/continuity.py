"""Continuity of a tracked stream: the policy a client picks per session and what each
frame reports about its step.

A stream's frames start from the previous answer, but nothing in a local solve keeps
the answer near it: a redundant arm that drifts along its self-motion into a limit or
a singular pose can only follow the next target on another branch, a jump of radians
between two frames (bench/tracking.py). The policy says what a frame may do then:

- ``REACH``: solve every frame, jumping if it must (the global fallback of
  ``IKOptions.global_fallback``); the frame reports the jump.
- ``SMOOTH``: never move a joint more than ``IKOptions.max_joint_step_rad`` from the
  previous answer. The frame is solved inside that box around the previous pose (the
  bounds the bound-constrained optimizer already keeps: restarts and the null-space
  step stay inside it too); a target that cannot be reached inside it answers
  ``not_reached`` with the closest pose found in the box.

Compiled helpers because they run on every frame of a ~10-40 us solve, where a few
numpy calls on 7-vectors cost as much as the solve's last iteration.
"""

from __future__ import annotations

import enum
from typing import NamedTuple

from .._jit import jit
from .kinematics import DD_HI, DD_LO


class Continuity(enum.StrEnum):
    """What a tracked frame may do when its target is not reachable near the last pose."""

    SMOOTH = "smooth"
    REACH = "reach"


class FrameStep(NamedTuple):
    """How far a tracked frame moved from the previous answer.

    ``largest_rad``: the largest change of one variable (radians, or metres for a
    prismatic joint). ``jumped``: it is larger than ``IKOptions.max_joint_step_rad``
    (under ``SMOOTH`` only on the frames after ``set_pose`` before the stream is
    anchored, ``IKSolver.track``, which are solved without the limit; the first is
    measured from the pose set).
    """

    largest_rad: float
    jumped: bool


NO_STEP = FrameStep(0.0, False)


@jit
def largest_step(a, b):  # type: ignore[no-untyped-def]
    """max_i |a_i - b_i| (0 for empty vectors)."""
    worst = 0.0
    for i in range(a.shape[0]):
        d = abs(a[i] - b[i])
        if d > worst:
            worst = d
    return worst


@jit
def narrow_bounds(dd, q, box):  # type: ignore[no-untyped-def]
    """Intersect the frame's bounds (DD rows) with [q - box, q + box]; a bound already
    tighter (a limit, a frozen variable) is kept. q is inside the bounds."""
    for i in range(q.shape[0]):
        lo = q[i] - box
        hi = q[i] + box
        if dd[DD_LO, i] < lo:
            dd[DD_LO, i] = lo
        if dd[DD_HI, i] > hi:
            dd[DD_HI, i] = hi
