"""Chain specs (joints as JSON, URDF text, a built-in example) -> a validated solver chain.

Every ``InvalidModel`` the solver raises becomes a ``ServiceError`` ``invalid_problem``
naming the request field (``chain.joints[2].lower``, ``chain.effectors[0].link``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, cast

import numpy as np

import schemas as S
from schemas.chain import MAX_NAME_LENGTH
from schemas.common import MAX_COORDINATE
from solver.arrays import Vector
from solver.errors import InvalidModel
from solver.ik import default_pole_link
from solver.model import (
    Chain,
    EffectorMode,
    Joint,
    JointKind,
    Transform,
    build_chain,
)
from solver.model.examples import EXAMPLES
from solver.model.skeleton import SkeletonChain, unknown_bone_message
from solver.model.urdf import chain_from_urdf

from ..config import Settings
from ..errors import ServiceError, invalid_problem
from .conventions import NATIVE, Y_UP_METRES, Z_UP_METRES, Convention, frame_of
from .geometry import effectors_of, rotation_matrix, vec3
from .limits import check_radians
from .skeletons import skeleton_chain

_EFFECTOR_FIELDS = frozenset(
    {"link", "tip_offset", "tip_rotation", "aim_axis", "position_weight", "rotation_weight", "mode"}
)
_URDF_REQUEST_FIELDS = frozenset({"base_link", "tip_links", "mode"})


@dataclass(frozen=True, slots=True)
class ChainView:
    """A chain plus the lookups the service needs on every frame."""

    chain: Chain
    effector_modes: dict[str, EffectorMode]
    dof_index: dict[str, int]
    summary: dict[str, Any]  # n_dof, dof (with limits), effectors: JSON-ready
    mid_limits: Vector  # the default seed: middle of each range, 0 if unbounded
    # The effectors a target may name (a valid Name) -> mode: the fast path's lookup.
    fast_modes: dict[str, EffectorMode]
    # Skeleton chains (gltf, bvh): the maps from q to bone rotations and transforms.
    skeleton: SkeletonChain | None = None
    # The client's coordinate conventions -> the chain's frame (identity by default).
    convention: Convention = NATIVE
    # What every result carries unless a frame asks otherwise (skeleton chains).
    bone_output: S.BoneOutput | None = None
    # Effectors whose limb has no bone a pole could pull by default (solver.ik.poles):
    # a pole without ``bone`` on them is refused naming the field, before any solve.
    no_default_pole: frozenset[str] = frozenset()
    # (effector, bone) pairs ``solver.ik.pole_node`` accepted: a stream names the same
    # pole bone every frame, and the check costs ~0.1 ms (an FK at the middle of the
    # limits). Only accepted pairs: at most effectors x links, whatever clients send.
    accepted_poles: set[tuple[str, str]] = field(default_factory=set)

    @classmethod
    def of(cls, chain: Chain) -> ChainView:
        modes = {e.name: e.mode for e in chain.effectors}
        dof = [
            {"name": n, "lower": _finite_or_none(lo), "upper": _finite_or_none(hi)}
            for n, lo, hi in zip(chain.dof_names, chain.lower, chain.upper, strict=True)
        ]
        followers = chain.followers
        summary = {
            "n_dof": chain.n_dof,
            "dof": dof,
            "effectors": [{"name": e.name, "mode": e.mode.value} for e in chain.effectors],
            "followers": [
                {"name": n, "leader": chain.dof_names[i], "multiplier": m, "offset": o}
                for n, i, m, o in zip(
                    followers.names,
                    followers.leader.tolist(),
                    followers.multiplier.tolist(),
                    followers.offset.tolist(),
                    strict=True,
                )
            ],
            "warnings": [
                {"code": w.kind.value, "joint": w.joint, "field": w.field, "message": w.message}
                for w in chain.notes
            ],
        }
        index = {n: i for i, n in enumerate(chain.dof_names)}
        mid = chain.mid_limits()
        fast = {n: m for n, m in modes.items() if 1 <= len(n) <= MAX_NAME_LENGTH}
        no_pole = frozenset(
            e.name for i, e in enumerate(chain.effectors) if default_pole_link(chain, i) is None
        )
        return cls(chain, modes, index, summary, mid, fast, no_default_pole=no_pole)


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def chain_from_spec(
    spec: S.HierarchyChain | S.UrdfChain | S.ExampleChain | S.GltfChain | S.BvhChain,
    settings: Settings,
    conventions: S.Conventions | None = None,
    bone_output: S.BoneOutput | None = None,
) -> ChainView:
    """Build and validate the chain a request describes, within the server's limits,
    with the client's conventions and default bone output.

    Raises:
        ServiceError: ``invalid_problem`` naming the field (``chain.joints[i].<field>``).
    """
    skeleton = None
    if isinstance(spec, S.GltfChain | S.BvhChain):
        skeleton = skeleton_chain(spec, settings)
        chain = skeleton.chain
        native = Y_UP_METRES
    elif isinstance(spec, S.ExampleChain):
        factory = cast(Callable[[], Chain], EXAMPLES[spec.name])
        chain = factory()
    elif isinstance(spec, S.UrdfChain):
        chain = _urdf_chain(spec, settings)
    else:
        chain = _hierarchy_chain(spec, settings)
    if skeleton is None:
        native = Z_UP_METRES
    if chain.n_dof > settings.max_dof:
        raise invalid_problem(
            f"too many degrees of freedom: {chain.n_dof} > {settings.max_dof}", "chain"
        )
    if len(chain.joints) > settings.max_joints:
        raise invalid_problem(
            f"too many joints: {len(chain.joints)} > {settings.max_joints}", "chain"
        )
    if bone_output is not None:
        check_bone_output(bone_output, skeleton, "bones")
    convention = Convention.between(frame_of(conventions, native), native)
    view = ChainView.of(chain)
    client = convention.client
    summary = {
        **view.summary,
        "conventions": {"up": client.up, "handedness": client.handedness, "unit_m": client.unit_m},
    }
    return replace(
        view, summary=summary, skeleton=skeleton, convention=convention, bone_output=bone_output
    )


def check_bone_output(output: S.BoneOutput, skeleton: SkeletonChain | None, where: str) -> None:
    """Refuse bone output on a chain without bones, and unknown bone names.

    Raises:
        ServiceError: ``invalid_problem`` naming ``<where>`` or ``<where>.world[i]``.
    """
    if not (output.local_rotations or output.world):
        return
    if skeleton is None:
        raise invalid_problem("bone output needs a skeleton chain (format gltf or bvh)", where)
    known = set(skeleton.skeleton.names)
    for i, name in enumerate(output.world):
        if name not in known:
            message = unknown_bone_message(name, skeleton.skeleton.names)
            raise invalid_problem(message, f"{where}.world[{i}]")


def _urdf_chain(spec: S.UrdfChain, settings: Settings) -> Chain:
    if len(spec.tip_links) > settings.max_effectors:
        raise invalid_problem(
            f"too many tip links: {len(spec.tip_links)} > {settings.max_effectors}",
            "chain.tip_links",
        )
    try:
        chain = chain_from_urdf(
            spec.urdf,
            base_link=spec.base_link,
            tip_links=spec.tip_links,
            mode=EffectorMode(spec.mode),
            max_dof=settings.max_dof,
            max_bytes=settings.max_urdf_bytes,
        )
    except InvalidModel as e:
        if e.field in _URDF_REQUEST_FIELDS:
            # The request's own field: named once, as the field, with the link at fault
            # (the reader's "tool_0.tip_links: " prefix read as a path of the file).
            where = ".".join(p for p in (e.joint, e.field) if p)
            rest = str(e).removeprefix(f"{where}: ")
            named = e.joint is None or repr(e.joint) in rest
            detail = rest if named else f"{e.joint!r}: {rest}"
            raise invalid_problem(detail, _urdf_field(spec, e)) from None
        raise invalid_problem(str(e), "chain.urdf") from None
    _check_urdf_offsets(chain)
    return chain


def _urdf_field(spec: S.UrdfChain, e: InvalidModel) -> str:
    """The request field a URDF reader's error names: a tip link by its index (of two
    alike the second: the first was fine), else the field."""
    tips = spec.tip_links
    if e.field == "tip_links" and e.joint in tips:
        first = tips.index(e.joint)
        again = tips.index(e.joint, first + 1) if tips.count(e.joint) > 1 else first
        return f"chain.tip_links[{again}]"
    return f"chain.{e.field}"


def _check_urdf_offsets(chain: Chain) -> None:
    """Refuse joint origins beyond ``MAX_COORDINATE`` (1000 km), as JSON chains do: the
    URDF format has no bound, and an origin of 1e308 would make every frame's kinematics
    overflow (each frame then ends ``nonfinite`` instead of the file being refused).

    Raises:
        ServiceError: ``invalid_problem`` at ``chain.urdf``, naming the joint.
    """
    for joint in chain.joints:
        offset = joint.origin.translation
        if not np.all(np.abs(offset) <= MAX_COORDINATE):
            raise invalid_problem(
                f"joint {joint.name!r}: origin.xyz {offset.tolist()} is beyond "
                f"+-{MAX_COORDINATE:g} m; URDF lengths are in metres",
                "chain.urdf",
            )


def _hierarchy_chain(spec: S.HierarchyChain, settings: Settings) -> Chain:
    if len(spec.joints) > settings.max_joints:
        raise invalid_problem(
            f"too many joints: {len(spec.joints)} > {settings.max_joints}", "chain.joints"
        )
    for i, j in enumerate(spec.joints):
        _check_radians(j, f"chain.joints[{i}]")
    joints = [
        Joint(
            name=j.name,
            parent=j.parent,
            child=j.child,
            kind=JointKind(j.kind),
            origin=Transform(vec3(j.origin.translation), rotation_matrix(j.origin.rotation)),
            pivot=vec3(j.pivot),
            axis=vec3(j.axis),
            axes=j.axes,
            lower=tuple(j.lower),
            upper=tuple(j.upper),
            terminator=j.terminator,
        )
        for j in spec.joints
    ]
    effectors = effectors_of(spec.effectors, settings.max_effectors)
    try:
        return build_chain(joints, effectors, max_dof=settings.max_dof)
    except InvalidModel as e:
        raise invalid_problem(str(e), _hierarchy_field(spec, e)) from None


_ROTATION_KINDS = frozenset({JointKind.REVOLUTE, JointKind.CONTINUOUS, JointKind.ROTATIONAL})


def _check_radians(j: S.JointSpec, where: str) -> None:
    """Refuse a rotation limit beyond a full turn (prismatic limits are metres)."""
    if JointKind(j.kind) not in _ROTATION_KINDS:
        return
    try:
        check_radians(j.lower, j.upper, f"joint {j.name!r}", where)
    except ServiceError as e:
        e.detail += '; for unlimited rotation use kind "continuous" with no limits'
        raise


def _hierarchy_field(spec: S.HierarchyChain, e: InvalidModel) -> str:
    """The request path of the joint / effector field an InvalidModel names."""
    field = e.field or ""
    if field in ("rotation", "translation"):
        field = f"origin.{field}"
    if e.joint is not None:
        if field in _EFFECTOR_FIELDS or (
            field == "name" and not any(j.name == e.joint for j in spec.joints)
        ):
            for i, eff in enumerate(spec.effectors):
                if eff.name == e.joint:
                    return f"chain.effectors[{i}].{field}" if field else f"chain.effectors[{i}]"
        indexed = list(enumerate(spec.joints))
        if field == "name":  # a duplicate: the later joint is the one at fault
            indexed.reverse()
        for i, j in indexed:
            # A duplicate variable is named "<joint>.<axis>" for rotational joints.
            if e.joint in (j.name, *(f"{j.name}.{a}" for a in j.axes)):
                return f"chain.joints[{i}].{field}" if field else f"chain.joints[{i}]"
    if field in ("joints", "effectors"):
        return f"chain.{field}"
    if field in ("parent", "name", "child"):
        return "chain.joints"
    return f"chain.{field}" if field else "chain"
