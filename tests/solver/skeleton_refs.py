"""Test-only helpers for the skeleton importers: the shared asset files, GLB editing, and
reference forward kinematics that share no code with ``solver.model`` (pytransform3d and
the glTF node math on the raw JSON)."""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import pytransform3d.rotations as pr
import pytransform3d.transformations as pt

REPO = Path(__file__).resolve().parents[2]
GLB_FILES = ("RiggedSimple.glb", "RiggedFigure.glb", "CesiumMan.glb")
BVH_FILE = "walk.bvh"
# The CMU/cgspeed unit, about an inch / 0.45 (shared/assets/README.md; an assumption).
WALK_UNIT_M = 0.0254 / 0.45


def assets_dir() -> Path:
    """The shared asset folder: $IK_SHARED_ASSETS, else ``shared/assets`` beside a parent
    of the repository (``/work/shared/assets`` for ``/work/main`` and worktrees)."""
    env = os.environ.get("IK_SHARED_ASSETS")
    candidates = [Path(env)] if env else [p / "shared" / "assets" for p in REPO.parents]
    for path in candidates:
        if (path / BVH_FILE).is_file():
            return path
    message = "shared skeleton assets not found (set IK_SHARED_ASSETS)"
    if os.environ.get("CI") == "true":  # CI clones main with ../shared beside it
        pytest.fail(message)
    pytest.skip(message)


def asset_bytes(name: str) -> bytes:
    return (assets_dir() / name).read_bytes()


def walk_text() -> str:
    # newline="" keeps the file's mixed CRLF / LF line endings for the parser.
    with open(assets_dir() / BVH_FILE, encoding="ascii", newline="") as f:
        return f.read()


# --- GLB container --------------------------------------------------------------------


def split_glb(data: bytes) -> tuple[dict[str, Any], bytes]:
    """The JSON document and the BIN chunk of a GLB (no checks: the files are valid)."""
    json_len = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + json_len])
    rest = data[20 + json_len :]
    bin_chunk = b""
    if rest:
        bin_len = struct.unpack_from("<I", rest, 0)[0]
        bin_chunk = rest[8 : 8 + bin_len]
    return doc, bin_chunk


def make_glb(doc: dict[str, Any], bin_chunk: bytes = b"") -> bytes:
    """A GLB from a JSON document and a BIN chunk, padded as the spec asks."""
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    out = struct.pack("<II", len(js), 0x4E4F534A) + js
    if bin_chunk:
        bin_chunk += b"\0" * (-len(bin_chunk) % 4)
        out += struct.pack("<II", len(bin_chunk), 0x004E4942) + bin_chunk
    return struct.pack("<4sII", b"glTF", 2, 12 + len(out)) + out


# --- glTF node math ---------------------------------------------------------------------


def node_matrix(node: dict[str, Any]) -> np.ndarray:
    """A node's local 4x4 matrix: ``matrix`` (column-major) or T * R * S (spec 5.25)."""
    if "matrix" in node:
        return np.array(node["matrix"], dtype=float).reshape(4, 4).T
    x, y, z, w = node.get("rotation", [0.0, 0.0, 0.0, 1.0])
    q = np.array([w, x, y, z]) / np.linalg.norm([w, x, y, z])
    m = pt.transform_from(pr.matrix_from_quaternion(q), node.get("translation", [0.0, 0.0, 0.0]))
    return m @ np.diag([*node.get("scale", [1.0, 1.0, 1.0]), 1.0])


def world_matrices(doc: dict[str, Any]) -> dict[int, np.ndarray]:
    """Every node's world matrix, composed from the scene roots down."""
    nodes = doc["nodes"]
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}
    out: dict[int, np.ndarray] = {}

    def world(i: int) -> np.ndarray:
        if i not in out:
            local = node_matrix(nodes[i])
            out[i] = world(parent[i]) @ local if i in parent else local
        return out[i]

    for i in range(len(nodes)):
        world(i)
    return out


def rigid(m: np.ndarray) -> np.ndarray:
    """A world matrix with its (uniform) scale divided out of the rotation columns."""
    out = m.copy()
    out[:3, :3] /= np.linalg.norm(m[:3, :3], axis=0)
    return out


# --- BVH -------------------------------------------------------------------------------


def bvh_world_positions(
    skeleton: Any, frame_degrees: np.ndarray, unit_m: float
) -> dict[str, np.ndarray]:
    """World position of every bone for one MOTION line (raw values, degrees and file
    units), through pytransform3d: T(offset, position channels replacing it) then the
    rotation channels as intrinsic Euler angles in their listed order."""
    axis = {"x": 0, "y": 1, "z": 2}
    world: dict[str, np.ndarray] = {}
    column = 0
    for bone in skeleton.bones:
        p = bone.rest.translation.copy()  # the OFFSET, already in metres
        angles, order = [], []
        for channel in bone.channels:
            value = float(frame_degrees[column])
            column += 1
            if channel.value.endswith("position"):
                p[axis[channel.value[0].lower()]] = value * unit_m
            else:
                angles.append(np.radians(value))
                order.append(axis[channel.value[0].lower()])
        r = np.eye(3)
        if len(order) == 3:
            i, j, k = order
            r = pr.matrix_from_euler(angles, i, j, k, False)  # intrinsic
        else:  # fewer than three: compose the active basic rotations by hand
            for a, k in zip(angles, order, strict=True):
                r = r @ pr.active_matrix_from_angle(k, a)
        local = pt.transform_from(r, p)
        world[bone.name] = world[bone.parent] @ local if bone.parent else local
    return {name: m[:3, 3] for name, m in world.items()}
