"""read_gltf: the shipped Khronos characters, synthetic documents (named nodes, matrix,
several skins, embedded buffers, scale), and one InvalidModel per hardening check."""

from __future__ import annotations

import base64
import copy
import json
import math
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

from solver.errors import InvalidModel
from solver.model import Effector
from solver.model.gltf import MAX_NODES, read_gltf
from solver.model.skeleton import SkeletonSettings, chain_from_skeleton
from tests.solver.skeleton_refs import (
    GLB_FILES,
    asset_bytes,
    make_glb,
    rigid,
    split_glb,
    world_matrices,
)


def _chain_world(data: bytes | str, **kwargs: Any) -> dict[str, np.ndarray]:
    skeleton = read_gltf(data, **kwargs)
    leaf = skeleton.bones[-1].name
    built = chain_from_skeleton(
        skeleton, SkeletonSettings(effectors=[Effector(name="tip", link=leaf)])
    )
    return built.world_transforms(np.zeros(built.chain.n_dof))


@pytest.mark.parametrize("name", GLB_FILES)
def test_shipped_file_rest_pose_matches_node_math(name: str) -> None:
    data = asset_bytes(name)
    doc, _ = split_glb(data)
    joints = doc["skins"][0]["joints"]
    skeleton = read_gltf(data)
    # Nameless nodes are named by index, every joint is a bone, parents come first.
    assert sorted(skeleton.names) == sorted(f"node_{j}" for j in joints)
    assert skeleton.name == "Armature"
    assert [b.name for b in skeleton.roots] == [f"node_{doc['skins'][0]['skeleton']}"]
    worlds = world_matrices(doc)
    chain_world = _chain_world(data)
    for j in joints:
        assert_allclose(chain_world[f"node_{j}"], rigid(worlds[j]), rtol=0, atol=2e-6)


def test_shipped_files_are_z_up_content_turned_y_up() -> None:
    # RiggedFigure is 1.45 tall along its own Z: its head must end up high along world Y.
    world = _chain_world(asset_bytes("RiggedFigure.glb"))
    heights = [m[1, 3] for m in world.values()]
    assert max(heights) - min(heights) > 1.0
    assert max(abs(m[2, 3]) for m in world.values()) < 0.5


# --- synthetic documents --------------------------------------------------------------


def _rot(axis: str, angle: float) -> list[float]:
    """glTF quaternion (x, y, z, w) about a basis axis."""
    q = [0.0, 0.0, 0.0, math.cos(angle / 2)]
    q["xyz".index(axis)] = math.sin(angle / 2)
    return q


def _doc(**changes: Any) -> dict[str, Any]:
    """Named nodes, a `matrix` node above the skeleton, two skins, an embedded buffer."""
    payload = base64.b64encode(bytes(64)).decode()
    doc: dict[str, Any] = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [
            {  # 0: scene root, a matrix: 90 deg about X and a translation
                "name": "Root",
                "children": [1, 6],
                "matrix": [1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0.5, 0, -0.25, 1],
            },
            {"name": "Armature", "children": [2], "scale": [0.01, 0.01, 0.01]},  # 1: cm
            {  # 2
                "name": "Hips",
                "children": [3, 5],
                "translation": [0, 95, 0],
                "rotation": _rot("y", 0.3),
            },
            {"name": "Spine", "children": [4], "translation": [0, 10, 0], "scale": [2, 2, 2]},
            {"name": "Head", "translation": [0, 20, 1], "rotation": _rot("x", -0.4)},  # 4
            {"name": "Tail", "translation": [0, -5, -8], "rotation": _rot("z", 1.0)},  # 5
            {"name": "Prop", "children": [7]},  # 6: another skin's tree
            {"name": "Lid", "translation": [1, 2, 3]},  # 7
        ],
        "skins": [
            {"name": "Body", "joints": [2, 3, 4, 5], "skeleton": 2},
            {"name": "Prop", "joints": [7]},
        ],
        "buffers": [{"byteLength": 64, "uri": f"data:application/octet-stream;base64,{payload}"}],
    }
    doc.update(changes)
    return doc


def test_named_nodes_matrix_scale_and_a_skin_by_name() -> None:
    doc = _doc()
    text = json.dumps(doc)
    skeleton = read_gltf(text, skin="Body")
    assert skeleton.names == ("Hips", "Spine", "Tail", "Head")
    assert skeleton.bone("Spine").parent == "Hips"
    world = _chain_world(text, skin="Body")
    ref = world_matrices(doc)
    for name, index in (("Hips", 2), ("Spine", 3), ("Head", 4), ("Tail", 5)):
        assert_allclose(world[name], rigid(ref[index]), rtol=0, atol=1e-12)
    # The 0.01 armature scale folds into translations: the hips sit 0.95 m above Root.
    assert_allclose(np.linalg.norm(world["Hips"][:3, 3] - ref[0][:3, 3]), 0.95, atol=1e-12)


def test_the_same_document_as_glb_and_by_index() -> None:
    doc = _doc()
    a = read_gltf(make_glb(doc), skin=1)
    b = read_gltf(json.dumps(doc).encode(), skin="Prop")
    assert a.names == b.names == ("Lid",)
    assert a.name == "Prop"
    # The root bone's offset is the path from the scene root (matrix * Prop).
    assert_allclose(a.bones[0].offset.translation, [0.5, 0.0, -0.25])


def test_intermediate_non_joint_node_folds_into_the_child() -> None:
    doc = _doc()
    doc["skins"][0]["joints"] = [2, 4, 5]  # Spine is no longer a joint
    skeleton = read_gltf(json.dumps(doc))
    assert skeleton.bone("Head").parent == "Hips"
    world = _chain_world(json.dumps(doc))
    assert_allclose(world["Head"], rigid(world_matrices(doc)[4]), rtol=0, atol=1e-12)


def test_duplicate_names_and_nameless_nodes_get_distinct_names() -> None:
    doc = _doc()
    doc["nodes"][3]["name"] = "Hips"
    del doc["nodes"][5]["name"]
    assert read_gltf(json.dumps(doc)).names == ("Hips#2", "Hips#3", "node_5", "Head")


def test_external_buffer_uri_is_not_fetched() -> None:
    doc = _doc(buffers=[{"byteLength": 10_000, "uri": "mesh.bin"}])
    assert read_gltf(json.dumps(doc)).names[0] == "Hips"


# --- errors: truncated and inconsistent containers --------------------------------------


def _error(data: bytes | str, **kwargs: Any) -> InvalidModel:
    with pytest.raises(InvalidModel) as info:
        read_gltf(data, **kwargs)
    return info.value


@pytest.mark.parametrize("keep", [0, 11, 19, 100, 5000, 11047])
def test_truncated_glb(keep: int) -> None:
    data = asset_bytes("RiggedSimple.glb")[:keep]
    err = _error(data)
    if keep >= 4:
        assert err.joint == "glb"
        assert "truncated" in str(err)


def test_buffer_longer_than_the_bin_chunk_or_the_file() -> None:
    doc, bin_chunk = split_glb(asset_bytes("RiggedSimple.glb"))
    for declared in (len(bin_chunk) + 4, 10**9):
        edited = copy.deepcopy(doc)
        edited["buffers"][0]["byteLength"] = declared
        err = _error(make_glb(edited, bin_chunk))
        assert (err.joint, err.field) == ("buffers[0]", "byteLength")
    # A GLB without a BIN chunk whose buffer has no uri.
    err = _error(make_glb(doc))
    assert (err.joint, err.field) == ("buffers[0]", "byteLength")


def test_data_uri_shorter_than_declared() -> None:
    doc = _doc()
    doc["buffers"][0]["byteLength"] = 65
    err = _error(json.dumps(doc))
    assert (err.joint, err.field) == ("buffers[0]", "byteLength")
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64,@@@"
    assert _error(json.dumps(doc)).field == "uri"


def test_header_length_and_chunk_order() -> None:
    data = bytearray(asset_bytes("RiggedSimple.glb"))
    assert _error(bytes(data) + b"\0\0\0\0").field == "length"
    bad_version = bytearray(data)
    bad_version[4] = 1
    assert "version" in str(_error(bytes(bad_version)))
    bin_first = bytearray(data)
    bin_first[16:20] = (0x004E4942).to_bytes(4, "little")
    assert _error(bytes(bin_first)).field == "chunks[0]"


def test_caps_on_size_and_json() -> None:
    data = asset_bytes("RiggedSimple.glb")
    assert _error(data, max_bytes=len(data) - 1).joint == "glb"
    assert _error(data, max_json_bytes=1000).field == "chunks[0]"
    assert _error(b'{"asset": {"version": "2.0"}, "nodes": ' + b"[" * 100_000).joint == "json"
    assert _error('{"asset": {"version": "2.0"}, "x": NaN}').joint == "json"
    assert _error('{"asset": {"version": "1.0"}}').joint == "asset"


# --- errors: the node graph and the skin -------------------------------------------------


def test_cycle_in_children_names_a_node_of_the_cycle() -> None:
    doc, bin_chunk = split_glb(asset_bytes("RiggedFigure.glb"))
    doc["nodes"][6]["children"] = [21]  # 21 -> 2 -> 3 -> 4 -> 5 -> 6 -> 21; 0 loses 21
    doc["nodes"][0]["children"] = [1]
    err = _error(make_glb(doc, bin_chunk))
    assert err.field == "children"
    assert err.joint in {f"nodes[{i}]" for i in (21, 2, 3, 4, 5, 6)}


def test_node_with_two_parents_and_bad_child_indices() -> None:
    doc = _doc()
    doc["nodes"][6]["children"] = [7, 4]
    err = _error(json.dumps(doc))
    assert (err.joint, err.field) == ("nodes[6](Prop)", "children")
    for bad in (8, -1, 1.0, True, "3"):
        doc = _doc()
        doc["nodes"][7]["children"] = [bad]
        assert _error(json.dumps(doc)).joint == "nodes[7](Lid)"
    doc = _doc()
    doc["nodes"][7]["children"] = [7]
    assert "own child" in str(_error(json.dumps(doc)))


@pytest.mark.parametrize("joints", [[2, 3, 99], [2, -1], [], [2, 2], "2", [2.0]])
def test_skin_joint_missing_or_bad(joints: Any) -> None:
    doc, bin_chunk = split_glb(asset_bytes("RiggedFigure.glb"))
    doc["skins"][0]["joints"] = joints
    err = _error(make_glb(doc, bin_chunk))
    assert (err.joint, err.field) == ("skins[0]", "joints")


def test_skeleton_root_is_only_range_checked() -> None:
    doc = _doc()
    doc["skins"][0]["skeleton"] = 6  # not above the joints: ignored, as three.js does
    assert read_gltf(json.dumps(doc)).names[0] == "Hips"
    for bad in (50, -1, "2"):
        doc["skins"][0]["skeleton"] = bad
        err = _error(json.dumps(doc))
        assert (err.joint, err.field) == ("skins[0]", "skeleton")


def test_a_long_joint_list_with_a_duplicate_is_refused_quickly() -> None:
    doc = _doc()
    doc["skins"][0]["joints"] = [2, 3, 4, 5] * 50_000
    err = _error(json.dumps(doc))
    assert (err.joint, err.field) == ("skins[0]", "joints")


def test_choosing_a_skin_that_is_not_there() -> None:
    assert _error(json.dumps(_doc()), skin="Nope").joint == "skin"
    assert _error(json.dumps(_doc()), skin=2).joint == "skin"
    assert _error(json.dumps(_doc(skins=[]))).joint == "skin"


def test_ten_thousand_nodes() -> None:
    nodes = [{"children": [i + 1]} for i in range(9_999)] + [{}]
    doc = _doc(nodes=nodes, skins=[{"joints": [0, 1]}])
    err = _error(json.dumps(doc))
    assert err.field == "nodes"
    assert str(MAX_NODES) in str(err)


def test_a_deep_chain_within_the_node_cap() -> None:
    nodes = [{"children": [i + 1], "translation": [0, 0.1, 0]} for i in range(999)] + [{}]
    doc = _doc(nodes=nodes, skins=[{"joints": list(range(1000))}])
    assert _error(json.dumps(doc)).field == "children"  # deeper than MAX_DEPTH
    skeleton = read_gltf(json.dumps(doc), max_depth=1000)
    assert len(skeleton.bones) == 1000


_NON_UNIFORM = [2, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]


@pytest.mark.parametrize(
    ("node", "field"),
    [
        ({"scale": [1, 2, 1]}, "scale"),
        ({"scale": [-1, -1, -1]}, "scale"),
        ({"scale": [0, 0, 0]}, "scale"),
        ({"rotation": [0, 0, 0, 2]}, "rotation"),
        ({"rotation": [0, 0, 1]}, "rotation"),
        ({"translation": [0, 1e999, 0]}, "translation"),
        ({"translation": [0, "1", 0]}, "translation"),
        (
            {"matrix": [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], "scale": [1, 1, 1]},
            "matrix",
        ),
        ({"matrix": [1, 0, 0, 0, 0.5, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}, "matrix"),  # shear
        ({"matrix": [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}, "matrix"),  # mirror
        ({"matrix": [1, 0, 0, 1, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}, "matrix"),  # projective
        ({"matrix": _NON_UNIFORM}, "matrix"),
    ],
)
def test_bad_transform_names_node_and_field(node: dict[str, Any], field: str) -> None:
    # An ancestor, a joint with a child, and a leaf joint; a scale on a leaf joint scales
    # nothing of the chain and is accepted (test_a_leaf_bones_own_scale_is_left_to_the_engine).
    scale_only = set(node) == {"scale"} or node == {"matrix": _NON_UNIFORM}
    for index in (1, 3) if scale_only else (1, 3, 4):
        doc = _doc()
        kept = {k: v for k, v in doc["nodes"][index].items() if k in ("name", "children")}
        doc["nodes"][index] = {**kept, **node}
        # 1e999 is valid JSON text that parses to inf (json.dumps would write Infinity).
        err = _error(json.dumps(doc).replace("Infinity", "1e999"))
        assert (err.joint, err.field) == (f"nodes[{index}]({kept['name']})", field)


def test_corrupted_files_get_invalid_model_or_load() -> None:
    """Seeded byte flips, truncations and JSON edits: InvalidModel or a skeleton whose
    chain builds, never another exception."""
    rng = np.random.default_rng(20261125)
    data = asset_bytes("RiggedFigure.glb")
    doc, _ = split_glb(data)
    text = json.dumps(doc)
    outcomes = {"refused": 0, "loaded": 0}
    for k in range(300):
        if k % 3 == 0:
            edited = bytearray(data)
            for _ in range(int(rng.integers(1, 8))):
                edited[int(rng.integers(0, 2000))] = int(rng.integers(0, 256))
            sample: bytes | str = bytes(edited)
        elif k % 3 == 1:
            sample = data[: int(rng.integers(0, len(data)))]
        else:
            chars = list(text)
            for _ in range(int(rng.integers(1, 5))):
                chars[int(rng.integers(0, len(chars)))] = str(
                    rng.choice(list('0123456789[]{},:"-.e '))
                )
            sample = "".join(chars)
        try:
            skeleton = read_gltf(sample)
            leaf = skeleton.names[-1]
            chain_from_skeleton(
                skeleton, SkeletonSettings(effectors=[Effector(name="e", link=leaf)])
            )
            outcomes["loaded"] += 1
        except InvalidModel:
            outcomes["refused"] += 1
    assert outcomes["refused"] > 100 and outcomes["loaded"] > 0


def test_documents_without_buffers_as_gltf_and_glb() -> None:
    doc = _doc()
    del doc["buffers"]
    assert read_gltf(json.dumps(doc)).names[0] == "Hips"
    assert read_gltf(make_glb(doc)).names[0] == "Hips"
    # A .glb with a BIN chunk but a buffer that points elsewhere is fine too.
    doc["buffers"] = [{"byteLength": 8, "uri": "data:application/octet-stream;base64,AAAAAAAAAAA="}]
    assert read_gltf(make_glb(doc, b"\0" * 8)).names[0] == "Hips"
