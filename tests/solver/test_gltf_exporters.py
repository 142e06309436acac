"""glTF skeletons as other exporters write them (none of the shared assets is like
these): node matrices, Mixamo's 0.01 armature, Blender's Z-up root, Unity's alternating
100 / 0.01 scales, joints listed children first, scaled leaf bones, required extensions,
gltfpack's placeholder buffer (BVH: test_bvh_exporters.py).

Each document is built here, small, and checked against the file's own meaning: the node
math on the raw JSON (``skeleton_refs.world_matrices``, pytransform3d), with each moving
bone's returned local rotation written into its node the way an engine does.
"""

from __future__ import annotations

import copy
import json
import math
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

from solver.errors import InvalidModel
from solver.model import Effector
from solver.model.gltf import read_gltf
from solver.model.skeleton import SkeletonSettings, chain_from_skeleton
from tests.solver.skeleton_refs import make_glb, node_matrix, rigid, world_matrices

# name, parent: an armature node (not a joint) above a small humanoid.
_BONES = (
    ("Hips", None),
    ("Spine", "Hips"),
    ("Chest", "Spine"),
    ("Arm.L", "Chest"),
    ("Hand.L", "Arm.L"),
    ("Thigh.R", "Hips"),
    ("Foot.R", "Thigh.R"),
    ("Head", "Chest"),
)


def _unit_quaternion(rng: np.random.Generator) -> list[float]:
    q = rng.normal(size=4)
    return (q / np.linalg.norm(q)).tolist()


def _humanoid(rng: np.random.Generator, unit: float = 1.0) -> dict[str, Any]:
    """Node 0 "Armature" above the bones (nodes 1..), random rest TRS; ``unit`` scales
    the translations (100 for a file authored in centimetres)."""
    nodes: list[dict[str, Any]] = [{"name": "Armature", "children": [1]}]
    index = {name: i + 1 for i, (name, _) in enumerate(_BONES)}
    for name, _ in _BONES:
        t = rng.normal(size=3) * 0.3 * unit
        nodes.append({"name": name, "translation": t.tolist(), "rotation": _unit_quaternion(rng)})
    for name, parent in _BONES:
        if parent is not None:
            nodes[index[parent]].setdefault("children", []).append(index[name])
    return {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": nodes,
        "skins": [{"name": "body", "joints": list(index.values()), "skeleton": 1}],
    }


def _as_matrices(doc: dict[str, Any]) -> None:
    """Every node's TRS as one column-major ``matrix`` (COLLADA2GLTF, FBX2glTF)."""
    for node in doc["nodes"]:
        m = node_matrix(node)
        for key in ("translation", "rotation", "scale"):
            node.pop(key, None)
        node["matrix"] = m.T.reshape(-1).tolist()


def _mixamo(doc: dict[str, Any]) -> None:
    # Mixamo via Blender: a 0.01 armature turned a quarter about X over bones in cm.
    half = math.sqrt(0.5)
    doc["nodes"][0].update({"rotation": [half, 0, 0, half], "scale": [0.01] * 3})


def _blender_z_up(doc: dict[str, Any]) -> None:
    half = math.sqrt(0.5)
    doc["nodes"][0]["rotation"] = [-half, 0, 0, half]


def _unity_alternating(doc: dict[str, Any]) -> None:
    # A 0.01 armature, hips at 100 and the spine at 0.01 again: each folds into the
    # translations below it.
    doc["nodes"][0]["scale"] = [0.01] * 3
    doc["nodes"][1]["scale"] = [100.0] * 3
    doc["nodes"][2]["scale"] = [0.01] * 3


def _children_first(doc: dict[str, Any]) -> None:
    doc["skins"][0]["joints"].reverse()


def _float32_scale(doc: dict[str, Any]) -> None:
    doc["nodes"][0]["scale"] = [1.0000001, 0.99999994, 1.0]


def _scenes_and_skins(doc: dict[str, Any]) -> None:
    # No default scene, an empty scene first, the hand and arm in a second skin too.
    del doc["scene"]
    doc["scenes"].insert(0, {"nodes": []})
    doc["skins"].append({"name": "gloves", "joints": [5, 4]})


VARIANTS = {
    "no_scene_and_a_joint_in_two_skins": (_scenes_and_skins, 1.0),
    "trs": (lambda doc: None, 1.0),
    "matrix": (_as_matrices, 1.0),
    "mixamo_armature": (_mixamo, 100.0),
    "blender_z_up_root": (_blender_z_up, 1.0),
    "unity_alternating_scales": (_unity_alternating, 100.0),
    "joints_children_first": (_children_first, 1.0),
    "float32_scale_noise": (_float32_scale, 1.0),
}


def _engine_pose(doc: dict[str, Any], bone_nodes: dict[str, int], quats: dict[str, Any]) -> Any:
    """The document with each bone's node rotation replaced, as an engine applies it: a
    ``matrix`` node is first split into T, R, S (three.js ``decompose``), T and S kept."""
    posed = copy.deepcopy(doc)
    for bone, (w, x, y, z) in quats.items():
        node = posed["nodes"][bone_nodes[bone]]
        if "matrix" in node:
            m = np.array(node.pop("matrix"), dtype=float).reshape(4, 4).T
            node["translation"] = m[:3, 3].tolist()
            node["scale"] = np.linalg.norm(m[:3, :3], axis=0).tolist()
        node["rotation"] = [x, y, z, w]
    return posed


def _check_against_node_math(doc: dict[str, Any], rng: np.random.Generator) -> None:
    skeleton = read_gltf(json.dumps(doc))
    names = {n["name"]: i for i, n in enumerate(doc["nodes"])}
    bone_nodes = {b: names[b] for b in skeleton.names}
    parent = {c: i for i, n in enumerate(doc["nodes"]) for c in n.get("children", [])}
    built = chain_from_skeleton(
        skeleton, SkeletonSettings(effectors=[Effector(name="tip", link="Hand.L")])
    )
    poses = [np.zeros(built.chain.n_dof)]
    poses += [rng.uniform(-3.0, 3.0, built.chain.n_dof) for _ in range(3)]
    for q in poses:
        quats = dict(zip(built.moving, built.local_rotations(q), strict=True))
        posed = _engine_pose(doc, bone_nodes, quats)
        reference = world_matrices(posed)
        world = built.world_transforms(q)
        for bone, node in bone_nodes.items():
            # Positions to a micrometre of a metre-sized figure.
            assert_allclose(world[bone][:3, 3], reference[node][:3, 3], rtol=0, atol=1e-6)
            # The bone's frame: its parent's, scale divided out, turned by its rotation
            # (its own scale, zero or mirroring on a leaf, is no part of it).
            above = rigid(reference[parent[node]])[:3, :3] if node in parent else np.eye(3)
            turn = node_matrix({"rotation": posed["nodes"][node]["rotation"]})[:3, :3]
            assert_allclose(world[bone][:3, :3], above @ turn, rtol=0, atol=1e-6)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_exporter_variant_matches_the_node_math(variant: str, rng: np.random.Generator) -> None:
    edit, unit = VARIANTS[variant]
    doc = _humanoid(rng, unit)
    edit(doc)
    _check_against_node_math(doc, rng)


@pytest.mark.parametrize("scale", [[1.0, 2.0, 1.0], [0.0, 0.0, 0.0], [-1.0, 1.0, 1.0]])
def test_a_leaf_bones_own_scale_is_left_to_the_engine(
    scale: list[float], rng: np.random.Generator
) -> None:
    """A hidden prop bone scaled to 0, a stretched or mirrored tip: nothing of the chain
    is below it, so it loads and every bone, that one too, is where the file puts it."""
    doc = _humanoid(rng)
    hand = next(i for i, n in enumerate(doc["nodes"]) if n["name"] == "Hand.L")
    assert "children" not in doc["nodes"][hand]
    doc["nodes"][hand]["scale"] = scale
    _check_against_node_math(doc, rng)
    # The same scale on a bone with a bone below it cannot be folded into a rigid chain.
    doc["nodes"][hand]["scale"] = [1.0, 1.0, 1.0]
    arm = next(i for i, n in enumerate(doc["nodes"]) if n["name"] == "Arm.L")
    doc["nodes"][arm]["scale"] = scale
    with pytest.raises(InvalidModel) as info:
        read_gltf(json.dumps(doc))
    assert (info.value.joint, info.value.field) == (f"nodes[{arm}](Arm.L)", "scale")


# --- extensions and buffers -----------------------------------------------------------


@pytest.mark.parametrize(
    "required",
    [
        ["KHR_draco_mesh_compression"],
        ["KHR_mesh_quantization", "EXT_meshopt_compression"],
        ["KHR_texture_basisu", "KHR_materials_variants", "EXT_texture_webp"],
    ],
)
def test_required_extensions_of_meshes_and_materials_are_accepted(
    required: list[str], rng: np.random.Generator
) -> None:
    doc = _humanoid(rng)
    doc["extensionsUsed"] = doc["extensionsRequired"] = required
    assert len(read_gltf(json.dumps(doc)).bones) == len(_BONES)


@pytest.mark.parametrize(
    ("required", "message"),
    [
        (["KHR_draco_mesh_compression", "ACME_node_transform"], "'ACME_node_transform'"),
        (["KHR_draco_mesh_compression", 7], "array of strings"),
    ],
)
def test_an_unknown_required_extension_is_refused_by_name(
    required: list[Any], message: str, rng: np.random.Generator
) -> None:
    doc = _humanoid(rng)
    doc["extensionsRequired"] = required
    for data in (json.dumps(doc), make_glb(doc)):
        with pytest.raises(InvalidModel, match=message) as info:
            read_gltf(data)
        assert (info.value.joint, info.value.field) == ("json", "extensionsRequired")
    doc["extensionsUsed"] = ["ACME_node_transform"]  # used, not required: loads
    del doc["extensionsRequired"]
    assert len(read_gltf(json.dumps(doc)).bones) == len(_BONES)


def test_gltfpack_placeholder_buffer_and_a_data_uri_beside_the_bin_chunk(
    rng: np.random.Generator,
) -> None:
    """gltfpack -c: buffer 0 the BIN chunk, buffer 1 meshopt's placeholder (no uri)."""
    doc = _humanoid(rng)
    doc["extensionsUsed"] = doc["extensionsRequired"] = ["EXT_meshopt_compression"]
    doc["buffers"] = [
        {"byteLength": 16},
        {"byteLength": 4096, "extensions": {"EXT_meshopt_compression": {"fallback": True}}},
        {"byteLength": 3, "uri": "data:application/octet-stream;base64,AAAA"},
    ]
    assert len(read_gltf(make_glb(doc, bytes(16))).bones) == len(_BONES)
    # A .gltf may have placeholders too; without the extension required, a buffer
    # without uri is a missing file.
    assert len(read_gltf(json.dumps({**doc, "buffers": doc["buffers"][1:]})).bones) == 8
    del doc["extensionsRequired"]
    with pytest.raises(InvalidModel, match="EXT_meshopt_compression") as info:
        read_gltf(make_glb(doc, bytes(16)))
    assert (info.value.joint, info.value.field) == ("buffers[1]", "uri")


def test_a_centimetre_file_read_with_unit_m_is_the_metre_file() -> None:
    metres = _humanoid(np.random.default_rng(5))
    centimetres = _humanoid(np.random.default_rng(5), unit=100.0)
    expected = read_gltf(json.dumps(metres)).rest_origins()
    scaled = read_gltf(json.dumps(centimetres), unit_m=0.01).rest_origins()
    as_written = read_gltf(json.dumps(centimetres)).rest_origins()
    for name, origin in expected.items():
        assert_allclose(scaled[name], origin, rtol=0, atol=1e-12)
        assert_allclose(as_written[name], 100.0 * origin, rtol=1e-12, atol=1e-12)
    with pytest.raises(InvalidModel, match="unit_m"):
        read_gltf(json.dumps(metres), unit_m=float("nan"))


@pytest.mark.parametrize(
    ("unit", "unit_m", "noted"),
    [(100.0, 1.0, True), (100.0, 0.01, False), (1.0, 1.0, False), (1.0, 0.01, True)],
)
def test_a_skeleton_too_large_or_small_for_a_character_is_noted(
    unit: float, unit_m: float, noted: bool
) -> None:
    doc = _humanoid(np.random.default_rng(5), unit=unit)
    skeleton = read_gltf(json.dumps(doc), unit_m=unit_m)
    settings = SkeletonSettings(effectors=[Effector(name="hand", link="Hand.L")])
    notes = chain_from_skeleton(skeleton, settings).chain.notes
    assert [(n.kind.value, n.field) for n in notes] == (
        [("unlikely_units", "unit_m")] if noted else []
    )
