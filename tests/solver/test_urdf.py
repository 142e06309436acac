"""chain_from_urdf: hardened parsing, one error per check (type, field, joint), happy paths.

The core tests use only URDFs committed in tests/solver/data/. The installed robots
located by bench/robots.py (example-robot-data, rtb-data: benchmark extras) are
checked in ``test_installed_robot`` only, which skips when the URDF file cannot be found.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
from numpy.testing import assert_allclose

import solver.model.urdf_xml
from solver.errors import InvalidModel
from solver.model import EffectorMode, JointKind, NoteKind
from solver.model.forward import effector_poses, link_poses
from solver.model.urdf import MAX_FIXED_JOINTS, chain_from_urdf

DATA = Path(__file__).resolve().parent / "data"
REPO = Path(__file__).resolve().parents[2]
PLANAR = (DATA / "planar_2link.urdf").read_text(encoding="utf-8")
PANDA = (DATA / "panda_kinematic.urdf").read_text(encoding="utf-8")
PANDA_ARM = tuple(f"panda_joint{i}" for i in range(1, 8))


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240611)


# --- small inline URDFs for the error table -------------------------------------------

_LINKS = '<link name="base"/><link name="l1"/><link name="l2"/><link name="other"/>'
_J1 = (
    '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>'
    '<axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint>'
)
_LIMIT = '<limit lower="-1" upper="1"/>'
_AXIS_LIMIT = '<axis xyz="0 0 1"/>' + _LIMIT


def _j2(
    inner: str = _AXIS_LIMIT,
    *,
    type_: str | None = "revolute",
    name: str = "j2",
    parent: str = "l1",
    child: str = "l2",
) -> str:
    type_attr = f' type="{type_}"' if type_ is not None else ""
    return (
        f'<joint name="{name}"{type_attr}><parent link="{parent}"/><child link="{child}"/>'
        f"{inner}</joint>"
    )


def _robot(*body: str, links: str = _LINKS) -> str:
    return f'<robot name="t">{links}{_J1}{"".join(body)}</robot>'


_BILLION_LAUGHS = """<?xml version="1.0"?>
<!DOCTYPE robot [
  <!ENTITY lol "lol">
  <!ENTITY lol1 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">
  <!ENTITY lol2 "&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;&lol1;">
  <!ENTITY lol3 "&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;&lol2;">
  <!ENTITY lol4 "&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;&lol3;">
  <!ENTITY lol5 "&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;&lol4;">
  <!ENTITY lol6 "&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;&lol5;">
  <!ENTITY lol7 "&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;&lol6;">
  <!ENTITY lol8 "&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;&lol7;">
  <!ENTITY lol9 "&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;&lol8;">
]>
<robot name="&lol9;"><link name="base"/></robot>
"""
_EXTERNAL_ENTITY = """<?xml version="1.0"?>
<!DOCTYPE robot [<!ENTITY x SYSTEM "file:///etc/passwd">]>
<robot name="t"><link name="&x;"/></robot>
"""
_EXTERNAL_DTD = '<!DOCTYPE robot SYSTEM "http://example.invalid/urdf.dtd"><robot name="t"/>'
_PLAIN_DTD = '<!DOCTYPE robot><robot name="t"/>'
_CYCLE = (  # l1 and l2 each have one parent joint, but they are each other's parents
    '<robot name="t"><link name="base"/><link name="l1"/><link name="l2"/>'
    '<joint name="a" type="fixed"><parent link="l1"/><child link="l2"/></joint>'
    '<joint name="b" type="fixed"><parent link="l2"/><child link="l1"/></joint></robot>'
)

# (id, text, keyword overrides, expected field, expected joint or None)
ERROR_CASES: list[tuple[str, str, dict[str, object], str, str | None]] = [
    # hardened parsing: every DTD is refused before anything is expanded or fetched
    ("billion_laughs", _BILLION_LAUGHS, {}, "urdf", None),
    ("external_entity", _EXTERNAL_ENTITY, {}, "urdf", None),
    ("external_dtd", _EXTERNAL_DTD, {}, "urdf", None),
    ("plain_dtd", _PLAIN_DTD, {}, "urdf", None),
    ("not_xml", "robot: {name: t}", {}, "urdf", None),
    ("unclosed", '<robot name="t"><link name="base">', {}, "urdf", None),
    ("empty", "", {}, "urdf", None),
    ("root_not_robot", '<sdf version="1.7"><model name="t"/></sdf>', {}, "urdf", None),
    ("lone_surrogate", '<robot name="\ud800"/>', {}, "urdf", None),
    # unsupported joint features on the path; mimic joints the chain cannot follow
    ("mimic_no_leader", _robot(_j2(_AXIS_LIMIT + '<mimic multiplier="2"/>')), {}, "mimic", "j2"),
    ("mimic_unknown", _robot(_j2(_AXIS_LIMIT + '<mimic joint="j9"/>')), {}, "mimic", "j2"),
    (
        "mimic_leader_not_below_base",
        _robot(_j2(_AXIS_LIMIT + '<mimic joint="j1"/>')),
        {"base_link": "l1"},
        "mimic",
        "j2",
    ),
    (
        "mimic_text_multiplier",
        _robot(_j2(_AXIS_LIMIT + '<mimic joint="j1" multiplier="two"/>')),
        {},
        "mimic.multiplier",
        "j2",
    ),
    ("floating", _robot(_j2("", type_="floating")), {}, "type", "j2"),
    ("planar", _robot(_j2('<axis xyz="0 0 1"/>', type_="planar")), {}, "type", "j2"),
    ("unknown_type", _robot(_j2(type_="ball")), {}, "type", "j2"),
    ("missing_type", _robot(_j2(type_=None)), {}, "type", "j2"),
    # limits
    ("revolute_no_limit", _robot(_j2('<axis xyz="0 0 1"/>')), {}, "limit", "j2"),
    (
        "prismatic_no_limit",
        _robot(_j2('<axis xyz="0 0 1"/>', type_="prismatic")),
        {},
        "limit",
        "j2",
    ),
    ("nan_lower", _robot(_j2('<limit lower="NaN" upper="1"/>')), {}, "limit.lower", "j2"),
    ("inf_upper", _robot(_j2('<limit lower="0" upper="inf"/>')), {}, "limit.upper", "j2"),
    ("text_lower", _robot(_j2('<limit lower="low" upper="1"/>')), {}, "limit.lower", "j2"),
    ("underscore_lower", _robot(_j2('<limit lower="-1_0" upper="1"/>')), {}, "limit.lower", "j2"),
    # axis
    ("zero_axis", _robot(_j2('<axis xyz="0 0 0"/>' + _LIMIT)), {}, "axis", "j2"),
    ("tiny_axis", _robot(_j2('<axis xyz="1e-12 0 0"/>' + _LIMIT)), {}, "axis", "j2"),
    ("two_axis_values", _robot(_j2('<axis xyz="0 1"/>' + _LIMIT)), {}, "axis", "j2"),
    ("nan_axis", _robot(_j2('<axis xyz="0 nan 1"/>' + _LIMIT)), {}, "axis", "j2"),
    # origin
    ("nan_xyz", _robot(_j2(_AXIS_LIMIT + '<origin xyz="0 NaN 0"/>')), {}, "origin.xyz", "j2"),
    (
        "overflow_xyz",
        _robot(_j2(_AXIS_LIMIT + '<origin xyz="1e999 0 0"/>')),
        {},
        "origin.xyz",
        "j2",
    ),
    ("comma_xyz", _robot(_j2(_AXIS_LIMIT + '<origin xyz="0,0,0"/>')), {}, "origin.xyz", "j2"),
    ("inf_rpy", _robot(_j2(_AXIS_LIMIT + '<origin rpy="0 -inf 0"/>')), {}, "origin.rpy", "j2"),
    ("text_rpy", _robot(_j2(_AXIS_LIMIT + '<origin rpy="0 0 pi"/>')), {}, "origin.rpy", "j2"),
    # structure
    ("unknown_parent_link", _robot(_j2(parent="nowhere")), {}, "parent", "j2"),
    ("unknown_child_link", _robot(_j2(child="nowhere")), {}, "child", "j2"),
    (
        "missing_parent",
        _robot('<joint name="j2" type="fixed"><child link="l2"/></joint>'),
        {},
        "parent",
        "j2",
    ),
    ("duplicate_joint", _robot(_j2(name="j1")), {}, "name", "j1"),
    ("duplicate_link", _robot(_j2(), links=_LINKS + '<link name="l1"/>'), {}, "name", "l1"),
    (
        "nameless_joint",
        _robot('<joint type="fixed"><parent link="l1"/><child link="l2"/></joint>'),
        {},
        "name",
        None,
    ),
    ("two_parents", _robot(_j2(child="l1")), {}, "child", "j2"),
    ("cycle", _CYCLE, {}, "parent", "b"),  # walking up from l2: a, then b closes the loop
    # base and tips
    ("unknown_tip", _robot(_j2()), {"tip_links": "l9"}, "tip_links", "l9"),
    (
        "tip_not_below_base",
        _robot(_j2(), _j2(name="j3", parent="base", child="other")),
        {"base_link": "l1", "tip_links": "other"},
        "tip_links",
        "other",
    ),
    ("tip_is_base", _robot(_j2()), {"tip_links": "base"}, "tip_links", "base"),
    ("no_tips", _robot(_j2()), {"tip_links": []}, "tip_links", None),
    ("duplicate_tips", _robot(_j2()), {"tip_links": ["l2", "l2"]}, "tip_links", "l2"),
    ("unknown_base", _robot(_j2()), {"base_link": "world"}, "base_link", "world"),
    ("too_many_dof", _robot(_j2()), {"max_dof": 1}, "joints", None),
]


@pytest.mark.parametrize(
    ("text", "overrides", "field", "joint"),
    [pytest.param(*case[1:], id=case[0]) for case in ERROR_CASES],
)
def test_invalid_urdf(
    text: str, overrides: dict[str, object], field: str, joint: str | None
) -> None:
    kwargs: dict[str, object] = {"base_link": "base", "tip_links": "l2", **overrides}
    with pytest.raises(InvalidModel) as info:
        chain_from_urdf(text, **kwargs)  # type: ignore[arg-type]
    assert info.value.field == field
    if joint is not None:
        assert info.value.joint == joint


def test_oversize_is_rejected_before_parsing(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_parse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the parser must not see oversize text")

    monkeypatch.setattr(solver.model.urdf_xml.DET, "fromstring", no_parse)
    big = '<robot name="t">' + " " * 2_000_000 + "</robot>"
    with pytest.raises(InvalidModel) as info:
        chain_from_urdf(big, base_link="base", tip_links="tip")
    assert info.value.field == "urdf"


def test_size_cap_counts_utf8_bytes() -> None:
    size = len(PLANAR.encode("utf-8"))
    assert chain_from_urdf(PLANAR, base_link="base", tip_links="tip", max_bytes=size).n_dof == 2
    with pytest.raises(InvalidModel) as info:
        chain_from_urdf(PLANAR, base_link="base", tip_links="tip", max_bytes=size - 1)
    assert info.value.field == "urdf"
    # 2 characters, 4 bytes: the character count alone would pass.
    text = PLANAR.replace("<robot", "<!-- éé --><robot", 1)
    cap = len(text.encode("utf-8")) - 1
    assert len(text) <= cap
    with pytest.raises(InvalidModel) as info:
        chain_from_urdf(text, base_link="base", tip_links="tip", max_bytes=cap)
    assert info.value.field == "urdf"


def test_too_many_fixed_joints_on_the_path() -> None:
    n = MAX_FIXED_JOINTS + 1
    links = "".join(f'<link name="f{i}"/>' for i in range(n))
    joints = "".join(
        f'<joint name="fj{i}" type="fixed"><parent link="{"l2" if i == 0 else f"f{i - 1}"}"/>'
        f'<child link="f{i}"/></joint>'
        for i in range(n)
    )
    text = _robot(_j2(), joints, links=_LINKS + links)
    with pytest.raises(InvalidModel) as info:
        chain_from_urdf(text, base_link="base", tip_links=f"f{n - 1}")
    assert info.value.field == "joints"
    ok = chain_from_urdf(text, base_link="base", tip_links=f"f{n - 2}")
    assert ok.n_dof == 2


# --- happy paths ------------------------------------------------------------------------


def test_planar_arm_structure() -> None:
    chain = chain_from_urdf(PLANAR, base_link="base", tip_links="tip")
    assert chain.dof_names == ("shoulder", "elbow")
    assert chain.root == "base"
    # camera (floating joint, off the path) and the <transmission> joint are ignored
    assert chain.link_names == ("base", "link1", "link2", "tip")
    assert_allclose(chain.lower, [-3.14159, -2.5], rtol=0.0, atol=0.0)
    assert_allclose(chain.upper, [3.14159, 2.5], rtol=0.0, atol=0.0)
    assert chain.effector_names == ("tip",)
    assert chain.effectors[0].link == "tip"
    assert chain.effectors[0].mode is EffectorMode.POSE


@pytest.mark.parametrize(
    ("q", "xy", "yaw"),
    [
        ((0.0, 0.0), (0.8, 0.0), 0.0),
        ((math.pi / 2, 0.0), (0.0, 0.8), math.pi / 2),
        ((math.pi / 2, -math.pi / 2), (0.3, 0.5), 0.0),
        ((0.0, math.pi / 2), (0.5, 0.3), math.pi / 2),
        ((-math.pi / 2, -math.pi / 2), (-0.3, -0.5), -math.pi),
    ],
)
def test_planar_arm_fk_by_hand(q: tuple[float, float], xy: tuple[float, float], yaw: float) -> None:
    chain = chain_from_urdf(PLANAR, base_link="base", tip_links="tip")
    pose = effector_poses(chain, np.array(q))[0]
    c, s = math.cos(yaw), math.sin(yaw)
    expected = np.array([[c, -s, 0, xy[0]], [s, c, 0, xy[1]], [0, 0, 1, 0], [0, 0, 0, 1]])
    assert_allclose(pose, expected, rtol=0.0, atol=1e-15)
    # the elbow link sits at the end of the first 0.5 m link
    elbow = link_poses(chain, np.array(q))["link2"]
    expected_xy = [0.5 * math.cos(q[0]), 0.5 * math.sin(q[0])]
    assert_allclose(elbow[:2, 3], expected_xy, rtol=0.0, atol=1e-15)


def test_tip_as_string_or_sequence_and_mode() -> None:
    one = chain_from_urdf(PLANAR, base_link="base", tip_links="tip")
    seq = chain_from_urdf(PLANAR, base_link="base", tip_links=("tip",), mode=EffectorMode.AIM)
    assert one.dof_names == seq.dof_names
    assert seq.effectors[0].mode is EffectorMode.AIM
    mid = chain_from_urdf(PLANAR, base_link="link1", tip_links="tip")  # base need not be the root
    assert mid.dof_names == ("elbow",)
    assert mid.root == "link1"


def test_urdf_defaults_and_joint_kinds() -> None:
    text = (
        '<robot name="t"><link name="base"/><link name="a"/><link name="b"/><link name="c"/>'
        '<link name="d"/>'
        # no <origin>, no <axis>: identity origin, axis (1, 0, 0)
        '<joint name="rev" type="revolute"><parent link="base"/><child link="a"/>'
        '<limit lower="-0.5" upper="0.5"/></joint>'
        # continuous: limits ignored, unbounded
        '<joint name="cont" type="continuous"><parent link="a"/><child link="b"/>'
        '<origin xyz="1 2 3"/><axis xyz="0 3 4"/><limit effort="1" velocity="1"/></joint>'
        '<joint name="slide" type="prismatic"><parent link="b"/><child link="c"/>'
        '<origin rpy="0.1 0.2 0.3"/><axis xyz="0 0 -2"/><limit lower="0" upper="0.2"/></joint>'
        # fixed: a zero axis and no limits are fine (the iiwa's tool0 joint has axis 0 0 0)
        '<joint name="tool" type="fixed"><parent link="c"/><child link="d"/>'
        '<axis xyz="0 0 0"/></joint></robot>'
    )
    chain = chain_from_urdf(text, base_link="base", tip_links="d")
    by_name = {j.name: j for j in chain.joints}
    assert [by_name[n].kind for n in ("rev", "cont", "slide", "tool")] == [
        JointKind.REVOLUTE,
        JointKind.CONTINUOUS,
        JointKind.PRISMATIC,
        JointKind.FIXED,
    ]
    assert_allclose(by_name["rev"].axis, [1.0, 0.0, 0.0], rtol=0.0, atol=0.0)
    assert_allclose(by_name["rev"].origin.translation, [0.0, 0.0, 0.0], rtol=0.0, atol=0.0)
    assert_allclose(by_name["rev"].origin.rotation, np.eye(3), rtol=0.0, atol=0.0)
    assert_allclose(by_name["cont"].axis, [0.0, 0.6, 0.8], rtol=0.0, atol=1e-15)
    assert_allclose(by_name["cont"].origin.translation, [1.0, 2.0, 3.0], rtol=0.0, atol=0.0)
    assert_allclose(by_name["slide"].axis, [0.0, 0.0, -1.0], rtol=0.0, atol=0.0)
    assert chain.dof_names == ("rev", "cont", "slide")
    assert_allclose(chain.lower, [-0.5, -math.inf, 0.0], rtol=0.0, atol=0.0)
    assert_allclose(chain.upper, [0.5, math.inf, 0.2], rtol=0.0, atol=0.0)
    # rpy is fixed-axis X-Y-Z: R = Rz(yaw) Ry(pitch) Rx(roll)
    r, p, y = 0.1, 0.2, 0.3
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    assert_allclose(by_name["slide"].origin.rotation, rz @ ry @ rx, rtol=0.0, atol=1e-15)


def test_default_xml_namespace_is_accepted() -> None:
    text = PLANAR.replace('<robot name="planar_2link">', '<robot name="p" xmlns="urn:ex:urdf">')
    chain = chain_from_urdf(text, base_link="base", tip_links="tip")
    assert chain.dof_names == ("shoulder", "elbow")


def test_panda_arm_ignores_the_mimic_finger_off_the_path() -> None:
    chain = chain_from_urdf(PANDA, base_link="panda_link0", tip_links="panda_link8")
    assert chain.dof_names == PANDA_ARM
    assert_allclose(
        chain.lower,
        [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973],
        rtol=0.0,
        atol=0.0,
    )
    assert_allclose(
        chain.upper, [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973], rtol=0.0, atol=0.0
    )
    # q = 0: the flange is 0.088 m forward and 0.333 + 0.316 + 0.384 - 0.107 m up, facing down
    pose = effector_poses(chain, np.zeros(7))[0]
    expected = np.array([[1.0, 0, 0, 0.088], [0, -1, 0, 0], [0, 0, -1, 0.926], [0, 0, 0, 1]])
    assert_allclose(pose, expected, rtol=0.0, atol=1e-15)


def test_panda_tree_with_two_tips() -> None:
    chain = chain_from_urdf(
        PANDA,
        base_link="panda_link0",
        tip_links=["panda_hand_tcp", "panda_leftfinger"],
        mode=EffectorMode.POSITION,
    )
    assert chain.dof_names == (*PANDA_ARM, "panda_finger_joint1")
    assert chain.effector_names == ("panda_hand_tcp", "panda_leftfinger")
    assert all(e.mode is EffectorMode.POSITION for e in chain.effectors)
    assert "panda_rightfinger" not in chain.link_names


# --- the specification's defaults and the conventions of files in the wild -------------


def test_missing_lower_or_upper_is_urdfs_zero_with_a_note() -> None:
    text = _robot(_j2('<axis xyz="0 0 1"/><limit upper="1.5" effort="1" velocity="1"/>'))
    chain = chain_from_urdf(text, base_link="base", tip_links="l2")
    assert (chain.lower[1], chain.upper[1]) == (0.0, 1.5)
    assert [(n.kind, n.joint, n.field) for n in chain.notes] == [
        (NoteKind.DEFAULT_LIMIT, "j2", "limit.lower")
    ]
    # Neither side, and no effort or velocity either: the joint is held at 0.
    held = chain_from_urdf(_robot(_j2("<limit/>")), base_link="base", tip_links="l2")
    assert (held.lower[1], held.upper[1]) == (0.0, 0.0)
    assert [n.field for n in held.notes] == ["limit.lower", "limit.upper"]


@pytest.mark.parametrize("type_", ["revolute", "prismatic"])
def test_lower_above_upper_is_bullets_unlimited_joint(type_: str) -> None:
    text = _robot(_j2('<axis xyz="0 0 1"/><limit lower="1" upper="-1"/>', type_=type_))
    chain = chain_from_urdf(text, base_link="base", tip_links="l2")
    assert (chain.lower[1], chain.upper[1]) == (-math.inf, math.inf)
    expected = JointKind.CONTINUOUS if type_ == "revolute" else JointKind.PRISMATIC
    assert chain.joints[1].kind is expected
    assert [(n.kind, n.joint, n.field) for n in chain.notes] == [
        (NoteKind.UNLIMITED_BY_CONVENTION, "j2", "limit")
    ]


@pytest.mark.parametrize(
    ("type_", "inner", "field", "value"),
    [
        # Degrees where URDF wants radians: kept as written, with a note.
        ("revolute", '<limit lower="-170" upper="170"/>', "limit", -170.0),
        ("revolute", '<origin rpy="0 0 90"/><limit lower="-1" upper="1"/>', "origin.rpy", 90.0),
        ("continuous", '<origin rpy="-180 0 0"/>', "origin.rpy", -180.0),
        # Millimetres where URDF wants metres.
        ("prismatic", '<limit lower="0" upper="500"/>', "limit", 500.0),
        ("fixed", '<origin rpy="0 45 0"/>', "origin.rpy", 45.0),
    ],
)
def test_numbers_that_read_as_degrees_or_millimetres_are_kept_with_a_note(
    type_: str, inner: str, field: str, value: float
) -> None:
    text = _robot(_j2(inner, type_=type_))
    chain = chain_from_urdf(text, base_link="base", tip_links="l2")
    assert [(n.kind, n.joint, n.field) for n in chain.notes] == [
        (NoteKind.UNLIKELY_UNITS, "j2", field)
    ]
    assert repr(value) in chain.notes[0].message
    if field == "limit":
        assert value in (chain.lower[-1], chain.upper[-1])  # read as written


@pytest.mark.parametrize(
    ("type_", "inner"),
    [
        # One turn either way (UR's wrists), a slide of a few metres, a half-turn origin.
        ("revolute", '<limit lower="-6.2832" upper="6.2832"/>'),
        ("revolute", '<origin rpy="3.14159 0 -1.5708"/><limit lower="-12.5" upper="12.5"/>'),
        ("prismatic", '<limit lower="-2.5" upper="9.9"/>'),
        # Another convention for "no limit" (example-robot-data's Iris rotors): no note.
        ("revolute", '<limit lower="-1e16" upper="1e16"/>'),
    ],
)
def test_radians_and_metres_make_no_units_note(type_: str, inner: str) -> None:
    chain = chain_from_urdf(_robot(_j2(inner, type_=type_)), base_link="base", tip_links="l2")
    assert chain.notes == ()
    panda = chain_from_urdf(PANDA, base_link="panda_link0", tip_links="panda_hand_tcp")
    assert not [n for n in panda.notes if n.kind is NoteKind.UNLIKELY_UNITS]


def test_whitespace_before_the_declaration_and_nuls_after_the_root() -> None:
    text = '\n  \ufeff<?xml version="1.0"?>\n' + PLANAR.split("?>", 1)[1] + "\n\x00\x00"
    chain = chain_from_urdf(text, base_link="base", tip_links="tip")
    assert chain.dof_names == ("shoulder", "elbow")


@pytest.mark.parametrize("type_", ["floating", "planar"])
def test_a_free_joint_on_the_path_names_the_base_link_to_use(type_: str) -> None:
    with pytest.raises(InvalidModel) as info:
        chain_from_urdf(_robot(_j2(type_=type_)), base_link="base", tip_links="l2")
    assert (info.value.field, info.value.joint) == ("type", "j2")
    assert "base_link='l2'" in str(info.value)


# --- installed robots (benchmark extras) --------------------------------------------------


def _bench_robots() -> ModuleType | None:
    path = REPO / "bench" / "robots.py"
    if not path.is_file():
        return None
    name = "_bench_robots_for_tests"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


def installed_robot(name: str) -> Any:
    """bench.robots.robot(name), or a skip if its URDF file cannot be found."""
    robots = _bench_robots()
    if robots is None:
        pytest.skip(f"{REPO / 'bench' / 'robots.py'} not found")
    try:
        return robots.robot(name)
    except FileNotFoundError as e:
        pytest.skip(f"URDF for {name!r} not found: {e}")


@pytest.mark.parametrize("name", ["panda", "ur5", "iiwa"])
def test_installed_robot(name: str, rng: np.random.Generator) -> None:
    spec = installed_robot(name)
    full = chain_from_urdf(spec.urdf_text(), base_link=spec.base_link, tip_links=spec.tip_link)
    assert full.dof_names == spec.joint_names
    assert_allclose(full.lower, spec.lower, rtol=0.0, atol=0.0)
    assert_allclose(full.upper, spec.upper, rtol=0.0, atol=0.0)
    assert full.effector_names == (spec.tip_link,)
    # Without meshes, the same kinematics.
    stripped = chain_from_urdf(
        spec.kinematic_urdf_text(),
        base_link=spec.base_link,
        tip_links=spec.tip_link,
    )
    for _ in range(10):
        q = rng.uniform(full.lower, full.upper)
        assert_allclose(
            effector_poses(full, q)[0], effector_poses(stripped, q)[0], rtol=0.0, atol=0.0
        )


def test_committed_panda_matches_installed_panda(rng: np.random.Generator) -> None:
    """The committed copy keeps the kinematics of the file it was made from."""
    spec = installed_robot("panda")
    tips = ["panda_hand_tcp", "panda_leftfinger"]
    installed = chain_from_urdf(spec.urdf_text(), base_link="panda_link0", tip_links=tips)
    committed = chain_from_urdf(PANDA, base_link="panda_link0", tip_links=tips)
    assert installed.dof_names == committed.dof_names
    assert_allclose(installed.lower, committed.lower, rtol=0.0, atol=0.0)
    assert_allclose(installed.upper, committed.upper, rtol=0.0, atol=0.0)
    for _ in range(10):
        q = rng.uniform(committed.lower, committed.upper)
        a, b = link_poses(installed, q), link_poses(committed, q)
        assert a.keys() == b.keys()
        for link in a:
            assert_allclose(a[link], b[link], rtol=0.0, atol=0.0)


_XACRO = 'xmlns:xacro="http://www.ros.org/wiki/xacro"'
_ROBOT = '<robot name="planar_2link">'


def _in_xacro_if(text: str) -> str:
    """The elbow joint inside an <xacro:if>: read as URDF, it was silently left out."""
    start = text.index('<joint name="elbow"')
    end = text.index("</joint>", start) + len("</joint>")
    return f'{text[:start]}<xacro:if value="${{arm}}">{text[start:end]}</xacro:if>{text[end:]}'


def _property(text: str) -> str:
    return text.replace('xyz="0.5 0 0"', 'xyz="${length} 0 0"', 1)


def _arg(text: str) -> str:
    return text.replace('<joint name="shoulder"', '<joint name="$(arg prefix)shoulder"', 1)


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (_in_xacro_if, "<xacro:if>"),
        (_property, "xyz='${length} 0 0' in <origin>"),
        (_arg, "name='$(arg prefix)shoulder' in <joint>"),
    ],
    ids=["xacro-if", "property-in-an-origin", "arg-in-a-joint-name"],
)
def test_a_file_that_is_still_xacro_says_so(edit: Any, words: str) -> None:
    text = edit(PLANAR.replace(_ROBOT, f"{_ROBOT[:-1]} {_XACRO}>"))
    with pytest.raises(InvalidModel) as info:
        chain_from_urdf(text, base_link="base", tip_links="tip")
    assert info.value.field == "urdf"
    assert "xacro, not URDF" in str(info.value) and words in str(info.value), str(info.value)


@pytest.mark.parametrize(
    "uri",
    ["http://ros.org/wiki/xacro", "http://wiki.ros.org/xacro", "https://www.ros.org/wiki/xacro"],
)
def test_xacro_is_recognised_under_the_namespace_uris_files_declare(uri: str) -> None:
    # ur_description's files declare http://ros.org/wiki/xacro: its top file (an include
    # and a macro call) was read as URDF and answered "child link 'base_link' is not
    # declared" instead of "expand it first".
    text = _in_xacro_if(PLANAR.replace(_ROBOT, f'{_ROBOT[:-1]} xmlns:xacro="{uri}">'))
    with pytest.raises(InvalidModel) as info:
        chain_from_urdf(text, base_link="base", tip_links="tip")
    assert info.value.field == "urdf"
    assert "xacro, not URDF (<xacro:if>)" in str(info.value), str(info.value)


def test_xacro_leftovers_where_the_chain_is_not_read_are_ignored() -> None:
    # A mesh path with a substitution and a declared (unused) xacro namespace.
    text = PLANAR.replace("package://nowhere/base.stl", "$(find nowhere)/base.stl")
    text = text.replace(_ROBOT, f"{_ROBOT[:-1]} {_XACRO}>")
    assert chain_from_urdf(text, base_link="base", tip_links="tip").n_dof == 2


def test_an_unknown_link_is_told_the_nearest_names() -> None:
    with pytest.raises(InvalidModel) as base:
        chain_from_urdf(PLANAR, base_link="bsae", tip_links="tip")
    assert base.value.field == "base_link" and "did you mean 'base'" in str(base.value)
    with pytest.raises(InvalidModel) as tip:
        chain_from_urdf(PLANAR, base_link="base", tip_links="Tip")
    assert tip.value.field == "tip_links" and "did you mean 'tip'" in str(tip.value)
