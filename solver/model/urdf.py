"""Build a ``Chain`` from URDF text: the joints on the paths from a base link to tip links.

Parsing is hardened (defusedxml, DTDs forbidden: no entity expansion, no external
entities, no DTD retrieval) and size-capped before the parser sees the text. Only the
kinematic subset of URDF is read: ``<joint>`` elements that are direct children of
``<robot>`` (``<transmission>`` and ``<gazebo>`` also contain ``<joint>`` tags), with
``type``, ``<parent>``, ``<child>``, ``<origin xyz rpy>``, ``<axis xyz>``,
``<limit lower upper>`` and ``<mimic joint multiplier offset>``. Meshes, inertials,
dynamics, ``effort`` and ``velocity`` and everything else are ignored.

The specification's defaults and the conventions of files in the wild:
  - ``<limit>`` is required on revolute and prismatic joints (as in urdfdom), but its
    ``lower`` and ``upper`` default to 0 (a ``default_limit`` note says so);
    ``effort`` and ``velocity`` may be missing (urdfdom requires them; IK needs neither).
  - Limits beyond two turns (or a slide beyond 10 m) and origin angles beyond a turn
    are kept as written, with an ``unlikely_units`` note (degrees? millimetres?).
  - ``lower > upper`` is read as "no limits" (Bullet's convention, used by pybullet's
    files): a revolute joint turns like a continuous one, a prismatic one slides
    freely; an ``unlimited_by_convention`` note says so.
  - Whitespace (or a byte-order mark) before ``<?xml`` and NULs or whitespace at the
    end (C strings written whole) are dropped before parsing.
  - A mimic joint on a path brings its leader's path in (a finger's tip then moves
    with the other finger's variable); see ``solver.model.mimic``.
  - ``floating`` and ``planar`` joints are not variables here: one on a path is
    refused with the link below it to use as ``base_link`` instead.

Every joint's name, type and links are checked, because the paths are found from
them; the numbers and the supported-type rules only apply to joints on the paths, so a
mimic finger or a floating world joint elsewhere in the file does not stop an arm
chain from loading.

Errors are ``InvalidModel``; ``field`` is one of:
  ``urdf``          size cap, XML syntax, DTD/entities, root element is not <robot>
  ``base_link``     unknown base link
  ``tip_links``     no tips, duplicate tip, unknown tip, tip equal to or not below base
  ``joints``        more than max_dof DOF or MAX_FIXED_JOINTS fixed joints on the paths
  ``name``          joint without a name, duplicate joint or link name
  ``type``          missing, unknown or unsupported type (floating, planar)
  ``parent``        missing <parent>, undeclared parent link, a cycle
  ``child``         missing <child>, undeclared child link, a link with two parent joints
  ``mimic``         no leader named, an unknown leader, a leader not below the base,
                    ``mimic.multiplier`` / ``mimic.offset`` not numbers
  ``origin.xyz``, ``origin.rpy``, ``axis``   not 3 finite numbers; zero axis
  ``limit``, ``limit.lower``, ``limit.upper``  missing <limit>, non-numeric, NaN
``joint`` names the joint (or, for link-level errors, the link).

URDF conventions: a joint's child frame is ``parent * origin * motion(q)`` with
origin rotation R = Rz(yaw) Ry(pitch) Rx(roll) (ROS REP-103 fixed axes X-Y-Z), axis
default (1, 0, 0) and unit-normalised; continuous joints have no limits.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InvalidModel
from .chain import MAX_DOF_HARD, Chain, build_chain
from .joints import Effector, EffectorMode, Joint, JointKind, Mimic, Transform
from .notes import ModelNote, NoteKind, unit_notes
from .urdf_xml import first_child as _child
from .urdf_xml import local_name as _tag
from .urdf_xml import parse_urdf_xml

_KINDS = {
    "revolute": JointKind.REVOLUTE,
    "continuous": JointKind.CONTINUOUS,
    "prismatic": JointKind.PRISMATIC,
    "fixed": JointKind.FIXED,
}
_UNSUPPORTED_TYPES = frozenset({"floating", "planar"})
# build_chain's cycle check walks up from every joint (quadratic in the path length):
# 18,000 fixed joints fit in 2 MB and took 39 s. Real robots have a handful per path.
MAX_FIXED_JOINTS = 1000
# xsd:double without the special values; float() alone would also accept "1_0" and "nan".
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


@dataclass(frozen=True, slots=True)
class _RawJoint:
    """A <joint> element with its structure read; numbers are parsed only on a path."""

    name: str
    type: str
    parent: str
    child: str
    element: ET.Element


def chain_from_urdf(
    text: str,
    *,
    base_link: str,
    tip_links: Sequence[str] | str,
    mode: EffectorMode = EffectorMode.POSE,
    max_dof: int = MAX_DOF_HARD,
    max_bytes: int = 2_000_000,
) -> Chain:
    """Build the chain from ``base_link`` to each of ``tip_links`` out of a URDF document.

    Only joints on the paths base -> tip are included; several tips give a tree. Each
    tip link gets one effector named after the link, at the link frame, with ``mode``.
    Joint names become the DOF names, in ``build_chain``'s order (breadth-first from
    the base, document order among siblings).

    Args:
        text: The URDF document.
        base_link: Link that becomes the chain's root (world) frame.
        tip_links: One link name or several; each must lie below ``base_link``.
        mode: What each effector's target constrains.
        max_dof: Upper bound on the chain's degrees of freedom.
        max_bytes: Upper bound on the UTF-8 size of ``text`` [bytes], checked before parsing.

    Returns:
        The validated, compiled chain.

    Raises:
        InvalidModel: Anything in the module docstring's list (and ``build_chain``'s
            checks, e.g. a chain with no joint); ``field`` says which
            check failed and ``joint`` names the joint or link at fault.
    """
    root = parse_urdf_xml(text, max_bytes)
    tips = _check_tips(tip_links)
    try:
        mode = EffectorMode(mode)
    except ValueError:
        raise InvalidModel(f"unknown effector mode {mode!r}", field="mode") from None
    links = _links(root)
    by_child = _joints_by_child(root, links)
    if base_link not in links:
        message = _unknown_link("base", base_link, links)
        raise InvalidModel(message, joint=base_link, field="base_link")
    on_path: set[str] = set()
    for tip in tips:
        on_path.update(_path_joint_names(tip, base_link, links, by_child))
    _add_mimic_leaders(on_path, base_link, links, by_child)
    # Document order among the path joints keeps DOF order stable and readable.
    raw = [j for j in by_child.values() if j.name in on_path]
    notes: list[ModelNote] = []
    joints = [_joint(j, base_link, notes) for j in raw]
    n_fixed = sum(1 for j in joints if j.kind is JointKind.FIXED)
    n_dof = len(joints) - n_fixed
    # Both before build_chain, whose checks grow with the square of the joint count.
    if n_dof > max_dof:
        raise InvalidModel(f"too many degrees of freedom: {n_dof} > {max_dof}", field="joints")
    if n_fixed > MAX_FIXED_JOINTS:
        raise InvalidModel(
            f"too many fixed joints on the paths: {n_fixed} > {MAX_FIXED_JOINTS}", field="joints"
        )
    effectors = [Effector(name=tip, link=tip, mode=mode) for tip in tips]
    chain = build_chain(joints, effectors, max_dof=max_dof)
    return dataclasses.replace(chain, notes=(*notes, *chain.notes))


def _unknown_link(role: str, name: str, links: set[str]) -> str:
    """``unknown <role> link 'x'`` with the file's nearest link names."""
    close = difflib.get_close_matches(name, sorted(links), n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
    return f"unknown {role} link {name!r}{hint}"


def _check_tips(tip_links: Sequence[str] | str) -> list[str]:
    tips = [tip_links] if isinstance(tip_links, str) else list(tip_links)
    if not tips:
        raise InvalidModel("at least one tip link is needed", field="tip_links")
    for tip in tips:
        if not isinstance(tip, str) or not tip:
            raise InvalidModel(
                f"tip link names must be non-empty strings, got {tip!r}", field="tip_links"
            )
    if len(set(tips)) != len(tips):
        dup = next(t for t in tips if tips.count(t) > 1)
        raise InvalidModel("duplicate tip link", joint=dup, field="tip_links")
    return tips


def _named(root: ET.Element, tag: str) -> Iterator[tuple[str, ET.Element]]:
    """Each ``<tag>`` element under root with its name, refusing a missing or repeated
    name (link and joint names are unique in a URDF)."""
    seen: set[str] = set()
    for element in root:
        if _tag(element) != tag:
            continue
        name = element.get("name")
        if not name:
            raise InvalidModel(f"<{tag}> without a name", field="name")
        if name in seen:
            raise InvalidModel(f"duplicate {tag} name", joint=name, field="name")
        seen.add(name)
        yield name, element


def _links(root: ET.Element) -> set[str]:
    return {name for name, _ in _named(root, "link")}


def _link_ref(element: ET.Element, tag: str, joint: str, links: set[str]) -> str:
    ref = _child(element, tag)
    name = ref.get("link") if ref is not None else None
    if not name:
        raise InvalidModel(f"joint needs <{tag} link=...>", joint=joint, field=tag)
    if name not in links:
        raise InvalidModel(f"{tag} link {name!r} is not declared", joint=joint, field=tag)
    return name


def _joints_by_child(root: ET.Element, links: set[str]) -> dict[str, _RawJoint]:
    """Structure of every joint, keyed by child link (a URDF is a tree: one parent each)."""
    by_child: dict[str, _RawJoint] = {}
    for name, element in _named(root, "joint"):
        kind = element.get("type")
        if not kind:
            raise InvalidModel("joint needs a type", joint=name, field="type")
        parent = _link_ref(element, "parent", name, links)
        child = _link_ref(element, "child", name, links)
        if child in by_child:
            raise InvalidModel(
                f"link {child!r} already has parent joint {by_child[child].name!r}",
                joint=name,
                field="child",
            )
        by_child[child] = _RawJoint(name, kind, parent, child, element)
    return by_child


def _path_joint_names(
    tip: str, base: str, links: set[str], by_child: dict[str, _RawJoint]
) -> list[str]:
    """Joints from tip up to base; raises if the tip is unknown, the base, or not below it."""
    if tip not in links:
        raise InvalidModel(_unknown_link("tip", tip, links), joint=tip, field="tip_links")
    if tip == base:
        raise InvalidModel("tip link is the base link", joint=tip, field="tip_links")
    names: list[str] = []
    visited = {tip}
    link = tip
    while link != base:
        joint = by_child.get(link)
        if joint is None:
            raise InvalidModel(
                f"link {tip!r} is not below base link {base!r}", joint=tip, field="tip_links"
            )
        names.append(joint.name)
        link = joint.parent
        if link in visited:
            raise InvalidModel("the joints form a cycle", joint=joint.name, field="parent")
        visited.add(link)
    return names


def _add_mimic_leaders(
    on_path: set[str], base: str, links: set[str], by_child: dict[str, _RawJoint]
) -> None:
    """Add to ``on_path`` the path of every mimic joint's leader (and theirs in turn):
    a follower moves with its leader's variable, so the leader must be in the chain."""
    by_name = {j.name: j for j in by_child.values()}
    pending = list(on_path)
    while pending:
        raw = by_name[pending.pop()]
        mimic = _child(raw.element, "mimic")
        if mimic is None:
            continue
        leader = by_name.get(mimic.get("joint") or "")
        if leader is None:
            raise InvalidModel(
                f"<mimic joint={mimic.get('joint')!r}> names no joint of this file: give "
                "the name of the joint it follows",
                joint=raw.name,
                field="mimic",
            )
        if leader.name in on_path:
            continue
        try:
            names = _path_joint_names(leader.child, base, links, by_child)
        except InvalidModel:
            raise InvalidModel(
                f"it follows joint {leader.name!r}, which is not below base link {base!r}: "
                "choose a base link above both joints",
                joint=raw.name,
                field="mimic",
            ) from None
        fresh = [n for n in names if n not in on_path]
        on_path.update(fresh)
        pending.extend(fresh)


def _refuse_free_joint(raw: _RawJoint, base: str) -> InvalidModel:
    return InvalidModel(
        f"{raw.type} joints are not supported: a {raw.type} joint's motion is not a joint "
        f"variable here; use base_link={raw.child!r} (the link it moves) or a link below it "
        f"instead of {base!r}, and move the base with the targets' frame",
        joint=raw.name,
        field="type",
    )


def _joint(raw: _RawJoint, base: str, notes: list[ModelNote]) -> Joint:
    e, name = raw.element, raw.name
    if raw.type in _UNSUPPORTED_TYPES:
        raise _refuse_free_joint(raw, base)
    kind = _KINDS.get(raw.type)
    if kind is None:
        raise InvalidModel(
            f"unknown joint type {raw.type!r}: URDF's types are revolute, continuous, "
            "prismatic, fixed, floating and planar",
            joint=name,
            field="type",
        )
    origin = _child(e, "origin")
    xyz = _vector(origin, "xyz", name, "origin.xyz", default=(0.0, 0.0, 0.0))
    rpy = _vector(origin, "rpy", name, "origin.rpy", default=(0.0, 0.0, 0.0))
    transform = Transform.from_rpy(xyz, rpy[0], rpy[1], rpy[2], owner=name)
    if kind is JointKind.FIXED:  # axis and limits mean nothing here (iiwa's tool0 has axis 0 0 0)
        notes.extend(unit_notes(name, (), rpy))
        return Joint(name=name, parent=raw.parent, child=raw.child, kind=kind, origin=transform)
    axis = np.array(_vector(_child(e, "axis"), "xyz", name, "axis", default=(1.0, 0.0, 0.0)))
    if float(np.linalg.norm(axis)) < 1e-9:
        raise InvalidModel(
            "axis must not be zero: give <axis xyz> a direction, or make the joint fixed",
            joint=name,
            field="axis",
        )
    lower: tuple[float, ...] = ()
    upper: tuple[float, ...] = ()
    written: tuple[float, ...] = ()  # the limits as the file gives them
    if kind is not JointKind.CONTINUOUS:
        lo, hi = written = _limits(_child(e, "limit"), raw.type, name, notes)
        if lo > hi:
            notes.append(
                ModelNote(
                    NoteKind.UNLIMITED_BY_CONVENTION,
                    name,
                    "limit",
                    f"lower > upper ({lo!r} > {hi!r}) read as no limits (Bullet's convention)",
                )
            )
            lo, hi = -math.inf, math.inf
            if kind is JointKind.REVOLUTE:
                kind = JointKind.CONTINUOUS
        lower, upper = (lo,), (hi,)
    notes.extend(unit_notes(name, written, rpy, slide=kind is JointKind.PRISMATIC))
    return Joint(
        name=name,
        parent=raw.parent,
        child=raw.child,
        kind=kind,
        origin=transform,
        axis=axis / np.linalg.norm(axis),
        lower=lower,
        upper=upper,
        mimic=_mimic(_child(e, "mimic"), name),
    )


def _mimic(element: ET.Element | None, joint: str) -> Mimic | None:
    if element is None:
        return None
    leader = element.get("joint")
    if not leader:
        raise InvalidModel(
            "<mimic> needs a joint attribute: the name of the joint it follows",
            joint=joint,
            field="mimic",
        )
    values = []
    for attr, default in (("multiplier", 1.0), ("offset", 0.0)):
        s = element.get(attr)
        values.append(default if s is None else _number(s, joint, f"mimic.{attr}"))
    return Mimic(leader, values[0], values[1])


def _limits(
    limit: ET.Element | None, kind: str, joint: str, notes: list[ModelNote]
) -> tuple[float, float]:
    """(lower, upper) as written; a missing side is URDF's default, 0, with a note."""
    if limit is None:
        raise InvalidModel(
            f"a {kind} joint needs <limit lower=... upper=...> (URDF requires it); add one, "
            "or make the joint continuous if it turns without limits",
            joint=joint,
            field="limit",
        )
    values = []
    for side in ("lower", "upper"):
        s = limit.get(side)
        if s is None:
            notes.append(
                ModelNote(
                    NoteKind.DEFAULT_LIMIT,
                    joint,
                    f"limit.{side}",
                    f"<limit> has no {side} attribute: URDF's default 0 is used",
                )
            )
            values.append(0.0)
        else:
            values.append(_number(s, joint, f"limit.{side}"))
    return values[0], values[1]


def _vector(
    element: ET.Element | None,
    attr: str,
    joint: str,
    field: str,
    *,
    default: tuple[float, float, float],
) -> tuple[float, float, float]:
    s = element.get(attr) if element is not None else None
    if s is None:
        return default
    parts = s.split()
    if len(parts) != 3:
        raise InvalidModel(f"expected 3 numbers, got {s!r}", joint=joint, field=field)
    x, y, z = (_number(p, joint, field) for p in parts)
    return x, y, z


def _number(s: str, joint: str, field: str) -> float:
    s = s.strip()
    if not _NUMBER.fullmatch(s):
        try:
            special = not math.isfinite(float(s))
        except ValueError:
            special = False
        what = "must be finite" if special else "is not a number"
        raise InvalidModel(f"{s!r} {what}", joint=joint, field=field)
    value = float(s)
    if not math.isfinite(value):  # overflow, e.g. "1e999"
        raise InvalidModel(f"{s!r} must be finite", joint=joint, field=field)
    return value
