"""Skeleton chain specs (glTF, BVH) -> a ``SkeletonChain``, errors naming the request field.

The readers (``solver.model.gltf``, ``solver.model.bvh``) name the part of the file at
fault (``nodes[3]``, ``skins[0]``, a BVH line); this module says which request field
holds it (``chain.glb_base64``, ``chain.gltf.nodes[3].rotation``, ``chain.bvh``) and
maps per-bone settings to the solver's (``chain.bones.LeftLeg.lower``,
``chain.effectors[1].bone``, ``chain.moving[4]``).
"""

from __future__ import annotations

import base64
import binascii
import json
import math
from collections.abc import Iterator

import numpy as np

import schemas as S
from schemas.common import MAX_COORDINATE
from schemas.errors import ErrorCode
from solver.errors import InvalidModel
from solver.model.bvh import read_bvh_skeleton
from solver.model.gltf import read_gltf
from solver.model.skeleton import (
    BoneSettings,
    FreeRoot,
    Skeleton,
    SkeletonChain,
    SkeletonSettings,
    chain_from_skeleton,
)

from ..config import Settings
from ..errors import ServiceError, invalid_problem
from .geometry import effectors_of
from .limits import check_radians

SkeletonSpec = S.GltfChain | S.BvhChain


def skeleton_chain(spec: SkeletonSpec, settings: Settings) -> SkeletonChain:
    """Read the file, then build the chain its settings describe.

    Raises:
        ServiceError: ``invalid_format`` for base64 that does not decode;
            ``invalid_problem`` for anything else, naming the field.
    """
    # Before the file: the cheaper checks first.
    effectors = effectors_of(spec.effectors, settings.max_effectors)
    skeleton = _read(spec, settings)
    field = "chain.bvh" if isinstance(spec, S.BvhChain) else _source(spec)
    _check_lengths(skeleton, field, "check the file's units (unit_m)")
    for name, bone in spec.bones.items():
        check_radians(bone.lower, bone.upper, f"bone {name!r}", f"chain.bones.{name}")
    free_root = None
    if spec.free_root is not None:
        lo, hi = spec.free_root.lower, spec.free_root.upper
        free_root = FreeRoot(lower_m=(lo.x, lo.y, lo.z), upper_m=(hi.x, hi.y, hi.z))
    skeleton_settings = SkeletonSettings(
        effectors=effectors,
        moving=spec.moving,
        bones={
            name: BoneSettings(
                axes=b.axes,
                lower=None if b.lower is None else tuple(b.lower),
                upper=None if b.upper is None else tuple(b.upper),
                terminator=b.terminator,
            )
            for name, b in spec.bones.items()
        },
        default_axes=spec.default_axes,
        free_root=free_root,
        root_link=_root_link(skeleton),
        max_dof=settings.max_dof,
    )
    try:
        return chain_from_skeleton(skeleton, skeleton_settings)
    except InvalidModel as e:
        raise invalid_problem(_without_location(e), _settings_field(spec, e)) from None


def _without_location(e: InvalidModel) -> str:
    """The message without its ``<bone>.<setting>: `` prefix (the field says where;
    the message still names the bone)."""
    where = ".".join(p for p in (e.joint, e.field) if p)
    return str(e).removeprefix(f"{where}: ") if where else str(e)


def _source(spec: S.GltfChain) -> str:
    return "chain.glb_base64" if spec.glb_base64 is not None else "chain.gltf"


def _check_lengths(skeleton: Skeleton, field: str, advice: str) -> None:
    """Refuse bone offsets beyond ``MAX_COORDINATE`` (1000 km), as JSON chains do: JSON
    numbers have no bound, and 1e300 would overflow the kinematics.

    Raises:
        ServiceError: ``invalid_problem`` at ``field``, naming the bone.
    """
    for bone in skeleton.bones:
        for part in (bone.rest, bone.offset):
            if not np.all(np.abs(part.translation) <= MAX_COORDINATE):
                raise invalid_problem(
                    f"bone {bone.name!r}: a translation beyond {MAX_COORDINATE:g} m "
                    f"({part.translation.tolist()}); {advice}",
                    field,
                )


def _root_link(skeleton: Skeleton) -> str:
    """The base link's name: ``world``, unless a bone has that name."""
    names = set(skeleton.names)
    name = "world"
    while name in names:
        name = f"_{name}"
    return name


def _base64_hint(text: str) -> str:
    """What is likely wrong with base64 that does not decode, for the two mistakes a
    client makes most: a browser's data URL (FileReader.readAsDataURL) sent whole, and
    the URL-safe alphabet (some engines' and languages' default encoders)."""
    if text.startswith("data:"):
        return "; this is a data URL: send only what follows 'base64,'"
    if "-" in text or "_" in text:
        return "; it holds '-' or '_', the URL-safe alphabet: use '+' and '/'"
    return ""


def _read(spec: SkeletonSpec, settings: Settings) -> Skeleton:
    # A decoded file cannot be larger than the body that carried it.
    cap = settings.max_body_bytes
    if isinstance(spec, S.BvhChain):
        try:
            # The hierarchy only: the chain needs no clip (its MOTION block is not read).
            return read_bvh_skeleton(spec.bvh, unit_m=spec.unit_m, max_bytes=cap)
        except InvalidModel as e:
            raise _file_problem(e, "chain.bvh") from None
    if spec.glb_base64 is not None:
        try:
            glb = base64.b64decode(spec.glb_base64, validate=True)
        except (binascii.Error, ValueError) as e:
            raise ServiceError(
                ErrorCode.INVALID_FORMAT,
                f"glb_base64 is not valid base64 (standard alphabet, padded): {e}"
                + _base64_hint(spec.glb_base64),
                status_code=422,
                field="chain.glb_base64",
            ) from None
        where = "chain.glb_base64"
        if not glb.startswith(b"glTF") and glb.removeprefix(_BOM).lstrip()[:1] != b"{":
            # Not a GLB (nor a .gltf document, which the reader also takes, with or
            # without a UTF-8 byte-order mark): say so rather than report it as JSON
            # that does not parse.
            what = "is empty" if not glb else f"starts with {glb[:4]!r}, not the magic b'glTF'"
            raise invalid_problem(
                f"chain.glb_base64 is not a GLB file: the decoded data {what} (a .gltf JSON "
                "document goes in chain.gltf)",
                "chain.glb_base64",
            )
        data: bytes | str = glb
    else:
        where = "chain.gltf"
        try:
            data = json.dumps(spec.gltf, allow_nan=False)
        except ValueError:  # NaN or Infinity: the request's JSON parser accepts them
            raise _non_finite(spec.gltf, where) from None
    try:
        return read_gltf(data, skin=spec.skin, max_bytes=cap, unit_m=spec.unit_m)
    except InvalidModel as e:
        raise _file_problem(e, _gltf_field(where, e)) from None


def _non_finite(document: object, where: str) -> ServiceError:
    """``invalid_format`` naming the first NaN or infinite number of a .gltf document
    (``chain.gltf.nodes[1].translation[0]``): the body's JSON parser reads the tokens
    NaN and Infinity, which some exporters write, but a glTF number must be finite."""
    path = first_non_finite(document)
    field = (
        where
        if path is None
        else where + "".join(f"[{p}]" if type(p) is int else f".{p}" for p in path)
    )
    if len(field) > _MAX_FIELD_CHARS:  # a document nested thousands deep
        field = where
    return ServiceError(
        ErrorCode.INVALID_FORMAT,
        f"{field}: a number that is not finite (a glTF number must be finite; JSON has "
        "no NaN or Infinity)",
        status_code=422,
        field=field,
    )


# An effector's settings as the request names them (the solver's errors name the same).
_EFFECTOR_FIELDS = frozenset(
    {"mode", "tip_offset", "tip_rotation", "aim_axis", "position_weight", "rotation_weight"}
)
# The UTF-8 byte-order mark some Windows tools write before a .gltf document.
_BOM = b"\xef\xbb\xbf"
# A field longer than this (a path thousands of levels deep) is named by its document.
_MAX_FIELD_CHARS = 512


def first_non_finite(document: object) -> list[str | int] | None:
    """The keys and indices down to the first non-finite float, depth first in document
    order. Only the path being walked is kept (a walk that built each child's path up
    front took gigabytes for a 4 MB body with a NaN at its end)."""
    if isinstance(document, float) and not math.isfinite(document):
        return []
    root = _children(document)
    stack = [] if root is None else [root]
    path: list[str | int] = []  # the key of each container below the root being walked
    while stack:
        step = next(stack[-1], None)
        if step is None:
            stack.pop()
            if path:
                path.pop()
            continue
        key, value = step
        if isinstance(value, float) and not math.isfinite(value):
            return [*path, key]
        children = _children(value)
        if children is not None:
            stack.append(children)
            path.append(key)
    return None


def _children(value: object) -> Iterator[tuple[str | int, object]] | None:
    if isinstance(value, dict):
        return iter(value.items())
    if isinstance(value, list):
        return enumerate(value)
    return None


def _file_problem(e: InvalidModel, field: str) -> ServiceError:
    """``invalid_problem`` at ``field``; the reader's message already names the part
    of the file (``nodes[1](knee).scale: ...``, ``LeftLeg.line 9: ...``)."""
    return ServiceError(ErrorCode.INVALID_PROBLEM, str(e), status_code=422, field=field)


def _gltf_field(where: str, e: InvalidModel) -> str:
    part = e.joint or ""
    if part == "skin":
        return "chain.skin"
    if where == "chain.gltf" and part == "json" and e.field:
        # a top-level member of the document ("nodes must be an array")
        return f"{where}.{e.field}"
    if where == "chain.gltf" and part not in ("", "glb", "json"):
        # "nodes[3](hip)" -> chain.gltf.nodes[3].<field>
        path = part.split("(", 1)[0].strip()
        return f"{where}.{path}.{e.field}" if e.field else f"{where}.{path}"
    return where


def _settings_field(spec: SkeletonSpec, e: InvalidModel) -> str:
    field, bone = e.field or "", e.joint
    if field == "moving" and spec.moving is not None and bone in spec.moving:
        return f"chain.moving[{spec.moving.index(bone)}]"
    if field == "effectors":
        for i, eff in enumerate(spec.effectors):
            if eff.bone == bone:
                return f"chain.effectors[{i}].bone"
    if field in ("axes", "lower", "upper") and bone is not None:
        if bone in spec.bones:
            return f"chain.bones.{bone}.{field}"
        return "chain.default_axes" if field == "axes" else "chain.bones"
    if field == "bones" and bone in spec.bones:
        return f"chain.bones.{bone}"
    if field in ("moving", "bones", "free_root", "effectors"):
        return f"chain.{field}"
    for i, eff in enumerate(spec.effectors):
        if bone is not None and (eff.name or eff.bone) == bone:
            # The effector's own setting (aim_axis, tip_offset, a weight), as sent.
            return (
                f"chain.effectors[{i}].{field}"
                if field in _EFFECTOR_FIELDS
                else f"chain.effectors[{i}]"
            )
    return "chain"
