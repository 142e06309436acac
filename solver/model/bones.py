"""The skeleton both importers produce (``gltf.read_gltf``, ``bvh.read_bvh``).

``Skeleton`` is bones in topological order, each with a parent, a rest transform, a
fixed offset and, for BVH, the channel layout of the file's MOTION block; ``Motion`` is
a BVH clip in SI units. ``skeleton.chain_from_skeleton`` turns a skeleton into a chain;
the frames a bone's transforms are given in are described there.

Errors are ``InvalidModel`` naming the bone (``joint``) and the member at fault
(``field``: ``bones``, ``name``, ``parent``); an unknown bone name lists close names.
"""

from __future__ import annotations

import difflib
import enum
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from solver.arrays import Matrix, Vector
from solver.errors import InvalidModel
from solver.model import Transform

# Bones beyond this make chain building and per-frame output slow for nothing: the
# largest game rigs (faces and fingers included) have a few hundred.
MAX_BONES = 4096
MAX_NAME_LENGTH = 256


class Channel(enum.StrEnum):
    """A BVH channel: a translation or rotation about one axis of the parent frame."""

    X_POSITION = "Xposition"
    Y_POSITION = "Yposition"
    Z_POSITION = "Zposition"
    X_ROTATION = "Xrotation"
    Y_ROTATION = "Yrotation"
    Z_ROTATION = "Zrotation"

    @property
    def axis(self) -> str:
        return self.value[0].lower()

    @property
    def is_rotation(self) -> bool:
        return self.value.endswith("rotation")


@dataclass(frozen=True, slots=True, kw_only=True)
class Bone:
    """One bone of a skeleton.

    Attributes:
        name: Unique name (a glTF node's name, ``node_<index>`` when it has none).
        parent: Parent bone's name; None for a root bone.
        rest: Rest transform in the bone's parent node frame [m].
        offset: Fixed transform from the parent bone's frame (the skeleton's world
            frame for a root bone) to the bone's parent node frame.
        channels: BVH channels in file order (empty for glTF and End Sites).
        rotation_order: The axes the source rotates this bone about, in order: the
            BVH rotation channels; None when the source does not say (glTF).
    """

    name: str
    parent: str | None
    rest: Transform = field(default_factory=Transform)
    offset: Transform = field(default_factory=Transform)
    channels: tuple[Channel, ...] = ()
    rotation_order: str | None = None

    @property
    def can_rotate(self) -> bool:
        """Whether the source lets this bone rotate (see ``skeleton``'s decisions)."""
        return self.rotation_order != ""


@dataclass(frozen=True, slots=True)
class Skeleton:
    """Bones in topological order (parents before children).

    Raises:
        InvalidModel: no bone, too many, an empty, over-long or duplicate name, a
            parent that is unknown or comes later.
    """

    name: str
    bones: tuple[Bone, ...]

    def __post_init__(self) -> None:
        if not self.bones:
            raise InvalidModel("a skeleton needs at least one bone", field="bones")
        if len(self.bones) > MAX_BONES:
            raise InvalidModel(f"too many bones: {len(self.bones)} > {MAX_BONES}", field="bones")
        seen: set[str] = set()
        for bone in self.bones:
            if not bone.name or len(bone.name) > MAX_NAME_LENGTH:
                raise InvalidModel(
                    f"bone names must have 1-{MAX_NAME_LENGTH} characters",
                    joint=bone.name[:MAX_NAME_LENGTH],
                    field="name",
                )
            if bone.name in seen:
                raise InvalidModel("duplicate bone name", joint=bone.name, field="name")
            if bone.parent is not None and bone.parent not in seen:
                raise InvalidModel(
                    f"parent {bone.parent!r} is unknown or comes after its child",
                    joint=bone.name,
                    field="parent",
                )
            seen.add(bone.name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bones)

    @property
    def roots(self) -> tuple[Bone, ...]:
        return tuple(b for b in self.bones if b.parent is None)

    def bone(self, name: str) -> Bone:
        for b in self.bones:
            if b.name == name:
                return b
        raise unknown_bone(name, self.names, field="bones")

    def by_name(self) -> dict[str, Bone]:
        return {b.name: b for b in self.bones}

    def rest_origins(self) -> dict[str, Vector]:
        """Each bone's origin in the skeleton's world frame at rest [m]."""
        frames: dict[str, tuple[Matrix, Vector]] = {}
        for bone in self.bones:
            rotation, origin = frames[bone.parent] if bone.parent else (np.eye(3), np.zeros(3))
            for step in (bone.offset, bone.rest):
                origin = rotation @ step.translation + origin
                rotation = rotation @ step.rotation
            frames[bone.name] = (rotation, origin)
        return {name: origin for name, (_, origin) in frames.items()}


@dataclass(frozen=True, slots=True)
class Motion:
    """A clip in SI units, one row per frame.

    Attributes:
        frame_time_s: Time between frames [s].
        values: Shape (n_frames, n_channels): rotations [rad], positions [m]
            (absolute local positions: they replace the bone's rest translation on
            their axes).
        channels: (bone name, channel) of each column, in file order.
    """

    frame_time_s: float
    values: Matrix
    channels: tuple[tuple[str, Channel], ...]

    @property
    def n_frames(self) -> int:
        return int(self.values.shape[0])


# How many of a skeleton's bone names an unknown-bone error lists when none is alike.
_LISTED_BONES = 12


def unknown_bone(name: str, names: Iterable[str], *, field: str) -> InvalidModel:
    """The error for a bone name that is not in the skeleton, with close names."""
    return InvalidModel(unknown_bone_message(name, names), joint=name, field=field)


def unknown_bone_message(name: str, names: Iterable[str]) -> str:
    """``unknown bone 'x'`` with the close names (or, when none is alike, the names
    there are): for a caller that names the field itself."""
    known = list(names)
    # A name the file gives several joints: the importer called them name#<node index>
    # (solver.model.gltf), which a name-based lookup in an engine would not guess.
    renamed = [n for n in known if n.startswith(f"{name}#")]
    if renamed:
        listed = ", ".join(repr(n) for n in renamed)
        return (
            f"unknown bone {name!r}: {len(renamed)} joints of the file have that name, so "
            f"each is called <name>#<node index>: {listed}"
        )
    close = difflib.get_close_matches(name, known, n=5, cutoff=0.5)
    if close:
        hint = f"; did you mean {', '.join(repr(c) for c in close)}?"
    else:
        # Nothing alike (a file without node names calls its bones node_<index>): the
        # names there are, so that the caller need not open the file to find them.
        shown = ", ".join(repr(n) for n in known[:_LISTED_BONES])
        more = f", ... ({len(known)} in all)" if len(known) > _LISTED_BONES else ""
        hint = f"; the skeleton's bones are {shown}{more}" if known else ""
    return f"unknown bone {name!r}{hint}"
