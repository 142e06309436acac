"""read_bvh: walk.bvh replayed through the chain against pytransform3d, the channel
convention, other layouts (6 channels everywhere, position-only), and one InvalidModel
per check, each naming the joint and the line."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

from solver.errors import InvalidModel
from solver.model import Effector
from solver.model.bvh import read_bvh
from solver.model.forward import link_poses
from solver.model.skeleton import Channel, FreeRoot, SkeletonSettings, chain_from_skeleton
from tests.solver.skeleton_refs import WALK_UNIT_M, bvh_world_positions, walk_text

WIDE = FreeRoot(lower_m=(-50.0,) * 3, upper_m=(50.0,) * 3)


def _settings(effector_bone: str, **kwargs: Any) -> SkeletonSettings:
    return SkeletonSettings(effectors=[Effector(name="e", link=effector_bone)], **kwargs)


def test_walk_structure() -> None:
    bvh = read_bvh(walk_text(), unit_m=WALK_UNIT_M)
    skeleton, motion = bvh.skeleton, bvh.motion
    assert motion is not None
    # README: ROOT Hips + 30 JOINTs + 7 End Sites, 96 channels, 344 frames at 120 fps.
    ends = [b for b in skeleton.bones if b.name.endswith("_end")]
    assert len(skeleton.bones) - len(ends) == 31 and len(ends) == 7
    assert motion.values.shape == (344, 96)
    assert motion.frame_time_s == pytest.approx(0.0083333)
    hips = skeleton.bone("Hips")
    assert hips.channels[:3] == (Channel.X_POSITION, Channel.Y_POSITION, Channel.Z_POSITION)
    assert hips.rotation_order == "zyx"
    assert skeleton.bone("LeftLeg").parent == "LeftUpLeg"
    assert skeleton.bone("LeftToeBase_end").parent == "LeftToeBase"


@pytest.mark.parametrize("frame", [0, 1, 117, 343])
def test_walk_frames_through_the_chain_match_pytransform3d(frame: int) -> None:
    text = walk_text()
    bvh = read_bvh(text, unit_m=WALK_UNIT_M)
    assert bvh.motion is not None
    built = chain_from_skeleton(bvh.skeleton, _settings("LeftHand", free_root=WIDE))
    q = built.clip(bvh.motion)[frame]
    poses = link_poses(built.chain, q)
    # The reference reads the raw MOTION line itself (degrees, file units).
    lines = text.replace("\r\n", "\n").split("\n")
    first = lines.index("Frame Time: .0083333") + 1
    raw = np.array(lines[first + frame].split(), dtype=float)
    reference = bvh_world_positions(bvh.skeleton, raw, WALK_UNIT_M)
    for name, position in reference.items():
        assert_allclose(poses[name][:3, 3], position, rtol=0, atol=1e-9)
    # And the clip's translation really moves the hips (the test is not all at rest).
    assert np.linalg.norm(poses["Hips"][:3, 3] - reference["Hips"]) < 1e-9
    assert abs(raw[0]) > 1.0


def test_without_free_root_the_clip_replays_in_place() -> None:
    bvh = read_bvh(walk_text(), unit_m=WALK_UNIT_M)
    assert bvh.motion is not None
    built = chain_from_skeleton(bvh.skeleton, _settings("LeftFoot"))
    assert "Hips.tx" not in built.chain.dof_names
    q = built.clip(bvh.motion)[200]
    poses = link_poses(built.chain, q)
    raw = np.degrees(bvh.motion.values[200])  # back to the file's numbers (angles)
    raw[:3] = 0.0  # hips at their OFFSET (0 0 0), where a chain without a free root keeps them
    reference = bvh_world_positions(bvh.skeleton, raw, WALK_UNIT_M)
    for name, position in reference.items():
        assert_allclose(poses[name][:3, 3], position, rtol=0, atol=1e-9)


# The convention on its own: one joint, each order of three rotation channels.
_ONE_JOINT = """HIERARCHY
ROOT A
{{
  OFFSET 0 0 0
  CHANNELS 3 {c0} {c1} {c2}
  JOINT B
  {{
    OFFSET 1 2 3
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {{
      OFFSET 0 1 0
    }}
  }}
}}
MOTION
Frames: 1
Frame Time: 0.04
{values}
"""


@pytest.mark.parametrize("order", ["xyz", "xzy", "yxz", "yzx", "zxy", "zyx"])
def test_rotation_channels_are_intrinsic_in_listed_order(order: str) -> None:
    angles = [30.0, -50.0, 70.0]
    text = _ONE_JOINT.format(
        c0=f"{order[0].upper()}rotation",
        c1=f"{order[1].upper()}rotation",
        c2=f"{order[2].upper()}rotation",
        values=" ".join(str(a) for a in [*angles, 10.0, 20.0, -15.0]),
    )
    bvh = read_bvh(text)
    assert bvh.motion is not None
    built = chain_from_skeleton(bvh.skeleton, _settings("B_end"))
    assert built.chain.joints[0].axes == order
    q = built.clip(bvh.motion)[0]
    assert_allclose(q[:3], np.radians(angles))
    poses = link_poses(built.chain, q)
    reference = bvh_world_positions(bvh.skeleton, np.array([*angles, 10.0, 20.0, -15.0]), 1.0)
    assert_allclose(poses["B_end"][:3, 3], reference["B_end"], rtol=0, atol=1e-12)
    assert np.linalg.norm(reference["B_end"] - [1.0, 3.0, 3.0]) > 0.5  # it did rotate


_SIX_EVERYWHERE = """HIERARCHY
ROOT Pelvis {
\tOFFSET 0 1 0
\tCHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
\tJOINT Thigh {
\t\tOFFSET 0.1 -0.1 0
\t\tCHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
\t\tJOINT Shin {
\t\t\tOFFSET 0 -0.4 0
\t\t\tCHANNELS 6 Xposition Yposition Zposition Yrotation Xrotation Zrotation
\t\t\tEnd Site {
\t\t\t\tOFFSET 0 -0.4 0
\t\t\t}
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.033333
0.2 0.9 0.1 10 20 30 0.1 -0.1 0 -5 40 0 0 -0.4 0 0 0 -60
0.3 0.9 0.1 15 25 35 0.1 -0.1 0 -5 45 0 0 -0.4 0 0 0 -65
"""


def test_six_channels_on_every_joint_with_braces_on_the_name_line() -> None:
    bvh = read_bvh(_SIX_EVERYWHERE)
    assert bvh.motion is not None
    assert [b.rotation_order for b in bvh.skeleton.bones] == ["yxz", "yxz", "yxz", ""]
    built = chain_from_skeleton(bvh.skeleton, _settings("Shin_end", free_root=FreeRoot()))
    assert built.chain.n_dof == 3 + 3 * 3
    clip = built.clip(bvh.motion)
    raw_lines = _SIX_EVERYWHERE.strip().split("\n")[-2:]
    for k in range(2):
        poses = link_poses(built.chain, clip[k])
        ref = bvh_world_positions(bvh.skeleton, np.array(raw_lines[k].split(), dtype=float), 1.0)
        # Position channels that equal the OFFSET (as exporters write them) replay exactly.
        for name in ("Pelvis", "Thigh", "Shin", "Shin_end"):
            assert_allclose(poses[name][:3, 3], ref[name], rtol=0, atol=1e-12)


_POSITION_ONLY = """HIERARCHY
ROOT Cart
{
  OFFSET 0 0.5 0
  CHANNELS 2 Zposition Xposition
  JOINT Pole
  {
    OFFSET 0 1 0
    CHANNELS 1 Zrotation
    End Site
    {
      OFFSET 0 1 0
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.1
2.0 -1.0 90
"""


def test_position_only_root_and_a_single_rotation_channel() -> None:
    bvh = read_bvh(_POSITION_ONLY)
    assert bvh.motion is not None
    assert bvh.skeleton.bone("Cart").rotation_order == ""
    built = chain_from_skeleton(bvh.skeleton, _settings("Pole_end", free_root=FreeRoot()))
    # The root does not rotate (no rotation channel) but slides along x and z only.
    assert built.chain.dof_names == ("Cart.tx", "Cart.tz", "Pole.z")
    q = built.clip(bvh.motion)[0]
    assert_allclose(q, [-1.0, 2.0, math.pi / 2])
    tip = link_poses(built.chain, q)["Pole_end"][:3, 3]
    assert_allclose(tip, [-2.0, 1.5, 2.0], rtol=0, atol=1e-12)


def test_no_motion_block_and_units() -> None:
    text = _POSITION_ONLY.split("MOTION")[0]
    bvh = read_bvh(text, unit_m=0.01)
    assert bvh.motion is None
    assert_allclose(bvh.skeleton.bone("Pole").rest.translation, [0.0, 0.01, 0.0])


def test_clip_refuses_axes_that_differ_from_the_channels() -> None:
    from solver.errors import InvalidProblem
    from solver.model.skeleton import BoneSettings

    bvh = read_bvh(_SIX_EVERYWHERE)
    assert bvh.motion is not None
    built = chain_from_skeleton(
        bvh.skeleton, _settings("Shin_end", bones={"Thigh": BoneSettings(axes="xyz")})
    )
    with pytest.raises(InvalidProblem, match="Thigh"):
        built.clip(bvh.motion)


# --- errors -----------------------------------------------------------------------------


def _error(text: str, **kwargs: Any) -> InvalidModel:
    with pytest.raises(InvalidModel) as info:
        read_bvh(text, **kwargs)
    return info.value


def _line_of(text: str, needle: str) -> int:
    return text.replace("\r\n", "\n").split("\n").index(needle) + 1


def test_channel_count_mismatch_names_joint_and_line() -> None:
    text = walk_text().replace(
        "\t\tCHANNELS 3 Zrotation Yrotation Xrotation\r\n\t\tJOINT LeftUpLeg",
        "\t\tCHANNELS 4 Zrotation Yrotation Xrotation\r\n\t\tJOINT LeftUpLeg",
        1,
    )
    err = _error(text)
    assert err.joint == "LHipJoint"
    assert (
        err.field
        == f"line {_line_of(text, chr(9) * 2 + 'CHANNELS 4 Zrotation Yrotation Xrotation')}"
    )


def test_frame_values_inconsistent_with_channels() -> None:
    text = walk_text()
    lines = text.split("\n")
    first = next(i for i, ln in enumerate(lines) if ln.startswith("Frame Time")) + 1
    short = lines.copy()
    short[first + 5] = " ".join(short[first + 5].split()[:-1])
    err = _error("\n".join(short))
    assert (err.joint, err.field) == ("MOTION", f"line {first + 6}")
    assert "95 values" in str(err)


def test_truncated_motion() -> None:
    text = walk_text()
    cut = text[: text.index("MOTION") + 2000]
    cut = cut[: cut.rindex("\n") + 1]  # whole lines: fewer frame lines than Frames
    err = _error(cut)
    assert err.joint == "MOTION"
    assert "truncated" in str(err)
    # Cut inside a line: that frame has too few values.
    assert "values" in str(_error(text[: text.index("MOTION") + 2000]))
    # The last three frames missing: counted after reading every line.
    short = "\n".join(text.rstrip().split("\n")[:-3])
    assert "the file has 341 frame lines" in str(_error(short))
    # A huge declared count is refused before any array is allocated for it.
    huge = text.replace("Frames: 344", "Frames: 999999")
    assert "more than the rest of the file can hold" in str(_error(huge))


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-Infinity", "1e999", "0x10", "1,5"])
def test_non_finite_or_malformed_numbers(bad: str) -> None:
    text = walk_text()
    lines = text.split("\n")
    first = next(i for i, ln in enumerate(lines) if ln.startswith("Frame Time")) + 1
    values = lines[first + 3].split()
    values[7] = bad
    lines[first + 3] = " ".join(values)
    err = _error("\n".join(lines))
    assert (err.joint, err.field) == ("MOTION", f"line {first + 4}")
    offset = text.replace("OFFSET 2.59720 -7.13576 0.00000", f"OFFSET 2.59720 {bad} 0.00000", 1)
    err = _error(offset)
    assert err.joint == "LeftLeg"


@pytest.mark.parametrize(
    ("edit", "joint"),
    [
        (("JOINT LeftLeg", "JOINT LeftUpLeg"), "LeftUpLeg"),  # duplicate name
        (
            (
                "CHANNELS 3 Zrotation Yrotation Xrotation",
                "CHANNELS 3 Zrotation Zrotation Xrotation",
            ),
            "LHipJoint",
        ),
        (
            (
                "CHANNELS 3 Zrotation Yrotation Xrotation",
                "CHANNELS 3 Zrotation Wrotation Xrotation",
            ),
            "LHipJoint",
        ),
        (("OFFSET 0 0 0", "OFFSET 0 0"), "LHipJoint"),
        (("OFFSET 0 0 0", "OFFSET 0 0 0\r\n\t\tOFFSET 0 0 0"), "LHipJoint"),
        (("JOINT LHipJoint\r\n\t{", "JOINT LHipJoint\r\n\t("), "LHipJoint"),
        (("JOINT LHipJoint", "JIONT LHipJoint"), "Hips"),
        (
            (
                "\t\tOFFSET 0 0 0\r\n"
                "\t\tCHANNELS 3 Zrotation Yrotation Xrotation\r\n\t\tJOINT LeftUpLeg",
                "\t\tCHANNELS 3 Zrotation Yrotation Xrotation\r\n\t\tJOINT LeftUpLeg",
            ),
            "LHipJoint",
        ),
    ],
)
def test_bad_hierarchy_names_the_joint(edit: tuple[str, str], joint: str) -> None:
    text = walk_text()
    assert edit[0] in text
    err = _error(text.replace(edit[0], edit[1], 1))
    assert err.joint == joint
    assert err.field is not None and err.field.startswith("line ")


def test_unbalanced_braces_and_structure() -> None:
    text = walk_text()
    head = text[: text.index("MOTION")]
    assert _error(head.rstrip()[:-1]).joint == "Hips"  # the root's '}' is missing
    assert _error(head + "}\r\n").joint == "bvh"
    assert _error("ROOT X\n{\nOFFSET 0 0 0\n}\n").joint == "bvh"  # no HIERARCHY
    assert _error("HIERARCHY\n").field == "HIERARCHY"
    assert _error("HIERARCHY\nJOINT X\n{\nOFFSET 0 0 0\n}\n").joint == "bvh"
    end_site_channels = "HIERARCHY\nROOT R\n{\nOFFSET 0 0 0\nEnd Site\n{\nCHANNELS 1 Xrotation\n"
    assert _error(end_site_channels).joint == "R_end"


def test_caps() -> None:
    text = walk_text()
    assert _error(text, max_bytes=len(text) - 1).joint == "bvh"
    assert _error(text, max_bones=10).field is not None
    assert "deeper" in str(_error(text, max_depth=4))
    assert _error(text, max_frames=100).joint == "MOTION"
    nested = "HIERARCHY\n" + "".join(f"JOINT j{i}\n{{\nOFFSET 0 1 0\n" for i in range(5000))
    nested = nested.replace("JOINT j0", "ROOT j0", 1)
    assert "deeper" in str(_error(nested))
    for unit in (0.0, -1.0, math.nan, math.inf):
        assert _error(text, unit_m=unit).joint == "bvh"


def test_extra_frame_lines_and_bad_header() -> None:
    text = walk_text()
    err = _error(text.replace("Frames: 344", "Frames: 343"))
    assert "more frame lines" in str(err)
    assert _error(text.replace("Frames: 344", "Frames: -1")).joint == "MOTION"
    assert _error(text.replace("Frame Time: .0083333", "Frame Time: 0")).joint == "MOTION"
    assert _error(text.replace("Frame Time: .0083333", "FrameTime .0083333")).joint == "MOTION"


def test_two_roots_lowercase_end_site_and_no_channels() -> None:
    text = (
        "HIERARCHY\nROOT A\n{\n OFFSET 1 0 0\n CHANNELS 1 Yrotation\n End site\n {\n"
        "  OFFSET 0 1 0\n }\n}\nROOT B\n{\n OFFSET -1 0 0\n CHANNELS 0\n}\n"
        "MOTION\nFrames: 1\nFrame Time: 0.5\n90\n"
    )
    bvh = read_bvh(text)
    assert bvh.skeleton.names == ("A", "A_end", "B")
    assert [b.name for b in bvh.skeleton.roots] == ["A", "B"]
    assert bvh.motion is not None and bvh.motion.channels == (("A", Channel.Y_ROTATION),)
    built = chain_from_skeleton(bvh.skeleton, _settings("A_end"))
    assert built.moving == ("A",)  # B has no rotation channel: fixed
    assert_allclose(built.clip(bvh.motion), [[math.pi / 2]])


def test_corrupted_files_get_invalid_model_or_load() -> None:
    """Seeded line deletions, cuts and repeats: InvalidModel or a skeleton and clip that
    build a chain and replay, never another exception."""
    rng = np.random.default_rng(20261125)
    original = walk_text().split("\n")
    outcomes = {"refused": 0, "loaded": 0}
    for _ in range(200):
        lines = original.copy()
        for _ in range(int(rng.integers(1, 4))):
            i = int(rng.integers(0, 200))
            op = int(rng.integers(0, 3))
            if op == 0:
                del lines[i]
            elif op == 1:
                lines[i] = lines[i][: int(rng.integers(0, max(1, len(lines[i]))))]
            else:
                lines.insert(i, lines[int(rng.integers(0, len(lines)))])
        try:
            bvh = read_bvh("\n".join(lines))
            leaf = bvh.skeleton.names[-1]
            built = chain_from_skeleton(bvh.skeleton, _settings(leaf, free_root=WIDE))
            if bvh.motion is not None:
                built.clip(bvh.motion)
            outcomes["loaded"] += 1
        except InvalidModel:
            outcomes["refused"] += 1
    assert outcomes["refused"] > 50 and outcomes["loaded"] > 0
