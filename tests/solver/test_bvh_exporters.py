"""BVH files as other exporters write them: rotation channels before position channels,
6-channel joints, CRLF and tabs, and MOTION blocks that ``read_bvh`` refuses (``Frames``
off by one, a comma decimal) but that do not stop ``read_bvh_skeleton``. The bones are
placed by hand from the file's numbers (no solver code, no pytransform3d)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from solver.errors import InvalidModel
from solver.model import Effector
from solver.model.bvh import read_bvh, read_bvh_skeleton
from solver.model.skeleton import SkeletonSettings, chain_from_skeleton

_BVH = """HIERARCHY\r
ROOT Hips\r
{\r
\tOFFSET 0 90 0\r
\tCHANNELS 6 Zrotation Xrotation Yrotation Xposition Yposition Zposition\r
\tJOINT Thigh\r
\t{\r
\t\tOFFSET 10 -5 0\r
\t\tCHANNELS 6 Xposition Yposition Zposition Yrotation Zrotation Xrotation\r
\t\tEnd Site\r
\t\t{\r
\t\t\tOFFSET 0 -40 0\r
\t\t}\r
\t}\r
}\r
MOTION\r
Frames: 2\r
Frame Time: 0.033333\r
{frames}"""
# Thigh's position channels hold its OFFSET, as Mixamo's and Blender's exports do.
_FRAMES = "1 2 3 0 91 0 10 -5 0 10 20 30\r\n-4 5 -6 1 90 2 10 -5 0 -30 40 -50\r\n"


def _bvh_world(values: list[float]) -> dict[str, np.ndarray]:
    """_BVH's bones for one MOTION line, by hand: T(positions) then the rotations in
    their listed order, each about its own axis (cm, degrees)."""

    def rot(axis: str, degrees: float) -> np.ndarray:
        c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
        i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
        m = np.eye(3)
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    rz, rx, ry, hx, hy, hz, tx, ty, tz, ty_, tz_, tx_ = values
    hips = np.eye(4)
    hips[:3, :3] = rot("z", rz) @ rot("x", rx) @ rot("y", ry)
    hips[:3, 3] = (hx, hy, hz)
    thigh = np.eye(4)
    thigh[:3, :3] = rot("y", ty_) @ rot("z", tz_) @ rot("x", tx_)
    thigh[:3, 3] = (tx, ty, tz)
    end = np.eye(4)
    end[:3, 3] = (0, -40, 0)
    return {"Hips": hips, "Thigh": hips @ thigh, "Thigh_end": hips @ thigh @ end}


def test_bvh_rotations_before_positions_six_channel_joints_crlf_and_tabs() -> None:
    bvh = read_bvh(_BVH.replace("{frames}", _FRAMES), unit_m=0.01)
    assert bvh.motion is not None
    assert [b.rotation_order for b in bvh.skeleton.bones] == ["zxy", "yzx", ""]
    built = chain_from_skeleton(
        bvh.skeleton, SkeletonSettings(effectors=[Effector(name="foot", link="Thigh_end")])
    )
    clip = built.clip(bvh.motion)
    for k, line in enumerate(_FRAMES.split("\r\n")[:2]):
        values = [float(v) for v in line.split()]
        # Without free_root the root stays at its rest position (its OFFSET).
        values[3:6] = [0, 90, 0]
        reference = _bvh_world(values)
        world = built.world_transforms(clip[k])
        for bone, m in reference.items():
            assert_allclose(world[bone][:3, 3], m[:3, 3] * 0.01, rtol=0, atol=1e-12)
            assert_allclose(world[bone][:3, :3], m[:3, :3], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("frames", "refused"),
    [
        (_FRAMES + "0 0 0 0 90 0 10 -5 0 0 0 0\r\n", "more frame lines than Frames"),
        (_FRAMES.split("\r\n")[0], "truncated"),
        (_FRAMES.replace("-4 5", "-4,5 5"), "not a finite number"),
    ],
)
def test_the_skeleton_alone_does_not_read_a_sloppy_motion_block(frames: str, refused: str) -> None:
    """Frames off by one, a comma decimal: read_bvh refuses the clip, naming the line;
    read_bvh_skeleton (what a chain needs) gives the same skeleton as a clean file."""
    text = _BVH.replace("{frames}", frames)
    with pytest.raises(InvalidModel, match=refused) as info:
        read_bvh(text, unit_m=0.01)
    assert info.value.joint == "MOTION"
    clean = read_bvh(_BVH.replace("{frames}", _FRAMES), unit_m=0.01).skeleton
    skeleton = read_bvh_skeleton(text, unit_m=0.01)
    assert skeleton.names == clean.names
    for got, want in zip(skeleton.bones, clean.bones, strict=True):
        assert got.channels == want.channels and got.parent == want.parent
        assert_allclose(got.rest.translation, want.rest.translation, rtol=0, atol=0)
    # The hierarchy is still checked.
    with pytest.raises(InvalidModel, match="CHANNELS declares 7"):
        read_bvh_skeleton(text.replace("CHANNELS 6", "CHANNELS 7", 1))


@pytest.mark.parametrize("end_site", ["End Site Thigh_Tip", "end site", "End Site Tip {"])
def test_end_site_with_a_name_or_in_lower_case(end_site: str) -> None:
    """Some exporters name the End Site (Blender's importer ignores the name): the bone
    is still ``<parent>_end``, at its OFFSET."""
    text = _BVH.replace("{frames}", _FRAMES)
    if end_site.endswith("{"):
        text = text.replace("\t\tEnd Site\r\n\t\t{\r\n", f"\t\t{end_site}\r\n", 1)
    else:
        text = text.replace("End Site", end_site, 1)
    skeleton = read_bvh(text, unit_m=0.01).skeleton
    assert skeleton.names == ("Hips", "Thigh", "Thigh_end")
    assert_allclose(skeleton.bone("Thigh_end").rest.translation, [0, -0.4, 0], rtol=0, atol=0)
