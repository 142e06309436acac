"""A character's skeleton (from glTF or BVH) and the chain built from it.

``Skeleton`` is what both importers produce: bones with a parent, a rest transform and,
for BVH, the channel layout of the file's MOTION block. ``chain_from_skeleton`` turns
it into a ``Chain`` the IK solves, following per-bone settings, and returns a
``SkeletonChain`` that also maps joint vectors back to what a game engine applies: each
moving bone's local rotation quaternion and the world transforms of bones.

The types live in ``bones`` (``Skeleton``, ``Bone``, ``Channel``, ``Motion``) and
``skeleton_settings`` (``SkeletonSettings``, ``BoneSettings``, ``FreeRoot``); this module
re-exports them.

Frames. A bone's frame is its node frame in the source file (glTF node, BVH joint):
``bone = parent_bone * offset * rest * motion(q)``, where ``offset`` is fixed (identity
for BVH; for glTF, non-joint nodes between the bone and its parent bone, or above a root
bone: a "Z_UP" or "Armature" node), ``rest`` the bone's own rest transform (translation
and rotation, uniform scale folded into translations, see ``gltf``), and ``motion`` the
joint's rotations. The chain's root link (``SkeletonSettings.root_link``) is the file's
world frame.

Decisions (what a game developer gets when they give no settings):
  moving bones   every bone that can rotate in its source: every glTF skin joint, every
                 BVH joint with rotation channels. BVH End Sites (bones named
                 ``<parent>_end``) and joints without rotation channels stay fixed.
                 ``SkeletonSettings.moving`` lists the moving bones instead.
  axes           a BVH bone's rotation channels in their file order (so a clip replays
                 exactly); otherwise ``SkeletonSettings.default_axes`` ("xyz").
                 Motion is intrinsic: axes "zyx" give Rz(q0) Ry(q1) Rx(q2).
  limits         a ball joint: every axis in [-360 deg, 360 deg], a full turn either
                 way. Every orientation is reachable (by several angle triples), the
                 rest pose (q = 0) is the middle of the box, where solves start, and no
                 bound sits on the gimbal lock (the Tait-Bryan box's +-90 deg on the
                 middle angle did: a stream stalled against it) nor half a turn from
                 rest (+-180 deg did: angles do not wrap;
                 ``skeleton_settings.default_limits``).
  free root      off. With ``FreeRoot``, prismatic joints along the x, y, z axes of the
                 root bone's parent frame come before its rotation (for BVH, only the
                 axes the root has position channels for, if it has any), limited to the
                 rest position +- ``FreeRoot`` ranges.
  quaternions    (w, x, y, z), rest rotation times the joint's motion, continuous in q
                 (not flipped to w >= 0, so consecutive frames never jump sign).

Errors are ``InvalidModel`` naming the bone (``joint``) and the setting (``field``:
``moving``, ``bones``, ``effectors``, ``free_root``, ``root_link``, ``axes``,
``lower``, ``upper``); an unknown bone name lists close names.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from solver.arrays import Matrix, Vector
from solver.errors import InvalidModel, InvalidProblem
from solver.model import (
    Chain,
    Joint,
    JointKind,
    Transform,
    build_chain,
    matrix_to_quaternion,
)
from solver.model.bones import (
    MAX_BONES,
    MAX_NAME_LENGTH,
    Bone,
    Channel,
    Motion,
    Skeleton,
    unknown_bone,
    unknown_bone_message,
)
from solver.model.forward import forward_kinematics
from solver.model.layout import ND_R, ND_T
from solver.model.notes import skeleton_size_notes
from solver.model.skeleton_settings import (
    DEFAULT_AXES,
    BoneSettings,
    FreeRoot,
    SkeletonSettings,
    default_limits,
)

# The skeleton's types live in bones.py, the settings in skeleton_settings.py; both
# stay importable from here.
__all__ = [
    "DEFAULT_AXES",
    "MAX_BONES",
    "MAX_NAME_LENGTH",
    "Bone",
    "BoneSettings",
    "Channel",
    "FreeRoot",
    "Motion",
    "Skeleton",
    "SkeletonChain",
    "SkeletonSettings",
    "chain_from_skeleton",
    "default_limits",
    "unknown_bone",
    "unknown_bone_message",
]

_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}
# q (x) e for a basis vector e, as q's components (w, x, y, z) permuted and signed:
# q (x) i = (-x, w, z, -y), q (x) j = (-y, -z, w, x), q (x) k = (-z, y, -x, w).
_TIMES_BASIS = {
    "x": ((1, 0, 3, 2), (-1.0, 1.0, 1.0, -1.0)),
    "y": ((2, 3, 0, 1), (-1.0, -1.0, 1.0, 1.0)),
    "z": ((3, 2, 1, 0), (-1.0, 1.0, -1.0, 1.0)),
}


@dataclass(frozen=True, slots=True)
class SkeletonChain:
    """A chain built from a skeleton, with the maps back to bones.

    Attributes:
        skeleton: The source skeleton.
        chain: The compiled chain (joints named after bones; variables
            ``<bone>.<axis>`` for rotations, ``<bone>.t<axis>`` for a free root).
        moving: Names of the moving bones, in skeleton order (the rows of
            ``local_rotations``).
    """

    skeleton: Skeleton
    chain: Chain
    moving: tuple[str, ...]
    _rest_quat: np.ndarray = field(repr=False)  # (n_moving, 4) rest rotations (w, x, y, z)
    # Per moving bone and axis slot (3, unused slots pad): the variable's index into q
    # with a 0 appended (unused: that 0), and q (x) e_axis as a signed permutation.
    _dof: np.ndarray = field(repr=False)  # int64 (n_moving, 3)
    _perm: np.ndarray = field(repr=False)  # int64 (3, n_moving, 4)
    _sign: np.ndarray = field(repr=False)  # float64 (3, n_moving, 4)

    def local_rotations(self, q: Vector) -> Matrix:
        """Each moving bone's local rotation for the joint vector q.

        Args:
            q: Joint vector, shape (n_dof,), [rad] and [m].

        Returns:
            Shape (len(moving), 4): unit quaternions (w, x, y, z), rest rotation times
            the joint's motion, in the bone's parent node frame (what a glTF node's
            ``rotation`` or an engine bone's local rotation holds).
        """
        qa = self._check_q(q)
        half = 0.5 * np.append(qa, 0.0)[self._dof]
        cos, sin = np.cos(half), np.sin(half)
        out = self._rest_quat
        rows = np.arange(out.shape[0])[:, None]
        for slot in range(3):
            # out (x) (cos, sin e_k) = cos out + sin (out (x) e_k); the last is a signed
            # permutation of out's components (Hamilton product with a basis vector).
            turned = out[rows, self._perm[slot]] * self._sign[slot]
            out = cos[:, slot, None] * out + sin[:, slot, None] * turned
        return out

    def world_transforms(self, q: Vector, bones: Sequence[str] | None = None) -> dict[str, Matrix]:
        """World pose (4x4, in the root link's frame) of bones, through the chain's FK.

        Args:
            q: Joint vector, shape (n_dof,).
            bones: Names; None for every bone.

        Raises:
            InvalidModel: an unknown bone name.
        """
        names = self.skeleton.names if bones is None else tuple(bones)
        known = set(self.skeleton.names)
        for name in names:
            if name not in known:
                raise unknown_bone(name, self.skeleton.names, field="bones")
        cc = self.chain.compiled
        nd = cc.nd.copy()
        forward_kinematics(self._check_q(q), cc.ni, nd)
        out: dict[str, Matrix] = {}
        for name in names:
            m = np.eye(4)
            node = cc.link_node[name]  # every bone is a link; -1 only for the root link
            m[:3, :3] = nd[node, ND_R : ND_R + 9].reshape(3, 3)
            m[:3, 3] = nd[node, ND_T : ND_T + 3]
            out[name] = m
        return out

    def clip(self, motion: Motion) -> Matrix:
        """A BVH clip as joint vectors, one row per frame (replay with FK or as seeds).

        Rotation channels of a moving bone become its variables; position channels of
        a free root become its translations relative to the rest position. Channels
        of fixed bones, and position channels of other bones, are dropped (the bone
        keeps its rest transform). Values are not clipped to the limits.

        Returns:
            Shape (n_frames, n_dof), [rad] and [m], in q order.

        Raises:
            InvalidProblem: a moving bone whose axes differ from its rotation
                channels' order (its angles would mean another rotation), or a
                channel naming a bone that is not in the skeleton.
        """
        column = {key: i for i, key in enumerate(motion.channels)}
        known = set(self.skeleton.names)
        for bone_name, _ in motion.channels:
            if bone_name not in known:
                raise InvalidProblem(f"the clip has channels for unknown bone {bone_name!r}")
        bones = self.skeleton.by_name()
        out = np.zeros((motion.n_frames, self.chain.n_dof))
        index = {name: i for i, name in enumerate(self.chain.dof_names)}
        for joint in self.chain.joints:
            if joint.kind is JointKind.ROTATIONAL:
                bone = bones[joint.name]
                order = "".join(c.axis for c in bone.channels if c.is_rotation)
                if order and order != joint.axes:
                    raise InvalidProblem(
                        f"bone {bone.name!r} rotates about {joint.axes!r} but its clip "
                        f"channels are in the order {order!r}: the angles cannot be replayed"
                    )
                for axis in joint.axes:
                    col = column.get((bone.name, Channel(f"{axis.upper()}rotation")))
                    if col is not None:
                        out[:, index[f"{joint.name}.{axis}"]] = motion.values[:, col]
            elif joint.kind is JointKind.PRISMATIC:
                bone_name, _, t_axis = joint.name.rpartition(".t")
                bone = bones[bone_name]
                col = column.get((bone_name, Channel(f"{t_axis.upper()}position")))
                if col is not None:
                    rest = bone.rest.translation[_AXIS_INDEX[t_axis]]
                    out[:, index[joint.name]] = motion.values[:, col] - rest
        return out

    def _check_q(self, q: Vector) -> Vector:
        qa = np.ascontiguousarray(q, dtype=np.float64).reshape(-1)
        if qa.shape != (self.chain.n_dof,):
            raise InvalidProblem(f"q must have {self.chain.n_dof} values, got {qa.shape[0]}")
        return qa


def _compose(a: Transform, b: Transform) -> Transform:
    return Transform(a.rotation @ b.translation + a.translation, a.rotation @ b.rotation)


def _moving_bones(skeleton: Skeleton, settings: SkeletonSettings) -> tuple[str, ...]:
    names = skeleton.names
    known = set(names)
    if settings.moving is None:
        return tuple(b.name for b in skeleton.bones if b.can_rotate)
    if isinstance(settings.moving, str):
        raise InvalidModel("moving must be a list of bone names", field="moving")
    listed = set()
    for name in settings.moving:
        if name not in known:
            raise unknown_bone(name, names, field="moving")
        if name in listed:
            raise InvalidModel("bone listed twice", joint=name, field="moving")
        listed.add(name)
    return tuple(n for n in names if n in listed)  # skeleton order, whatever the list's


def _axes_and_limits(
    bone: Bone, given: BoneSettings, default_axes: str
) -> tuple[str, tuple[float, ...], tuple[float, ...]]:
    if given.axes is not None:
        axes = given.axes
    elif bone.rotation_order:
        axes = bone.rotation_order
    else:
        axes = default_axes
    axes = axes.lower()
    if not 1 <= len(axes) <= 3 or set(axes) - set("xyz") or len(set(axes)) != len(axes):
        raise InvalidModel(
            f"axes must be 1-3 distinct letters of 'xyz', got {axes!r}",
            joint=bone.name,
            field="axes",
        )
    lower, upper = default_limits(axes)
    if (given.lower is None) != (given.upper is None):
        raise InvalidModel(
            "give both lower and upper limits, or neither",
            joint=bone.name,
            field="lower" if given.lower is None else "upper",
        )
    if given.lower is not None and given.upper is not None:
        lower, upper = tuple(given.lower), tuple(given.upper)
    return axes, lower, upper


def _free_root_joints(
    bone: Bone, free: FreeRoot, parent_link: str
) -> tuple[list[Joint], str, Transform]:
    """Prismatic joints before the root bone's rotation; returns them, the link they end
    on and the origin left for the bone's own joint (its rest rotation)."""
    lo = np.asarray(free.lower_m, dtype=np.float64)
    hi = np.asarray(free.upper_m, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,):
        raise InvalidModel(
            "free root limits need 3 values each", joint=bone.name, field="free_root"
        )
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()) or np.any(lo > hi):
        raise InvalidModel(
            "free root limits must be finite with lower <= upper",
            joint=bone.name,
            field="free_root",
        )
    positions = "".join(c.axis for c in bone.channels if not c.is_rotation)
    # BVH: translate along the axes the file animates; otherwise all three.
    axes = "".join(a for a in "xyz" if a in positions) if positions else "xyz"
    joints: list[Joint] = []
    link = parent_link
    origin = _compose(bone.offset, Transform(bone.rest.translation.copy()))
    for a in axes:
        k = _AXIS_INDEX[a]
        child = f"{bone.name}.t{a}"
        direction = np.zeros(3)
        direction[k] = 1.0
        joints.append(
            Joint(
                name=child,
                parent=link,
                child=child,
                kind=JointKind.PRISMATIC,
                origin=origin,
                axis=direction,
                lower=(float(lo[k]),),
                upper=(float(hi[k]),),
            )
        )
        link, origin = child, Transform()
    return joints, link, Transform(np.zeros(3), bone.rest.rotation.copy())


def chain_from_skeleton(skeleton: Skeleton, settings: SkeletonSettings) -> SkeletonChain:
    """Build the chain of a skeleton (see the module's decisions for the defaults).

    Args:
        skeleton: From ``gltf.read_gltf`` or ``bvh.read_bvh``.
        settings: Moving bones, per-bone axes, limits and terminators, effectors on
            bones, an optional free root.

    Returns:
        The chain and its maps back to bones.

    Raises:
        InvalidModel: an unknown bone name (with close names), settings for a bone
            that does not move, bad axes or limits, a free root on a skeleton with
            several roots, or anything ``build_chain`` refuses.
    """
    names = skeleton.names
    known = set(names)
    if settings.root_link in known:
        raise InvalidModel(
            f"a bone is named {settings.root_link!r}, the root link's name: choose another "
            "root_link",
            joint=settings.root_link,
            field="root_link",
        )
    moving = _moving_bones(skeleton, settings)
    moving_set = set(moving)
    for name, given in settings.bones.items():
        if name not in known:
            raise unknown_bone(name, names, field="bones")
        if name not in moving_set and (
            given.axes is not None or given.lower is not None or given.upper is not None
        ):
            raise InvalidModel(
                "axes or limits for a bone that does not move (list it in moving)",
                joint=name,
                field="bones",
            )
    effectors = list(settings.effectors)
    for e in effectors:
        if e.link not in known:
            raise unknown_bone(e.link, names, field="effectors")
    free_root_bone: str | None = None
    if settings.free_root is not None:
        roots = skeleton.roots
        if len(roots) != 1:
            raise InvalidModel(
                f"a free root needs a single root bone, found {[b.name for b in roots][:5]}",
                field="free_root",
            )
        free_root_bone = roots[0].name
        # Its translations are links <bone>.tx, .ty, .tz: a bone of that name would clash.
        clash = [n for n in (f"{free_root_bone}.t{a}" for a in "xyz") if n in known]
        if clash:
            raise InvalidModel(
                f"the free root's translations are named {free_root_bone}.tx, .ty, .tz, "
                f"and a bone is named {clash[0]!r}: rename that bone to use free_root",
                joint=free_root_bone,
                field="free_root",
            )

    joints: list[Joint] = []
    no_settings = BoneSettings()
    for bone in skeleton.bones:
        given = settings.bones.get(bone.name, no_settings)
        parent_link = settings.root_link if bone.parent is None else bone.parent
        origin = _compose(bone.offset, bone.rest)
        if bone.name == free_root_bone:
            assert settings.free_root is not None
            prismatic, parent_link, origin = _free_root_joints(
                bone, settings.free_root, parent_link
            )
            joints.extend(prismatic)
        if bone.name in moving_set:
            kind = JointKind.ROTATIONAL
            axes, lower, upper = _axes_and_limits(bone, given, settings.default_axes)
        else:  # a fixed bone: no axes, no limits (Joint's defaults)
            kind, axes, lower, upper = JointKind.FIXED, "", (), ()
        joints.append(
            Joint(
                name=bone.name,
                parent=parent_link,
                child=bone.name,
                kind=kind,
                origin=origin,
                axes=axes,
                lower=lower,
                upper=upper,
                terminator=given.terminator,
            )
        )
    chain = build_chain(joints, effectors, max_dof=settings.max_dof)
    notes = skeleton_size_notes(skeleton.rest_origins())
    if notes:
        chain = dataclasses.replace(chain, notes=(*chain.notes, *notes))
    return _with_maps(skeleton, chain, moving)


def _with_maps(skeleton: Skeleton, chain: Chain, moving: tuple[str, ...]) -> SkeletonChain:
    index = {name: i for i, name in enumerate(chain.dof_names)}
    by_name = {j.name: j for j in chain.joints}
    bones = skeleton.by_name()
    n = len(moving)
    rest_quat = np.zeros((n, 4))
    dof = np.full((n, 3), chain.n_dof, dtype=np.int64)  # q's appended 0
    perm = np.tile(np.arange(4), (3, n, 1))
    sign = np.zeros((3, n, 4))
    for row, name in enumerate(moving):
        joint = by_name[name]
        rest_quat[row] = matrix_to_quaternion(bones[name].rest.rotation)
        for slot, a in enumerate(joint.axes):
            dof[row, slot] = index[f"{name}.{a}"]
            perm[slot, row], sign[slot, row] = _TIMES_BASIS[a]
    return SkeletonChain(skeleton, chain, moving, rest_quat, dof, perm, sign)
