"""Chain definitions: a hierarchy of joints and effectors as JSON, URDF text, or a named
example chain shipped with the server. One of them is chosen by ``format``."""

from __future__ import annotations

from typing import Annotated, Any, Literal, get_args

from pydantic import ConfigDict, Field, model_validator

from .common import (
    IDENTITY,
    MAX_COORDINATE,
    ZERO3,
    Coordinate,
    FiniteFloat,
    Quaternion,
    StrictModel,
    Vec3,
    check_exactly_one,
)

# Longest name (joint, link, effector) a request may use.
MAX_NAME_LENGTH = 128
Name = Annotated[str, Field(min_length=1, max_length=MAX_NAME_LENGTH)]
JointKindName = Literal["fixed", "rotational", "revolute", "continuous", "prismatic"]
EffectorModeName = Literal["position", "pose", "aim"]
ExampleName = Literal["panda_arm", "humanoid_arm", "tail", "two_arm_torso"]

# Static caps that bound the work pydantic does before the server's configurable
# limits (IK_MAX_JOINTS, IK_MAX_DOF, ...) are checked.
HARD_MAX_JOINTS = 4096
HARD_MAX_EFFECTORS = 256
HARD_MAX_URDF_CHARS = 8_000_000


class OriginSpec(StrictModel):
    """Rest transform of a joint frame in its parent link's frame: rotate, then translate."""

    translation: Vec3 = Field(default=ZERO3, description="Offset [m]")
    rotation: Quaternion = Field(default=IDENTITY, description="Orientation (unit quaternion)")


# The elbow of EXAMPLE_ARM (below), also JointSpec's example in /docs.
_EXAMPLE_ELBOW: dict[str, Any] = {
    "name": "elbow",
    "parent": "upper_arm",
    "child": "forearm",
    "kind": "revolute",
    "origin": {"translation": {"x": 0.0, "y": 0.0, "z": 0.4}},
    "axis": {"x": 0.0, "y": 1.0, "z": 0.0},
    "lower": [0.0],
    "upper": [2.6],
}


class JointSpec(StrictModel):
    """A joint from ``parent`` link to ``child`` link.

    Kinds: ``fixed`` (no DOF); ``rotational`` (1-3 rotations about the joint frame's
    x/y/z in the order given by ``axes``, e.g. ``"zy"``: one DOF per axis, named
    ``"<joint>.<axis>"``); ``revolute`` (rotation about ``axis``) and ``prismatic``
    (sliding along ``axis``), one DOF named like the joint; ``continuous`` (revolute
    without limits). The link frame is ``parent * origin * Tr(pivot) * motion(q) *
    Tr(-pivot)``.
    """

    model_config = ConfigDict(json_schema_extra={"examples": [_EXAMPLE_ELBOW]})

    name: Name = Field(description="Unique joint name")
    parent: Name = Field(description="Parent link name")
    child: Name = Field(description="Child link name (each link has at most one parent joint)")
    kind: JointKindName = Field(description="How the joint moves its child")
    origin: OriginSpec = Field(default_factory=OriginSpec, description="Rest transform")
    pivot: Vec3 = Field(default=ZERO3, description="Point the motion acts about, joint frame [m]")
    axis: Vec3 = Field(
        default=Vec3(x=0.0, y=0.0, z=1.0),
        description="Unit axis (revolute, continuous, prismatic); normalised by the server",
    )
    axes: str = Field(
        default="",
        pattern=r"^[xyz]{0,3}$",
        description='Rotational joints: active local axes in order, e.g. "zxy"',
    )
    lower: list[Coordinate] = Field(
        default_factory=list,
        max_length=3,
        description="One lower limit per DOF [rad] or [m]; empty for fixed and continuous",
    )
    upper: list[Coordinate] = Field(
        default_factory=list,
        max_length=3,
        description="One upper limit per DOF [rad] or [m]; empty for fixed and continuous",
    )
    terminator: bool = Field(
        default=False,
        description="Joints above this one do not move for effectors whose chain runs through it",
    )


class EffectorSpec(StrictModel):
    """A named point on a link that targets pull on."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"name": "hand", "link": "hand", "mode": "position"}]}
    )

    name: Name = Field(description="Unique effector name; targets refer to it")
    link: Name = Field(description="Link carrying the effector")
    tip_offset: Vec3 = Field(default=ZERO3, description="Tip point in the link frame [m]")
    tip_rotation: Quaternion = Field(
        default=IDENTITY, description="Orientation of the tip frame in the link frame"
    )
    mode: EffectorModeName = Field(
        default="position",
        description=(
            "position: the tip reaches a point; pose: point and orientation; "
            "aim: the tip's aim_axis points along a direction (and reaches a point if given)"
        ),
    )
    aim_axis: Vec3 = Field(
        default=Vec3(x=0.0, y=0.0, z=1.0), description="Aim mode: tip-frame axis to point"
    )
    position_weight: FiniteFloat = Field(
        default=1.0,
        ge=0.0,
        le=MAX_COORDINATE,
        description="Weight of the squared position error [1/m^2]",
    )
    rotation_weight: FiniteFloat = Field(
        default=0.01,
        ge=0.0,
        le=MAX_COORDINATE,
        description="Weight of the squared orientation error [m^2/rad^2 relative]; "
        "0.01 makes 1 mrad count like 0.1 mm",
    )


class HierarchyChain(StrictModel):
    """A chain given as joints and effectors (JSON)."""

    format: Literal["hierarchy"] = Field(description="Selects this chain format")
    joints: list[JointSpec] = Field(
        min_length=1, max_length=HARD_MAX_JOINTS, description="The joints, any order"
    )
    effectors: list[EffectorSpec] = Field(
        min_length=1, max_length=HARD_MAX_EFFECTORS, description="The effectors"
    )


class UrdfChain(StrictModel):
    """A chain read from URDF text: the joints on the paths from ``base_link`` to each
    of ``tip_links``. Each tip link becomes an effector named after the link."""

    format: Literal["urdf"] = Field(description="Selects this chain format")
    urdf: str = Field(
        max_length=HARD_MAX_URDF_CHARS,
        description="The URDF document (kinematic elements are read; meshes are ignored)",
    )
    base_link: Name = Field(description="Link that becomes the chain's root (world) frame")
    tip_links: list[Name] = Field(
        min_length=1, max_length=HARD_MAX_EFFECTORS, description="Links that carry effectors"
    )
    mode: EffectorModeName = Field(default="pose", description="Mode of every effector")


class ExampleChain(StrictModel):
    """One of the example chains built into the server (handy for trying the API)."""

    format: Literal["example"] = Field(description="Selects this chain format")
    name: ExampleName = Field(
        description="panda_arm (7 DOF, pose effector 'tool'), humanoid_arm (7 DOF, pose "
        "effector 'hand'), tail (40 DOF, position effector 'tip'), two_arm_torso (7 DOF, "
        "position effectors 'left_hand' and 'right_hand')"
    )


# --- skeletons (glTF, BVH) -------------------------------------------------------------
# Static caps before the server's own (IK_MAX_SKELETON_BYTES, IK_MAX_JOINTS, ...).
HARD_MAX_SKELETON_CHARS = 48_000_000
HARD_MAX_BONE_SETTINGS = 4096
BoneAxes = Annotated[str, Field(pattern=r"^[xyz]{1,3}$")]


class BoneSettingsSpec(StrictModel):
    """How one bone's joint is built (a bone named in ``moving``, or by default every
    bone the file lets rotate). Defaults: the BVH channels' rotation order, else
    ``default_axes``; limits of a ball joint (every axis +-2 pi: a full turn either
    way)."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"axes": "x", "lower": [0.0], "upper": [2.6]}]}
    )

    axes: BoneAxes | None = Field(
        default=None,
        description='Rotation axes of the bone\'s own frame, in order (intrinsic): "zyx" is '
        "Rz(q0) Ry(q1) Rx(q2)",
    )
    lower: list[Coordinate] | None = Field(
        default=None, min_length=1, max_length=3, description="One lower limit per axis [rad]"
    )
    upper: list[Coordinate] | None = Field(
        default=None, min_length=1, max_length=3, description="One upper limit per axis [rad]"
    )
    terminator: bool = Field(
        default=False,
        description="Bones above this one do not move for effectors below it",
    )


class BoneEffectorSpec(StrictModel):
    """An effector on a bone (by the bone's name)."""

    model_config = ConfigDict(
        json_schema_extra={"examples": [{"bone": "LeftHand", "mode": "position"}]}
    )

    bone: Name = Field(description="Bone carrying the effector")
    name: Name | None = Field(default=None, description="Effector name; default: the bone's")
    tip_offset: Vec3 = Field(
        default=ZERO3, description="Tip point in the bone's frame [m, the file's frame]"
    )
    tip_rotation: Quaternion = Field(
        default=IDENTITY,
        description="Orientation of the tip frame in the bone's frame (the file's axes: "
        "the session's conventions do not convert it)",
    )
    mode: EffectorModeName = Field(default="position", description="As in hierarchy chains")
    aim_axis: Vec3 = Field(
        default=Vec3(x=0.0, y=0.0, z=1.0),
        description="Aim mode: tip-frame axis to point (the file's axes: the session's "
        "conventions do not convert it)",
    )
    position_weight: FiniteFloat = Field(default=1.0, ge=0.0, le=MAX_COORDINATE)
    rotation_weight: FiniteFloat = Field(default=0.01, ge=0.0, le=MAX_COORDINATE)


class FreeRootSpec(StrictModel):
    """A root bone that translates (hips that move): limits relative to its rest
    position along x, y, z of the root's parent frame [m]."""

    lower: Vec3 = Field(default=Vec3(x=-10.0, y=-10.0, z=-10.0), description="[m]")
    upper: Vec3 = Field(default=Vec3(x=10.0, y=10.0, z=10.0), description="[m]")


class _SkeletonChainBase(StrictModel):
    effectors: list[BoneEffectorSpec] = Field(
        min_length=1, max_length=HARD_MAX_EFFECTORS, description="Effectors on bones"
    )
    moving: list[Name] | None = Field(
        default=None,
        max_length=HARD_MAX_BONE_SETTINGS,
        description="Bones that move (the others stay at rest); default: every bone the "
        "file lets rotate (every glTF skin joint, every BVH joint with rotation channels)",
    )
    bones: dict[Name, BoneSettingsSpec] = Field(
        default_factory=dict,
        max_length=HARD_MAX_BONE_SETTINGS,
        description="Per-bone axes, limits and terminators, keyed by bone name",
    )
    default_axes: BoneAxes = Field(
        default="xyz", description="Axes of a moving bone whose file gives no rotation order"
    )
    free_root: FreeRootSpec | None = Field(
        default=None, description="Let the (single) root bone translate; default: fixed"
    )


class GltfChain(_SkeletonChainBase):
    """A skin of a glTF 2.0 file: its joint nodes become bones (rest TRS = rest
    transforms). Give the ``.glb`` as ``glb_base64``, or the ``.gltf`` JSON document
    (buffers embedded or absent: no buffer data is read) as ``gltf``. Native frame:
    Y up, right-handed, metres. Bones without a node name are ``node_<index>``."""

    format: Literal["gltf"] = Field(description="Selects this chain format")
    glb_base64: str | None = Field(
        default=None,
        max_length=HARD_MAX_SKELETON_CHARS,
        description="The .glb file, base64 (standard alphabet, padded)",
    )
    gltf: dict[str, Any] | None = Field(default=None, description="The .gltf JSON document")
    skin: int | Name | None = Field(
        default=None, description="Skin index or name; default: the first"
    )
    unit_m: FiniteFloat = Field(
        default=1.0,
        gt=0.0,
        le=MAX_COORDINATE,
        description="Metres per file length unit: 1 as the glTF specification says; 0.01 "
        "for a file an exporter wrote in centimetres with no 0.01 scale node above its "
        "bones (a chain's warnings say unlikely_units when its bones span over 10 m)",
    )

    @model_validator(mode="after")
    def _one_source(self) -> GltfChain:
        check_exactly_one(self, "glb_base64", "gltf")
        return self


class BvhChain(_SkeletonChainBase):
    """A BVH (motion capture) skeleton: every ROOT and JOINT a bone (moving about its
    CHANNELS rotation axes, in their order), every End Site a fixed bone
    ``<parent>_end``. Native frame: Y up, right-handed, file units x ``unit_m``."""

    format: Literal["bvh"] = Field(description="Selects this chain format")
    bvh: str = Field(max_length=HARD_MAX_SKELETON_CHARS, description="The BVH text")
    unit_m: FiniteFloat = Field(
        default=1.0,
        gt=0.0,
        le=MAX_COORDINATE,
        description="Metres per file length unit (0.01 for a file in centimetres)",
    )


ChainSpec = Annotated[
    HierarchyChain | UrdfChain | ExampleChain | GltfChain | BvhChain,
    Field(discriminator="format", description="The chain, in one of five formats"),
]
# The values of ``format``. pydantic puts the chosen one in an error's location
# (``chain.bvh.unit_m``), where it reads as a field: the service leaves it out.
CHAIN_FORMATS: frozenset[str] = frozenset(
    get_args(spec.model_fields["format"].annotation)[0]
    for spec in (HierarchyChain, UrdfChain, ExampleChain, GltfChain, BvhChain)
)

# The hierarchy used by the /docs examples and the README: a 3-DOF arm whose hand
# reaches points within 0.75 m of the shoulder.
EXAMPLE_ARM: dict[str, Any] = {
    "format": "hierarchy",
    "joints": [
        {
            "name": "shoulder",
            "parent": "base",
            "child": "upper_arm",
            "kind": "rotational",
            "axes": "zy",
            "origin": {"translation": {"x": 0.0, "y": 0.0, "z": 0.3}},
            "lower": [-3.1, -1.5],
            "upper": [3.1, 1.5],
        },
        _EXAMPLE_ELBOW,
        {
            "name": "wrist",
            "parent": "forearm",
            "child": "hand",
            "kind": "fixed",
            "origin": {"translation": {"x": 0.0, "y": 0.0, "z": 0.35}},
        },
    ],
    "effectors": [{"name": "hand", "link": "hand", "mode": "position"}],
}

# A glTF leg for the /docs examples: hip 1 m up, knee and ankle 0.45 m below each other
# (Y up); the ankle reaches points within 0.9 m of the hip.
EXAMPLE_GLTF_LEG: dict[str, Any] = {
    "format": "gltf",
    "gltf": {
        "asset": {"version": "2.0"},
        "nodes": [
            {"name": "hip", "translation": [0.0, 1.0, 0.0], "children": [1]},
            {"name": "knee", "translation": [0.0, -0.45, 0.0], "children": [2]},
            {"name": "ankle", "translation": [0.0, -0.45, 0.0]},
        ],
        "skins": [{"name": "leg", "joints": [0, 1, 2]}],
    },
    "moving": ["hip", "knee"],
    "bones": {"knee": {"axes": "x", "lower": [0.0], "upper": [2.6]}},
    "effectors": [{"bone": "ankle", "name": "foot", "mode": "position"}],
}

# The same leg as BVH text in centimetres (unit_m 0.01), its root at the origin.
EXAMPLE_BVH_LEG: dict[str, Any] = {
    "format": "bvh",
    "bvh": "\n".join(
        [
            "HIERARCHY",
            "ROOT Hips",
            "{",
            "  OFFSET 0 0 0",
            "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
            "  JOINT LeftUpLeg",
            "  {",
            "    OFFSET 10 0 0",
            "    CHANNELS 3 Zrotation Xrotation Yrotation",
            "    JOINT LeftLeg",
            "    {",
            "      OFFSET 0 -45 0",
            "      CHANNELS 3 Zrotation Xrotation Yrotation",
            "      End Site",
            "      {",
            "        OFFSET 0 -45 0",
            "      }",
            "    }",
            "  }",
            "}",
        ]
    ),
    "unit_m": 0.01,
    "moving": ["LeftUpLeg", "LeftLeg"],
    "effectors": [{"bone": "LeftLeg_end", "name": "left_foot"}],
}
