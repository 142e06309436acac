"""Read a skin's skeleton from glTF 2.0: ``.glb`` (binary) or ``.gltf`` (JSON).

Why a reader of our own rather than pygltflib. We need the container, the node graph
(names, children, rest TRS or matrix) and the skins: no meshes, accessors, images or
animations. pygltflib (1.16) would bring dataclasses-json, marshmallow and
typing-inspect into the service's runtime, decodes every part of the document into
objects, checks no size, count or depth, and leaves graph checks (cycles, a node with
two parents, indices out of range) to the caller; we would write all of the hardening
below anyway, around a library that does not help with it. ``gltf_container`` is the
GLB header and chunk walk (glTF 2.0 spec, section 4.4), ``json.loads`` and the buffer
checks; this module is the node graph, the skins and their checks.

What is read:
  - GLB: 12-byte header (magic "glTF", version 2, total length equal to the input's
    length), a JSON chunk first, an optional BIN chunk second; unknown chunk types are
    skipped (spec 4.4.3.1). ``.gltf``: the JSON document itself (bytes or str).
  - buffers: only checked, never used. A GLB buffer without ``uri`` must fit the BIN
    chunk; a ``data:`` URI must decode (base64) to at least ``byteLength`` bytes; other
    URIs (external files) are not fetched, which is fine: no buffer data is needed.
  - ``extensionsRequired``: those of meshes, materials, textures and the like are
    accepted (nothing here reads them); any other is refused (``gltf_container``).
  - nodes: ``name``, ``children``, ``translation``, ``rotation`` (x, y, z, w),
    ``scale`` or ``matrix`` (16 numbers, column-major).
  - skins: ``joints``, ``name``, and ``skeleton`` (range-checked only: a bone's parent
    is found in the node tree). ``skin`` chooses one by index or name (default: the
    first).

The skeleton. The skin's joint nodes become bones, named after their nodes (a node
without a name gets ``node_<index>``; a name shared by several joints becomes
``<name>#<index>``). A bone's parent is its nearest ancestor that is a joint of the
skin; the nodes between them, and for a root bone the path from the top of the node
tree (a "Z_UP" node, an "Armature" node), are folded into the bone's ``offset``.

Scale. A rigid chain cannot scale, so a node with a joint below it (the bones with
children bones, the nodes between them and above the root bone) may carry a uniform
scale only (components within ``SCALE_TOLERANCE`` of each other, e.g. the 0.01 of an
exporter's centimetre armature); it is folded exactly into the translations below it:
a node's translation is multiplied by the product of its ancestors' scales. World
transforms of bones are then the glTF world matrices with the scale divided out.
Non-uniform, zero or negative (mirroring) scale, shear, or a projective matrix row on
these nodes is refused. A bone with no joint below it (a hand's tip, a hidden prop
bone scaled to 0) scales nothing of the chain: its own scale, whatever it is, is left
to the engine, which keeps it beside the rotation it is sent (a ``matrix`` there must
still give a rotation: no mirror, shear or zero column). glTF is in metres, Y up,
right-handed (spec 3.4); ``unit_m`` scales the whole file for one that is not (a
centimetre export with no 0.01 scale node above its armature), as a scale node would.

Errors are ``InvalidModel``. ``joint`` names the part: ``glb``, ``json``, ``asset``,
``buffers[i]``, ``nodes[i]`` (with the node's name in parentheses when it has one),
``skins[i]`` or ``skin``; ``field`` the member at fault (``byteLength``, ``uri``,
``children``, ``rotation``, ``scale``, ``matrix``, ``joints``, ``skeleton``, ...).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from solver.arrays import Matrix, Vector
from solver.errors import InvalidModel
from solver.model import Transform, quaternion_to_matrix
from solver.model.bones import Bone, Skeleton
from solver.model.gltf_container import (
    MAX_BUFFERS,
    MAX_BYTES,
    MAX_JSON_BYTES,
    json_array,
    read_document,
)

# The container's caps live in gltf_container.py; they stay importable from here.
__all__ = [
    "MATRIX_TOLERANCE",
    "MAX_BUFFERS",
    "MAX_BYTES",
    "MAX_DEPTH",
    "MAX_JSON_BYTES",
    "MAX_NODES",
    "MAX_SKINS",
    "ROTATION_TOLERANCE",
    "SCALE_TOLERANCE",
    "read_gltf",
]

MAX_NODES = 4096
MAX_DEPTH = 256  # node tree depth
MAX_SKINS = 1024
SCALE_TOLERANCE = 1e-4  # relative spread of scale components still called uniform
ROTATION_TOLERANCE = 1e-3  # |q| - 1 accepted (and normalised) for float32 exports
MATRIX_TOLERANCE = 1e-4  # orthogonality of a node matrix's columns after scale


@dataclass(frozen=True, slots=True)
class _Local:
    """A node's rest transform split into its rigid part and its scale, checked only
    when something below the node is scaled by it (``uniform_scale``)."""

    translation: Vector
    rotation: Matrix
    scale: Vector  # per axis (a matrix's column norms)
    part: str
    field: str  # the member the scale came from: "scale" or "matrix"

    def uniform_scale(self) -> float:
        """The scale as one number, refused unless uniform and positive."""
        return _uniform(self.scale, self.part, self.field)


def read_gltf(
    data: bytes | str,
    *,
    skin: int | str | None = None,
    max_bytes: int = MAX_BYTES,
    max_json_bytes: int = MAX_JSON_BYTES,
    max_nodes: int = MAX_NODES,
    max_depth: int = MAX_DEPTH,
    unit_m: float = 1.0,
) -> Skeleton:
    """The skeleton of one skin of a glTF 2.0 document.

    Args:
        data: A ``.glb`` file's bytes, or a ``.gltf`` JSON document (bytes or str).
        skin: Index or name of the skin; None for the first.
        unit_m: Metres per file length unit: 1 by the specification; 0.01 for a file
            an exporter wrote in centimetres with no scale node to say so.
        max_bytes: Cap on the input's size [bytes].
        max_json_bytes: Cap on a GLB's JSON chunk [bytes].
        max_nodes: Cap on the document's node count.
        max_depth: Cap on the node tree's depth.

    Returns:
        The skeleton (named after the skin, ``skin_<index>`` without a name).

    Raises:
        InvalidModel: anything in the module docstring; the message names the part.
    """
    if not (isinstance(unit_m, int | float) and math.isfinite(unit_m) and unit_m > 0.0):
        raise InvalidModel(f"unit_m must be finite and > 0, got {unit_m!r}", joint="gltf")
    doc = read_document(data, max_bytes=max_bytes, max_json_bytes=max_json_bytes)
    nodes = json_array(doc, "nodes", "json", max_len=max_nodes, what="nodes")
    for i, node in enumerate(nodes):
        if not isinstance(node, dict):
            raise InvalidModel("a node must be a JSON object", joint=f"nodes[{i}]")
    parent = _parents(nodes)
    depth = _depths(nodes, parent, max_depth)
    skin_index, skin_doc = _choose_skin(doc, skin)
    joints = _skin_joints(skin_doc, skin_index, len(nodes))
    name = _skin_name(skin_doc, skin_index)
    return _skeleton(nodes, parent, depth, joints, name, float(unit_m))


# -- node graph ----------------------------------------------------------------


def _node_part(nodes: list[Any], i: int) -> str:
    name = nodes[i].get("name")
    if isinstance(name, str) and name:
        return f"nodes[{i}]({name[:64]})"
    return f"nodes[{i}]"


def _index(value: Any, n: int) -> bool:
    return type(value) is int and 0 <= value < n


def _parents(nodes: list[Any]) -> list[int]:
    """Each node's parent (-1 for a root); refuses bad indices and two parents."""
    n = len(nodes)
    parent = [-1] * n
    for i, node in enumerate(nodes):
        children = node.get("children", [])
        if not isinstance(children, list):
            raise InvalidModel(
                "children must be an array", joint=_node_part(nodes, i), field="children"
            )
        for c in children:
            if not _index(c, n):
                raise InvalidModel(
                    f"child {c!r} is not a node index (0..{n - 1})",
                    joint=_node_part(nodes, i),
                    field="children",
                )
            if c == i:
                raise InvalidModel(
                    "a node cannot be its own child", joint=_node_part(nodes, i), field="children"
                )
            if parent[c] >= 0:
                raise InvalidModel(
                    f"node {c} already has parent node {parent[c]}",
                    joint=_node_part(nodes, i),
                    field="children",
                )
            parent[c] = i
    return parent


def _depths(nodes: list[Any], parent: list[int], max_depth: int) -> list[int]:
    """Depth of each node below its root; refuses cycles and trees deeper than the cap."""
    n = len(nodes)
    depth = [-1] * n
    children: list[list[int]] = [[] for _ in range(n)]
    for c, p in enumerate(parent):
        if p >= 0:
            children[p].append(c)
    stack = [i for i in range(n) if parent[i] < 0]
    for i in stack:
        depth[i] = 0
    while stack:
        i = stack.pop()
        for c in children[i]:
            depth[c] = depth[i] + 1
            if depth[c] > max_depth:
                raise InvalidModel(
                    f"the node tree is deeper than {max_depth}",
                    joint=_node_part(nodes, c),
                    field="children",
                )
            stack.append(c)
    if -1 in depth:
        # Every node has at most one parent, so an unreached node sits on or below a
        # cycle: walk up from it until a node repeats, and name that one.
        i, seen = depth.index(-1), set()
        while i not in seen:
            seen.add(i)
            i = parent[i]
        raise InvalidModel(
            "the nodes' children form a cycle", joint=_node_part(nodes, i), field="children"
        )
    return depth


def _choose_skin(doc: dict[str, Any], skin: int | str | None) -> tuple[int, dict[str, Any]]:
    skins = json_array(doc, "skins", "json", max_len=MAX_SKINS, what="skins")
    if not skins:
        raise InvalidModel("the document has no skin", joint="skin")
    for i, s in enumerate(skins):
        if not isinstance(s, dict):
            raise InvalidModel("a skin must be a JSON object", joint=f"skins[{i}]")
    if skin is None:
        return 0, skins[0]
    if type(skin) is int:
        if not 0 <= skin < len(skins):
            raise InvalidModel(
                f"skin index {skin} is out of range (the document has {len(skins)})",
                joint="skin",
            )
        return skin, skins[skin]
    if isinstance(skin, str):
        found = [i for i, s in enumerate(skins) if s.get("name") == skin]
        if len(found) == 1:
            return found[0], skins[found[0]]
        names = [s.get("name") for s in skins if isinstance(s.get("name"), str)]
        if found:
            raise InvalidModel(f"several skins are named {skin!r}: choose by index", joint="skin")
        raise InvalidModel(f"no skin named {skin!r}; the skins are {names[:10]}", joint="skin")
    raise InvalidModel(f"skin must be an index or a name, got {skin!r}", joint="skin")


def _skin_name(skin_doc: dict[str, Any], index: int) -> str:
    name = skin_doc.get("name")
    return name if isinstance(name, str) and name else f"skin_{index}"


def _skin_joints(skin_doc: dict[str, Any], index: int, n_nodes: int) -> list[int]:
    part = f"skins[{index}]"
    joints = skin_doc.get("joints")
    if not isinstance(joints, list) or not joints:
        raise InvalidModel("joints must be a non-empty array", joint=part, field="joints")
    for k, j in enumerate(joints):
        if not _index(j, n_nodes):
            raise InvalidModel(
                f"joints[{k}] = {j!r} is not a node index (0..{n_nodes - 1})",
                joint=part,
                field="joints",
            )
    seen: set[int] = set()
    for j in joints:  # a set, not list.count: a crafted list may be long
        if j in seen:
            raise InvalidModel(f"node {j} is listed twice", joint=part, field="joints")
        seen.add(j)
    root = skin_doc.get("skeleton")
    # Only range-checked: bones take their parents from the node tree, as three.js and
    # Godot do, so a file whose skeleton root is not above every joint still loads.
    if root is not None and not _index(root, n_nodes):
        raise InvalidModel(
            f"skeleton = {root!r} is not a node index (0..{n_nodes - 1})",
            joint=part,
            field="skeleton",
        )
    return list(joints)


# -- transforms ----------------------------------------------------------------


def _numbers(node: dict[str, Any], key: str, count: int, part: str) -> Vector | None:
    value = node.get(key)
    if value is None:
        return None
    if (
        not isinstance(value, list)
        or len(value) != count
        or not all(type(v) in (int, float) for v in value)
    ):
        raise InvalidModel(f"{key} must be {count} numbers", joint=part, field=key)
    arr = np.array(value, dtype=np.float64)
    if not np.isfinite(arr).all():
        raise InvalidModel(f"{key} must be finite", joint=part, field=key)
    return arr


def _uniform(scale: Vector, part: str, field: str) -> float:
    if np.any(scale <= 0.0):
        raise InvalidModel(
            f"scale {scale.tolist()} is zero or mirrors (negative): a rigid chain cannot",
            joint=part,
            field=field,
        )
    if float(scale.max()) > float(scale.min()) * (1.0 + SCALE_TOLERANCE):
        raise InvalidModel(
            f"non-uniform scale {scale.tolist()}: only uniform scale can be folded into a "
            "rigid chain",
            joint=part,
            field=field,
        )
    return float(scale.mean())


def _local(nodes: list[Any], i: int) -> _Local:
    node, part = nodes[i], _node_part(nodes, i)
    matrix = _numbers(node, "matrix", 16, part)
    t = _numbers(node, "translation", 3, part)
    r = _numbers(node, "rotation", 4, part)
    s = _numbers(node, "scale", 3, part)
    if matrix is not None:
        if t is not None or r is not None or s is not None:
            raise InvalidModel(
                "a node has either matrix or translation/rotation/scale, not both",
                joint=part,
                field="matrix",
            )
        return _from_matrix(matrix, part)
    rotation = np.eye(3)
    if r is not None:
        norm = float(np.linalg.norm(r))
        if abs(norm - 1.0) > ROTATION_TOLERANCE:
            raise InvalidModel(
                f"rotation must be a unit quaternion (x, y, z, w), got |q| = {norm:.6g}",
                joint=part,
                field="rotation",
            )
        x, y, z, w = r / norm
        rotation = quaternion_to_matrix(np.array([w, x, y, z]))
    scale = np.ones(3) if s is None else s
    return _Local(np.zeros(3) if t is None else t, rotation, scale, part, "scale")


def _from_matrix(values: Vector, part: str) -> _Local:
    m = values.reshape(4, 4).T  # glTF matrices are column-major
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise InvalidModel(
            "matrix must be affine (last row 0, 0, 0, 1)", joint=part, field="matrix"
        )
    a = m[:3, :3]
    column_scale = np.linalg.norm(a, axis=0)
    if np.any(column_scale < 1e-12) or np.linalg.det(a) <= 0.0:
        raise InvalidModel(
            "matrix is singular or mirrors (negative determinant)", joint=part, field="matrix"
        )
    rotation = a / column_scale
    if not np.allclose(rotation.T @ rotation, np.eye(3), atol=MATRIX_TOLERANCE):
        raise InvalidModel("matrix has shear", joint=part, field="matrix")
    # Re-orthonormalise (SVD) so float32 noise does not reach the chain's strict check.
    u, _, vt = np.linalg.svd(rotation)
    return _Local(m[:3, 3].copy(), u @ vt, column_scale, part, "matrix")


# -- skeleton --------------------------------------------------------------------


def _bone_names(nodes: list[Any], joints: list[int]) -> dict[int, str]:
    names: dict[int, str] = {}
    for j in joints:
        name = nodes[j].get("name")
        if name is not None and not isinstance(name, str):
            raise InvalidModel("name must be a string", joint=f"nodes[{j}]", field="name")
        names[j] = name if name else f"node_{j}"
    counts: dict[str, int] = {}
    for name in names.values():
        counts[name] = counts.get(name, 0) + 1
    return {j: (f"{name}#{j}" if counts[name] > 1 else name) for j, name in names.items()}


def _skeleton(
    nodes: list[Any],
    parent: list[int],
    depth: list[int],
    joints: list[int],
    name: str,
    unit_m: float,
) -> Skeleton:
    joint_set = set(joints)
    names = _bone_names(nodes, joints)
    locals_: dict[int, _Local] = {}
    # Product of the scales of a node and its ancestors, and the file's unit above them.
    cumulative: dict[int, float] = {}

    def local(i: int) -> _Local:
        if i not in locals_:
            locals_[i] = _local(nodes, i)
        return locals_[i]

    def scale_above(i: int) -> float:
        """Product of the scales of i's ancestors (what i's translation is scaled by)."""
        path = []
        node = parent[i]
        while node >= 0 and node not in cumulative:
            path.append(node)
            node = parent[node]
        acc = unit_m if node < 0 else cumulative[node]
        for k in reversed(path):
            acc *= local(k).uniform_scale()
            cumulative[k] = acc
        return unit_m if parent[i] < 0 else cumulative[parent[i]]

    def rigid(i: int) -> Transform:
        loc = local(i)
        return Transform(loc.translation * scale_above(i), loc.rotation)

    bones = []
    # Depth order puts every bone after its parent bone (an ancestor); ties keep skin order.
    for j in sorted(joints, key=lambda k: depth[k]):
        between: list[int] = []
        node = parent[j]
        while node >= 0 and node not in joint_set:
            between.append(node)
            node = parent[node]
        offset = Transform()
        for k in reversed(between):
            step = rigid(k)
            offset = Transform(
                offset.rotation @ step.translation + offset.translation,
                offset.rotation @ step.rotation,
            )
        local(j)  # refuse a bad transform on a leaf bone too (its scale: see the docstring)
        bones.append(
            Bone(
                name=names[j],
                parent=None if node < 0 else names[node],
                rest=rigid(j),
                offset=offset,
            )
        )
    return Skeleton(name, tuple(bones))
