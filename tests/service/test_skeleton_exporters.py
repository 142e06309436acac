"""Skeleton files from other exporters through the API: Blender's dotted bone names and
unicode names in every setting, required glTF extensions, gltfpack's placeholder
buffer, a BVH whose MOTION block is sloppy (the chain reads the hierarchy only).

Answers are checked against the file's own meaning (the glTF node math of
``tests/solver/skeleton_refs.py``; a BVH end site placed by hand)."""

from __future__ import annotations

import base64
import copy
import math
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose
from starlette.testclient import TestClient

from tests.solver.skeleton_refs import make_glb, world_matrices

from .helpers import create

_HALF = math.sqrt(0.5)
# Mixamo-like: a 0.01 armature turned a quarter about X, bones in centimetres, with
# Blender's ".L" names, a colon and a Japanese name.
_NODES: list[dict[str, Any]] = [
    {"name": "Armature", "scale": [0.01] * 3, "rotation": [_HALF, 0, 0, _HALF], "children": [1]},
    {"name": "mixamorig:Hips", "translation": [0, 100, 0], "children": [2, 4]},
    {"name": "thigh.L", "translation": [10, -5, 0], "children": [3]},
    {"name": "ヒザ.L", "translation": [0, -45, 0]},
    {"name": "Spine.001", "translation": [0, 20, 0]},
]
_DOC = {"asset": {"version": "2.0"}, "nodes": _NODES, "skins": [{"joints": [1, 2, 3, 4]}]}


def _chain(doc: dict[str, Any] | None = None, **extra: Any) -> dict[str, Any]:
    return {
        "format": "gltf",
        "gltf": doc or _DOC,
        "effectors": [{"bone": "ヒザ.L", "name": "knee"}],
        **extra,
    }


def test_dotted_and_unicode_bone_names_in_every_setting(client: TestClient) -> None:
    chain = _chain(
        moving=["thigh.L", "mixamorig:Hips"],
        bones={"thigh.L": {"axes": "x", "lower": [-1.0], "upper": [1.0]}},
    )
    s = create(client, chain)
    assert [d["name"] for d in s.body["dof"]] == [
        "mixamorig:Hips.x",
        "mixamorig:Hips.y",
        "mixamorig:Hips.z",
        "thigh.L.x",
    ]
    fk = client.post(
        f"/v1/sessions/{s.id}/fk",
        json={
            "joints": {"thigh.L.x": 0.5, "mixamorig:Hips.y": 0.3},
            "bones": {"local_rotations": True, "world": ["ヒザ.L", "Spine.001"]},
        },
        headers=s.headers,
    )
    assert fk.status_code == 200, fk.text
    body = fk.json()
    # What an engine does with the answer: each local rotation into its node.
    posed = copy.deepcopy(_DOC)
    index = {n["name"]: i for i, n in enumerate(_NODES)}
    for bone, r in body["bones"]["local"].items():
        posed["nodes"][index[bone]]["rotation"] = [r["x"], r["y"], r["z"], r["w"]]
    reference = world_matrices(posed)
    for bone in ("ヒザ.L", "Spine.001"):
        p = body["bones"]["world"][bone]["position"]
        got = [p["x"], p["y"], p["z"]]
        assert_allclose(got, reference[index[bone]][:3, 3], rtol=0, atol=1e-9)
    knee = body["effectors"][0]["position"]
    expected = reference[index["ヒザ.L"]][:3, 3]
    assert_allclose([knee["x"], knee["y"], knee["z"]], expected, rtol=0, atol=1e-9)
    # A DOF name that is not there names the field, whatever the characters.
    bad = client.post(
        f"/v1/sessions/{s.id}/fk", json={"joints": {"thigh.R.x": 0.1}}, headers=s.headers
    )
    assert bad.status_code == 422
    assert bad.json()["field"] == "joints.thigh.R.x"


@pytest.mark.parametrize("as_glb", [False, True])
def test_an_unknown_required_extension_is_a_422_naming_it(client: TestClient, as_glb: bool) -> None:
    doc = {**_DOC, "extensionsRequired": ["KHR_draco_mesh_compression", "ACME_bones"]}
    chain = _chain(doc)
    if as_glb:
        del chain["gltf"]
        chain["glb_base64"] = base64.b64encode(make_glb(doc)).decode()
    r = client.post("/v1/sessions", json={"chain": chain})
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["code"] == "invalid_problem"
    assert body["field"] == ("chain.glb_base64" if as_glb else "chain.gltf.extensionsRequired")
    assert "'ACME_bones'" in body["detail"]


def test_a_gltfpack_glb_with_a_placeholder_buffer_imports(client: TestClient) -> None:
    doc = {
        **_DOC,
        "extensionsUsed": ["EXT_meshopt_compression", "KHR_mesh_quantization"],
        "extensionsRequired": ["EXT_meshopt_compression", "KHR_mesh_quantization"],
        "buffers": [
            {"byteLength": 8},
            {"byteLength": 1024, "extensions": {"EXT_meshopt_compression": {"fallback": True}}},
        ],
    }
    glb = base64.b64encode(make_glb(doc, bytes(8))).decode()
    chain = {"format": "gltf", "glb_base64": glb, "effectors": [{"bone": "ヒザ.L"}]}
    create(client, chain)


_BVH = (
    "HIERARCHY\r\nROOT Hips\r\n{\r\n\tOFFSET 0 90 0\r\n"
    "\tCHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation\r\n"
    "\tJOINT LeftUpLeg\r\n\t{\r\n\t\tOFFSET 10 -5 0\r\n"
    "\t\tCHANNELS 3 Yrotation Xrotation Zrotation\r\n"
    "\t\tEnd Site\r\n\t\t{\r\n\t\t\tOFFSET 0 -40 0\r\n\t\t}\r\n\t}\r\n}\r\n"
)


@pytest.mark.parametrize(
    "motion",
    [
        "MOTION\r\nFrames: 2\r\nFrame Time: 0,033333\r\n0 90 0 0 0 0 0 0 0\r\n",  # comma, short
        "MOTION\r\nFrames: 1\r\nFrame Time: 0.033333\r\n0 90 0 0 0 0 0 0 0\r\n1 2\r\n",  # long
    ],
)
def test_a_bvh_whose_motion_block_is_sloppy_imports(client: TestClient, motion: str) -> None:
    """The chain needs the hierarchy only: the clip's mistakes do not refuse the file."""
    chain = {
        "format": "bvh",
        "bvh": _BVH + motion,
        "unit_m": 0.01,
        "effectors": [{"bone": "LeftUpLeg_end", "name": "foot"}],
    }
    s = create(client, chain, conventions={"unit": "cm"})
    fk = client.post(
        f"/v1/sessions/{s.id}/fk", json={"joints": {"LeftUpLeg.x": 0.7}}, headers=s.headers
    )
    assert fk.status_code == 200, fk.text
    foot = fk.json()["effectors"][0]["position"]
    # Hips at (0, 90, 0) cm, the thigh 10 cm aside and 5 down, the foot 40 cm along
    # the thigh's -Y turned 0.7 rad about X: in the client's centimetres.
    expected = np.array([10.0, 85.0, 0.0]) + 40 * np.array([0.0, -math.cos(0.7), -math.sin(0.7)])
    assert_allclose([foot["x"], foot["y"], foot["z"]], expected, rtol=0, atol=1e-9)
    # The hierarchy is still read strictly.
    broken = {**chain, "bvh": chain["bvh"].replace("CHANNELS 3", "CHANNELS 4")}
    r = client.post("/v1/sessions", json={"chain": broken})
    assert r.status_code == 422
    assert r.json()["field"] == "chain.bvh"


def test_a_bone_named_like_the_free_roots_translation_is_named_in_the_error(
    client: TestClient,
) -> None:
    """A free root's translations are links ``<root>.tx/.ty/.tz``: a bone called so
    was reported as ``chain.effectors[0]: duplicate joint name``."""
    nodes = [{"name": "Hips", "children": [1]}, {"name": "Hips.ty", "translation": [0, 1, 0]}]
    doc = {"asset": {"version": "2.0"}, "nodes": nodes, "skins": [{"joints": [0, 1]}]}
    chain = {"format": "gltf", "gltf": doc, "effectors": [{"bone": "Hips.ty"}]}
    r = client.post("/v1/sessions", json={"chain": {**chain, "free_root": {}}})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == "chain.free_root"
    assert "'Hips.ty'" in r.json()["detail"]
    create(client, chain)  # without a free root there is no clash


def test_a_centimetre_gltf_without_a_scale_node_warns_and_reads_with_unit_m(
    client: TestClient,
) -> None:
    # An exporter that writes centimetres and no 0.01 node: the same armature as _DOC
    # (turned a quarter about X), its bones 100x too long for glTF's metres.
    doc = copy.deepcopy(_DOC)
    del doc["nodes"][0]["scale"]
    as_written = create(client, _chain(doc))
    [warning] = as_written.body["warnings"]
    assert (warning["code"], warning["field"]) == ("unlikely_units", "unit_m")
    assert "centimetres" in warning["message"] and "unit_m" in warning["message"]
    read = create(client, _chain(doc, unit_m=0.01))
    assert read.body["warnings"] == [] and create(client, _chain()).body["warnings"] == []
    pose = {"joints": {"thigh.L.x": 0.5}, "bones": {"world": ["ヒザ.L"]}}
    answers = [
        client.post(f"/v1/sessions/{s.id}/fk", json=pose, headers=s.headers).json()
        for s in (read, create(client, _chain()), as_written)
    ]
    knees = [a["bones"]["world"]["ヒザ.L"]["position"] for a in answers]
    assert_allclose([knees[0][k] for k in "xyz"], [knees[1][k] for k in "xyz"], atol=1e-12)
    assert_allclose([knees[2][k] for k in "xyz"], [100 * knees[1][k] for k in "xyz"], rtol=1e-12)
    bad = client.post("/v1/sessions", json={"chain": _chain(doc, unit_m=0)})
    assert bad.status_code == 422 and bad.json()["field"] == "chain.unit_m", bad.text
