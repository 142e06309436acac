"""Remarks an importer makes on a model it accepted: a file read by a convention of
its own (``lower > upper`` for an unlimited joint) or by the format's defaults, which
the user should hear about rather than find out from the solutions."""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from solver.arrays import Vector


class NoteKind(enum.StrEnum):
    """What an importer read in a way the user should know about."""

    UNLIMITED_BY_CONVENTION = "unlimited_by_convention"  # lower > upper: no limits
    DEFAULT_LIMIT = "default_limit"  # a missing lower or upper read as URDF's 0
    MIMIC_NARROWS_LEADER = "mimic_narrows_leader"  # a follower's limits cut the range
    # A follower's limits leave its leader no room (written for the other sense of the
    # map, e.g. PR2's grippers): ignored, as ROS and pinocchio ignore a mimic's limits.
    MIMIC_LIMITS_IGNORED = "mimic_limits_ignored"
    # Numbers that read like degrees or millimetres where the format wants radians and
    # metres (a revolute limit of 170, an rpy of 90, a slide of 500): taken as written.
    UNLIKELY_UNITS = "unlikely_units"


@dataclass(frozen=True, slots=True)
class ModelNote:
    """One remark on an imported model: its kind, the joint and field, and a sentence."""

    kind: NoteKind
    joint: str
    field: str
    message: str


# Beyond two turns either way a revolute limit reads as degrees (multi-turn joints stop
# at +-2 pi: UR's wrists), up to two turns in degrees; an origin angle beyond a turn,
# likewise. Larger numbers are another convention (1e16 for "no limit", Gazebo's rotors).
_LIMIT_RAD = (4.0 * math.pi, 720.0)
_ANGLE_RAD = (2.0 * math.pi, 360.0)
# Beyond 10 m a slide reads as millimetres or centimetres (a gantry's is a few metres).
_SLIDE_M = (10.0, 10_000.0)


def _unlikely(values: tuple[float, ...], band: tuple[float, float]) -> list[float]:
    return [v for v in values if band[0] < abs(v) <= band[1]]


def unit_notes(
    joint: str, limits: tuple[float, ...], rpy: tuple[float, ...], *, slide: bool = False
) -> list[ModelNote]:
    """An ``unlikely_units`` note for limits or origin angles that read as degrees (or a
    slide as millimetres), for a format whose angles are radians and lengths metres.
    Only a note: the numbers are kept as written, since a joint may mean them."""
    notes = []
    band, unit = (_SLIDE_M, "m") if slide else (_LIMIT_RAD, "rad")
    wide = _unlikely(limits, band)
    if wide:
        meant = "millimetres or centimetres" if slide else "degrees"
        notes.append(
            ModelNote(
                NoteKind.UNLIKELY_UNITS,
                joint,
                "limit",
                f"limit {wide[0]!r} {unit} is beyond {band[0]:.4g} {unit}: were the limits "
                f"written in {meant}? They are read in {unit}, as the format says",
            )
        )
    turned = _unlikely(rpy, _ANGLE_RAD)
    if turned:
        notes.append(
            ModelNote(
                NoteKind.UNLIKELY_UNITS,
                joint,
                "origin.rpy",
                f"origin angle {turned[0]!r} rad is beyond a turn: were the angles written in "
                "degrees? They are read in radians, as the format says",
            )
        )
    return notes


# A character whose bones span more than this from its root at rest reads as a file in
# centimetres (a person's hips to head, 0.7 m, at 70 "m"), inches or another unit (a
# CMU BVH conversion: 18); less than this, as a file in metres read as centimetres (a
# person at 0.7 cm; a Mixamo file whose 0.01 scale node already gives metres, read with
# unit_m 0.01). Between them lie the characters a game has, from a hand rig to a large
# creature.
_SPAN_M = (0.05, 10.0)


def skeleton_size_notes(origins: Mapping[str, Vector]) -> list[ModelNote]:
    """An ``unlikely_units`` note for a skeleton whose bones' rest origins ([m], the
    first one its root) span more or less than a character does: a file written in
    other units than the reader took (``unit_m``). Only a note: the skeleton is kept."""
    if len(origins) < 2:
        return []
    names = list(origins)
    points = np.array([origins[n] for n in names])
    distances = np.linalg.norm(points - points[0], axis=1)
    far = int(np.argmax(distances))
    span = float(distances[far])
    if _SPAN_M[0] <= span <= _SPAN_M[1] or span == 0.0:
        return []
    if span > _SPAN_M[1]:
        why = "is the file in centimetres or another unit? Set unit_m (0.01 for centimetres)"
    else:
        why = "is unit_m too small for the file? (1 for a file in metres)"
    return [
        ModelNote(
            NoteKind.UNLIKELY_UNITS,
            names[far],
            "unit_m",
            f"the skeleton spans {span:.4g} m at rest (from {names[0]!r} to {names[far]!r}): "
            f"{why}; lengths are the file's numbers times unit_m",
        )
    ]
