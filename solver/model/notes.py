"""Remarks an importer makes on a model it accepted: a file read by a convention of
its own (``lower > upper`` for an unlimited joint) or by the format's defaults, which
the user should hear about rather than find out from the solutions."""

from __future__ import annotations

import enum
from dataclasses import dataclass


class NoteKind(enum.StrEnum):
    """What an importer read in a way the user should know about."""

    UNLIMITED_BY_CONVENTION = "unlimited_by_convention"  # lower > upper: no limits
    DEFAULT_LIMIT = "default_limit"  # a missing lower or upper read as URDF's 0
    MIMIC_NARROWS_LEADER = "mimic_narrows_leader"  # a follower's limits cut the range
    # A follower's limits leave its leader no room (written for the other sense of the
    # map, e.g. PR2's grippers): ignored, as ROS and pinocchio ignore a mimic's limits.
    MIMIC_LIMITS_IGNORED = "mimic_limits_ignored"


@dataclass(frozen=True, slots=True)
class ModelNote:
    """One remark on an imported model: its kind, the joint and field, and a sentence."""

    kind: NoteKind
    joint: str
    field: str
    message: str
