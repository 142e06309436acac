"""glTF and BVH skeleton chains through the API: import, per-bone settings, bad input.

The shared assets (tests/solver/skeleton_refs.py finds them) are real files; the bad
inputs are edits of them or small synthetic documents.
"""

from __future__ import annotations

import base64
import copy
from typing import Any

import numpy as np
import pytest
from starlette.testclient import TestClient

from schemas.chain import EXAMPLE_BVH_LEG, EXAMPLE_GLTF_LEG
from service.errors import field_path
from tests.solver.skeleton_refs import (
    GLB_FILES,
    WALK_UNIT_M,
    asset_bytes,
    make_glb,
    split_glb,
    walk_text,
)

from .helpers import create

# A hand and a foot of each asset (RiggedSimple has two bones: its tip bone).
# RiggedFigure / CesiumMan: node 18 arm_joint_L_3, node 10 leg_joint_L_5
# (shared/assets/README.md); the 2017 files have no node names.
HAND_FOOT = {
    "RiggedSimple.glb": ["node_3"],
    "RiggedFigure.glb": ["node_18", "node_10"],
    "CesiumMan.glb": ["node_18", "node_10"],
    "walk.bvh": ["LeftHand", "RightFoot"],
}


def glb_chain(name: str, **settings: Any) -> dict[str, Any]:
    bones = settings.pop("effector_bones", HAND_FOOT[name])
    return {
        "format": "gltf",
        "glb_base64": base64.b64encode(asset_bytes(name)).decode(),
        "effectors": [{"bone": b} for b in bones],
        **settings,
    }


def walk_chain(**settings: Any) -> dict[str, Any]:
    return {
        "format": "bvh",
        "bvh": walk_text(),
        "unit_m": WALK_UNIT_M,
        "effectors": [{"bone": b} for b in HAND_FOOT["walk.bvh"]],
        **settings,
    }


def error(client: TestClient, chain: dict[str, Any], **extra: Any) -> dict[str, Any]:
    r = client.post("/v1/sessions", json={"chain": chain, **extra})
    assert r.status_code == 422, r.text
    body: dict[str, Any] = r.json()
    return body


# --- every asset imports ----------------------------------------------------------------
@pytest.mark.parametrize("name", GLB_FILES)
def test_every_glb_asset_imports_and_its_hand_reaches_a_target(
    client: TestClient, name: str
) -> None:
    # The largest time budget: this checks reach, not speed (shared, busy test cores).
    s = create(client, glb_chain(name), options={"time_budget_us": 50_000})
    assert [e["name"] for e in s.body["effectors"]] == HAND_FOOT[name]
    fk = client.post(
        f"/v1/sessions/{s.id}/fk", json={"bones": {"world": HAND_FOOT[name]}}, headers=s.headers
    )
    assert fk.status_code == 200, fk.text
    # A target placed by FK of another pose of the character: within reach.
    q = np.array(fk.json()["q"]) + 0.2
    moved = client.post(
        f"/v1/sessions/{s.id}/fk",
        json={"q": q.tolist(), "bones": {"world": HAND_FOOT[name]}},
        headers=s.headers,
    ).json()["bones"]["world"]
    targets = [{"effector": b, "position": moved[b]["position"]} for b in HAND_FOOT[name]]
    r = client.post(f"/v1/sessions/{s.id}/frames", json={"targets": targets}, headers=s.headers)
    assert r.json()["results"][0]["success"] is True, r.text


def test_walk_bvh_imports_with_a_free_root(client: TestClient) -> None:
    s = create(client, walk_chain(free_root={}))
    names = [d["name"] for d in s.body["dof"]]
    assert names[:3] == ["Hips.tx", "Hips.ty", "Hips.tz"]
    assert "LeftUpLeg.z" in names and "LeftHand_end.x" not in names  # End Sites stay fixed


def test_gltf_json_document_imports_like_its_glb(client: TestClient) -> None:
    doc, _ = split_glb(asset_bytes("RiggedFigure.glb"))
    del doc["buffers"]  # no buffer data is read; the accessors that use it are unused
    for key in ("bufferViews", "accessors", "meshes", "animations", "images", "textures"):
        doc.pop(key, None)
    for node in doc["nodes"]:
        node.pop("mesh", None)
    doc["skins"][0].pop("inverseBindMatrices", None)
    chain = {"format": "gltf", "gltf": doc, "effectors": [{"bone": "node_18"}]}
    from_json = create(client, chain)
    from_glb = create(client, glb_chain("RiggedFigure.glb", effector_bones=["node_18"]))
    assert from_json.body["dof"] == from_glb.body["dof"]


def test_one_shot_solve_takes_a_skeleton(client: TestClient) -> None:
    r = client.post(
        "/v1/solve",
        json={
            "chain": EXAMPLE_GLTF_LEG,
            "targets": [{"effector": "foot", "position": {"x": 0.1, "y": 0.3, "z": 0.2}}],
            "bones": {"local_rotations": True, "world": ["ankle"]},
        },
    )
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["success"] is True
    ankle = body["bones"]["world"]["ankle"]["position"]
    assert np.allclose([ankle["x"], ankle["y"], ankle["z"]], [0.1, 0.3, 0.2], atol=1e-3)
    assert set(body["bones"]["local"]) == {"hip", "knee"}


# --- per-bone settings -------------------------------------------------------------------
def test_moving_axes_limits_and_tip_offset_shape_the_chain(client: TestClient) -> None:
    chain = {
        **EXAMPLE_BVH_LEG,
        "moving": ["LeftUpLeg", "LeftLeg"],
        "bones": {
            "LeftUpLeg": {"axes": "zx"},
            "LeftLeg": {"axes": "x", "lower": [-2.5], "upper": [0.0]},
        },
        "effectors": [
            {"bone": "LeftLeg", "name": "heel", "tip_offset": {"x": 0.0, "y": -0.45, "z": -0.05}}
        ],
    }
    s = create(client, chain)
    dof = {d["name"]: (d["lower"], d["upper"]) for d in s.body["dof"]}
    assert list(dof) == ["LeftUpLeg.z", "LeftUpLeg.x", "LeftLeg.x"]
    assert dof["LeftLeg.x"] == (-2.5, 0.0)
    assert dof["LeftUpLeg.z"] == (-2 * np.pi, 2 * np.pi)  # the default ball range
    fk = client.post(
        f"/v1/sessions/{s.id}/fk",
        json={"q": [0.0, 0.0, 0.0], "bones": {"world": ["LeftLeg"]}},
        headers=s.headers,
    )
    knee = fk.json()["bones"]["world"]["LeftLeg"]["position"]
    assert np.allclose([knee["x"], knee["y"], knee["z"]], [0.1, -0.45, 0.0])


def test_a_terminator_keeps_the_bones_above_it_still(client: TestClient) -> None:
    chain = {**EXAMPLE_GLTF_LEG, "bones": {"knee": {"axes": "x", "terminator": True}}}
    s = create(client, chain)
    r = client.post(
        f"/v1/sessions/{s.id}/frames",
        json={"targets": [{"effector": "foot", "position": {"x": 0.0, "y": 0.2, "z": 0.3}}]},
        headers=s.headers,
    )
    joints = r.json()["results"][0]["joints"]
    assert all(joints[f"hip.{a}"] == s.body["pose"]["joints"][f"hip.{a}"] for a in "xyz")


# --- bad input: a 422 naming the part ----------------------------------------------------
def _glb_with(edit: Any) -> str:
    doc, bin_chunk = split_glb(asset_bytes("RiggedFigure.glb"))
    edit(doc)
    return base64.b64encode(make_glb(doc, bin_chunk)).decode()


def _cycle(doc: dict[str, Any]) -> None:
    # Node 2 (the skeleton's root joint) moves from its parent (node 21) under its own
    # child, node 3: 2 -> 3 -> 2, each node with one parent.
    doc["nodes"][21]["children"].remove(2)
    doc["nodes"][3]["children"] = [*doc["nodes"][3].get("children", []), 2]


def _two_parents(doc: dict[str, Any]) -> None:
    doc["nodes"][3]["children"] = [*doc["nodes"][3].get("children", []), 2]


def _missing_joint(doc: dict[str, Any]) -> None:
    doc["skins"][0]["joints"][4] = 999


def _long_buffer(doc: dict[str, Any]) -> None:
    doc["buffers"][0]["byteLength"] += 1_000


@pytest.mark.parametrize(
    ("glb", "words"),
    [
        (lambda: base64.b64encode(asset_bytes("RiggedFigure.glb")[:4000]).decode(), "truncated"),
        (lambda: _glb_with(_long_buffer), "buffers[0].byteLength"),
        (lambda: _glb_with(_cycle), "cycle"),
        (lambda: _glb_with(_two_parents), "already has parent"),
        (lambda: _glb_with(_missing_joint), "skins[0].joints"),
    ],
    ids=["truncated", "buffer-longer-than-file", "cycle", "two-parents", "skin-joint-missing"],
)
def test_bad_glb_files_are_422_naming_the_part(client: TestClient, glb: Any, words: str) -> None:
    chain = {"format": "gltf", "glb_base64": glb(), "effectors": [{"bone": "node_18"}]}
    body = error(client, chain)
    assert body["code"] == "invalid_problem"
    assert body["field"] == "chain.glb_base64"
    assert words in body["detail"], body


def test_a_10000_node_document_is_refused(client: TestClient) -> None:
    nodes = [{"children": [i + 1]} for i in range(9_999)] + [{}]
    doc = {"asset": {"version": "2.0"}, "nodes": nodes, "skins": [{"joints": [0, 1]}]}
    body = error(client, {"format": "gltf", "gltf": doc, "effectors": [{"bone": "node_1"}]})
    assert body["code"] == "invalid_problem" and body["field"] == "chain.gltf.nodes"
    assert "4096" in body["detail"], body


def test_gltf_json_errors_name_the_node_field(client: TestClient) -> None:
    chain = copy.deepcopy(EXAMPLE_GLTF_LEG)
    chain["gltf"]["nodes"][1]["scale"] = [1.0, 2.0, 1.0]
    body = error(client, chain)
    assert body["field"] == "chain.gltf.nodes[1].scale", body


def test_gltf_document_errors_name_the_member(client: TestClient) -> None:
    chain = copy.deepcopy(EXAMPLE_GLTF_LEG)
    chain["gltf"]["skins"] = {"joints": [0, 1]}
    body = error(client, chain)
    assert body["field"] == "chain.gltf.skins" and "must be an array" in body["detail"], body


def test_bad_base64_is_invalid_format(client: TestClient) -> None:
    body = error(client, {"format": "gltf", "glb_base64": "gl!TF", "effectors": [{"bone": "a"}]})
    assert (body["code"], body["field"]) == ("invalid_format", "chain.glb_base64")


@pytest.mark.parametrize(
    ("encode", "words"),
    [
        # a browser's FileReader.readAsDataURL, sent whole
        (lambda b64: "data:model/gltf-binary;base64," + b64, "data URL"),
        # the URL-safe alphabet (base64url)
        (lambda b64: b64.replace("+", "-").replace("/", "_"), "URL-safe"),
    ],
)
def test_base64_a_client_got_wrong_says_how(client: TestClient, encode: Any, words: str) -> None:
    b64 = glb_chain("CesiumMan.glb")["glb_base64"]
    assert "+" in b64 and "/" in b64  # else the URL-safe case would decode
    chain = glb_chain("CesiumMan.glb", glb_base64=encode(b64))
    body = error(client, chain)
    assert (body["code"], body["field"]) == ("invalid_format", "chain.glb_base64"), body
    assert words in body["detail"], body


def test_unknown_bone_names_say_which_setting_and_suggest(client: TestClient) -> None:
    body = error(client, walk_chain(effectors=[{"bone": "LeftHnd"}]))
    assert body["field"] == "chain.effectors[0].bone"
    assert "LeftHand" in body["detail"]
    body = error(client, walk_chain(moving=["Hips", "Spine9"]))
    assert body["field"] == "chain.moving[1]"
    body = error(client, walk_chain(bones={"Nek": {"axes": "x"}}))
    assert body["field"] == "chain.bones.Nek"
    body = error(client, walk_chain(), bones={"world": ["Hed"]})
    assert body["field"] == "bones.world[0]"
    # Where, then what: no "Hed.world:" of the solver's own in between.
    assert body["detail"].startswith("bones.world[0]: unknown bone 'Hed'; did you mean 'Head'")


def test_a_bad_effector_setting_names_the_effector_and_the_setting(client: TestClient) -> None:
    # A game client's zero aim axis, or weights that leave nothing to solve, on its
    # second effector: the field says which effector and which setting, as a JSON
    # chain's error does, not just "chain.effectors".
    hand = {"bone": "LeftHand"}
    body = error(
        client,
        walk_chain(
            effectors=[hand, {"bone": "Head", "mode": "aim", "aim_axis": {"x": 0, "y": 0, "z": 0}}]
        ),
    )
    assert (body["code"], body["field"]) == ("invalid_problem", "chain.effectors[1].aim_axis")
    assert "axis must not be zero" in body["detail"], body
    body = error(
        client, walk_chain(effectors=[hand, {"bone": "Head", "name": "look", "position_weight": 0}])
    )
    assert body["field"] == "chain.effectors[1].position_weight", body


def test_only_the_chain_s_own_format_leaves_a_field() -> None:
    # A bone named "chain" whose settings hold a key named like a format keeps both.
    loc = ["body", "chain", "bvh", "bones", "chain", "urdf"]
    assert field_path(loc) == "chain.bones.chain.urdf"
    assert field_path(["body", "chain", "hierarchy", "joints", 0]) == "chain.joints[0]"


def test_a_field_path_brackets_list_indices_only() -> None:
    # As the chain's and the solver's errors write a field: an index (an int in loc)
    # in brackets, a map key dotted even when it reads as a number (a joint named "0").
    assert field_path(["body", "frame", "targets", 0, "position", "x"]) == (
        "frame.targets[0].position.x"
    )
    assert field_path(["body", "joints", "0"]) == "joints.0"
    assert field_path(["frames", 2, 1]) == "frames[2][1]"
    assert field_path(["body"]) is None


def test_a_schema_error_names_the_chain_s_field_not_its_format(client: TestClient) -> None:
    """pydantic's location holds the chain's format (``chain.bvh.unit_m``), which reads
    as a field inside the BVH text: the field named is the one the request has."""
    body = error(client, walk_chain(unit_m=0))
    assert (body["code"], body["field"]) == ("invalid_format", "chain.unit_m"), body
    body = error(client, walk_chain(effectors=[{"bone": "LeftHand", "mode": "poze"}]))
    assert body["field"] == "chain.effectors[0].mode", body
    body = error(client, {"format": "bvh", "effectors": [{"bone": "Head"}]})  # no text
    assert body["field"] == "chain.bvh", body


def test_an_unknown_bone_like_no_other_lists_the_bones_there_are(client: TestClient) -> None:
    # CesiumMan's nodes have no names: its bones are node_<index>, which an engine's
    # "LeftHand" resembles too little for a suggestion.
    body = error(client, glb_chain("CesiumMan.glb", effector_bones=["LeftHand"]))
    assert body["field"] == "chain.effectors[0].bone", body
    assert "bones are 'node_2', 'node_11'" in body["detail"], body
    assert "(19 in all)" in body["detail"], body


def test_limits_in_degrees_and_bad_settings_are_named(client: TestClient) -> None:
    body = error(client, walk_chain(bones={"LeftLeg": {"lower": [-150.0], "upper": [0.0]}}))
    assert body["field"] == "chain.bones.LeftLeg.lower" and "radians" in body["detail"]
    body = error(client, walk_chain(bones={"LeftLeg": {"axes": "zy", "lower": [0.0]}}))
    assert body["field"].startswith("chain.bones.LeftLeg"), body
    body = error(client, walk_chain(bones={"LeftLeg": {"axes": "zz"}}))
    assert body["field"] == "chain.bones.LeftLeg.axes", body


def test_bad_bvh_names_the_line(client: TestClient) -> None:
    text = EXAMPLE_BVH_LEG["bvh"].replace("CHANNELS 3 Zrotation", "CHANNELS 4 Zrotation", 1)
    body = error(client, {**EXAMPLE_BVH_LEG, "bvh": text})
    assert body["field"] == "chain.bvh" and "line 9" in body["detail"], body


def test_bone_output_on_a_chain_without_bones_is_refused(client: TestClient) -> None:
    body = error(client, {"format": "example", "name": "panda_arm"}, bones={"world": ["x"]})
    assert body["field"] == "bones" and "gltf or bvh" in body["detail"]


def test_a_skeleton_over_the_body_limit_is_413(make_client: Any) -> None:
    from service.config import Settings

    small = make_client(Settings(max_body_bytes=100_000))
    r = small.post("/v1/sessions", json={"chain": glb_chain("CesiumMan.glb")})
    assert r.status_code == 413 and r.json()["code"] == "payload_too_large"


def test_a_gltf_document_with_an_embedded_buffer_and_a_skin_by_name(client: TestClient) -> None:
    doc, bin_chunk = split_glb(asset_bytes("RiggedSimple.glb"))
    doc["buffers"][0]["uri"] = (
        "data:application/octet-stream;base64," + base64.b64encode(bin_chunk).decode()
    )
    chain = {"format": "gltf", "gltf": doc, "skin": "Armature", "effectors": [{"bone": "node_3"}]}
    s = create(client, chain)
    assert [d["name"] for d in s.body["dof"]][:3] == ["node_2.x", "node_2.y", "node_2.z"]
    body = error(client, {**chain, "skin": "Armature.001"})
    assert body["field"] == "chain.skin", body
    doc["buffers"][0]["byteLength"] += 100  # longer than its data
    body = error(client, {**chain, "gltf": doc})
    assert body["field"].startswith("chain.gltf.buffers[0]"), body


def test_translations_beyond_a_thousand_km_are_refused(client: TestClient) -> None:
    bvh = EXAMPLE_BVH_LEG["bvh"].replace("OFFSET 10 0 0", "OFFSET 1e300 0 0")
    body = error(client, {**EXAMPLE_BVH_LEG, "bvh": bvh})
    assert body["field"] == "chain.bvh" and "LeftUpLeg" in body["detail"], body
    assert "unit_m" in body["detail"], body
    chain = copy.deepcopy(EXAMPLE_GLTF_LEG)
    chain["gltf"]["nodes"][1]["translation"] = [0.0, -1e7, 0.0]
    body = error(client, chain)
    assert body["field"] == "chain.gltf" and "knee" in body["detail"], body
    # glTF is metres by its specification, but a file may not be: unit_m is advised.
    assert "unit_m" in body["detail"], body


def _nan_token_body(path: str, chain: dict[str, Any]) -> bytes:
    """A request body as Python's json.dumps (and some exporters) write it: NaN as a
    bare token, which the body's parser reads."""
    import json

    foot = [{"effector": "foot", "position": {"x": 0.1, "y": 0.3, "z": 0.2}}]
    body = {"chain": chain} if path == "/v1/sessions" else {"chain": chain, "targets": foot}
    return json.dumps(body).encode()


@pytest.mark.parametrize("path", ["/v1/sessions", "/v1/solve"])
@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (
            lambda d: d.setdefault("extras", {}).update(weight=float("nan")),
            "chain.gltf.extras.weight",
        ),
        (
            lambda d: d["nodes"][1].update(translation=[0.0, float("-inf"), 0.0]),
            "chain.gltf.nodes[1].translation[1]",
        ),
    ],
    ids=["nan-in-extras", "infinity-in-a-translation"],
)
def test_a_non_finite_number_in_a_gltf_document_is_422_naming_it(
    client: TestClient, path: str, edit: Any, field: str
) -> None:
    # Was a 500 (json.dumps(allow_nan=False) raised) and the connection dropped.
    chain = copy.deepcopy(EXAMPLE_GLTF_LEG)
    edit(chain["gltf"])
    r = client.post(
        path, content=_nan_token_body(path, chain), headers={"content-type": "application/json"}
    )
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["code"] == "invalid_format" and body["field"] == field, body
    assert "not finite" in body["detail"], body


def test_a_non_finite_number_in_a_glb_s_json_chunk_is_422(client: TestClient) -> None:
    def nan_scale(doc: dict[str, Any]) -> None:
        doc["nodes"][3]["scale"] = [1.0, float("nan"), 1.0]

    chain = {
        "format": "gltf",
        "glb_base64": _glb_with(nan_scale),
        "effectors": [{"bone": "node_18"}],
    }
    body = error(client, chain)
    # The GLB reader refuses the token itself (no path: it parses the chunk whole).
    assert body["field"] == "chain.glb_base64" and "NaN" in body["detail"], body


def test_joints_sharing_a_name_are_told_apart_by_node_index(client: TestClient) -> None:
    # Two joints named "leg" (nodes 1 and 2): the importer calls them leg#1 and leg#2,
    # and asking for "leg" says so (difflib alone suggested other names first).
    chain = copy.deepcopy(EXAMPLE_GLTF_LEG)
    for node in chain["gltf"]["nodes"][1:]:
        node["name"] = "leg"
    chain["moving"] = ["hip", "leg#1"]
    chain["bones"] = {}
    chain["effectors"] = [{"bone": "leg", "name": "foot", "mode": "position"}]
    body = error(client, chain)
    assert body["field"] == "chain.effectors[0].bone", body
    assert "'leg#1', 'leg#2'" in body["detail"] and "<node index>" in body["detail"], body
    chain["effectors"] = [{"bone": "leg#2", "name": "foot", "mode": "position"}]
    s = create(client, chain)
    assert s.body["effectors"][0]["name"] == "foot"


@pytest.mark.parametrize(
    ("data", "words"),
    [(b"", "is empty"), (bytes(range(7, 200)), r"starts with b'\x07\x08\t\n'")],
    ids=["empty", "random-bytes"],
)
def test_glb_base64_that_is_not_a_glb_says_so(client: TestClient, data: bytes, words: str) -> None:
    # It was read as a .gltf JSON document: "json: the JSON is not valid / not UTF-8".
    glb = base64.b64encode(data).decode()
    body = error(client, {"format": "gltf", "glb_base64": glb, "effectors": [{"bone": "a"}]})
    assert body["field"] == "chain.glb_base64", body
    assert "not a GLB file" in body["detail"] and words in body["detail"], body


def test_glb_base64_may_hold_a_gltf_document_with_a_byte_order_mark(client: TestClient) -> None:
    # The reader takes a .gltf document there too, with the UTF-8 BOM some Windows
    # tools write; the check for "not a GLB" must not refuse it.
    import json

    doc = b"\xef\xbb\xbf" + json.dumps(EXAMPLE_GLTF_LEG["gltf"]).encode()
    chain = {**EXAMPLE_GLTF_LEG, "glb_base64": base64.b64encode(doc).decode()}
    del chain["gltf"]
    create(client, chain)


def test_the_path_of_a_nan_deep_in_a_long_document_is_found_in_bounded_memory() -> None:
    # A NaN after two million numbers under 800 levels: the walk keeps only the path
    # it is on (it built every child's path string first: ~4 GB for this body).
    import tracemalloc

    from service.convert.skeletons import first_non_finite

    leaf: Any = [0.0] * 2_000_000 + [float("nan")]
    document: Any = leaf
    for _ in range(800):
        document = {"a": document}
    tracemalloc.start()
    path = first_non_finite(document)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert path == ["a"] * 800 + [2_000_000]
    assert peak < 1_000_000, peak


def test_a_skeleton_sessions_smooth_step_limit_is_a_characters(client: TestClient) -> None:
    """A game character's limbs turn faster than a robot arm's joints: a skeleton
    session's smooth step limit defaults to 0.3 rad a frame (a walk at 2x speed steps
    0.27; bench.character_tracking), a robot's stays 0.1; an explicit option wins."""
    leg = create(client, EXAMPLE_GLTF_LEG)
    assert leg.body["options"]["max_joint_step_rad"] == 0.3
    assert leg.body["options"]["continuity"] == "smooth"
    assert create(client).body["options"]["max_joint_step_rad"] == 0.1
    chosen = create(client, EXAMPLE_GLTF_LEG, options={"max_joint_step_rad": 0.05})
    assert chosen.body["options"]["max_joint_step_rad"] == 0.05

    def frame(frame_id: int, z: float) -> dict[str, Any]:
        target = {"effector": "foot", "position": {"x": 0.0, "y": 0.2, "z": z}}
        body = {"id": frame_id, "targets": [target]}
        r = client.post(f"/v1/sessions/{leg.id}/frames", json=body, headers=leg.headers)
        assert r.status_code == 200, r.text
        result: dict[str, Any] = r.json()["results"][0]
        return result

    assert frame(1, 0.3)["success"]  # anchors the stream
    far = frame(2, -0.3)  # the foot swung from the front to the back: over 0.3 rad
    assert 0.1 < far["largest_step_rad"] <= 0.3 + 1e-9 and not far["jumped"], far
