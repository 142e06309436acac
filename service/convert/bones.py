"""Joint vectors -> what a client places in its world: bone local rotations and world
transforms (skeleton chains), effector world poses (every chain, ``fk_dict``), in the
session's conventions (``conventions.py``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import schemas as S
from solver.arrays import Matrix, Vector
from solver.model import EffectorMode, matrix_to_quaternion
from solver.model.forward import effector_poses

from ..errors import invalid_problem
from .chains import ChainView, check_bone_output
from .conventions import Convention
from .poses import clipped_dofs, pose_vector
from .results import SolvedFrame


def bones_dict(view: ChainView, q: Vector, output: S.BoneOutput) -> dict[str, Any]:
    """A ``BonesOut``: local rotations of the moving bones and world transforms of the
    bones ``output`` names (checked when it was accepted: ``chains.check_bone_output``)."""
    skeleton = view.skeleton
    assert skeleton is not None  # check_bone_output refused bone output without one
    conv = view.convention
    out: dict[str, Any] = {}
    if output.local_rotations:
        quats = conv.quaternions_out(skeleton.local_rotations(q)).tolist()
        out["local"] = {
            name: {"w": w, "x": x, "y": y, "z": z}
            for name, (w, x, y, z) in zip(skeleton.moving, quats, strict=True)
        }
    if output.world:
        world = {}
        for name, m in skeleton.world_transforms(q, output.world).items():
            position, rotation = transform_out(conv, m)
            world[name] = {"position": position, "rotation": rotation}
        out["world"] = world
    return out


def transform_out(conv: Convention, m: Matrix) -> tuple[dict[str, float], dict[str, float]]:
    """A world transform (4x4, the chain's frame) as the client reads one: its position
    ``{x, y, z}`` and rotation ``{w, x, y, z}`` in the session's conventions."""
    px, py, pz = conv.position_out(m[:3, 3]).tolist()
    w, x, y, z = matrix_to_quaternion(conv.rotation_out(m[:3, :3])).tolist()
    return {"x": px, "y": py, "z": pz}, {"w": w, "x": x, "y": y, "z": z}


def effectors_out(view: ChainView, q: Vector) -> list[dict[str, Any]]:
    """``EffectorPoseOut``s: every effector's tip frame at ``q`` (the solver's own FK,
    the frame its targets are measured against), in the chain's effector order and the
    session's conventions; aim effectors add where their aim axis points."""
    chain = view.chain
    conv = view.convention
    out: list[dict[str, Any]] = []
    for eff, m in zip(chain.effectors, effector_poses(chain, q), strict=True):
        position, orientation = transform_out(conv, m)
        direction = None
        if eff.mode is EffectorMode.AIM:
            dx, dy, dz = conv.direction_out(m[:3, :3] @ eff.aim_axis).tolist()
            direction = {"x": dx, "y": dy, "z": dz}
        out.append(
            {
                "name": eff.name,
                "position": position,
                "orientation": orientation,
                "direction": direction,
            }
        )
    return out


def wants_bones(output: S.BoneOutput | None) -> bool:
    return output is not None and (output.local_rotations or bool(output.world))


def add_bones(
    results: list[dict[str, Any]],
    solved: Sequence[SolvedFrame],
    view: ChainView,
    outputs: Sequence[S.BoneOutput | None],
) -> list[dict[str, Any]]:
    """Rendered results with ``bones`` added where the frame's output (or, for None,
    the session's) asks for it; the results without bone output are left as they are."""
    for result, frame, output in zip(results, solved, outputs, strict=True):
        chosen = view.bone_output if output is None else output
        if wants_bones(chosen):
            assert chosen is not None
            result["bones"] = bones_dict(view, frame.result.q, chosen)
    return results


# What an FK answer of a skeleton chain carries when the request names no bone data.
DEFAULT_FK_BONES = S.BoneOutput(local_rotations=True)


def fk_dict(
    view: ChainView,
    current: Vector,
    q: list[float] | None,
    joints: dict[str, float] | None,
    output: S.BoneOutput | None,
    field: str = "",
) -> dict[str, Any]:
    """An ``FkResult``: the pose (``q`` or ``joints`` over ``current``, clipped into the
    limits, named in ``clipped``; neither: ``current``), its effectors' world poses and,
    on skeleton chains, its bone data (``output``; None: ``DEFAULT_FK_BONES``).
    ``field``: where the request sits in its message ("": the HTTP body and a WebSocket
    message alike, whose errors name ``q``, ``joints.<name>``, ``bones``).

    Raises:
        ServiceError: ``invalid_problem``: both ``q`` and ``joints`` (named ``joints``),
            a wrong length or DOF name, bone data asked of a chain without bones, an
            unknown bone.
    """
    at = f"{field}." if field else ""
    if q is not None and joints is not None:
        # An error with no field tells the client nothing to fix: name the second one.
        raise invalid_problem("give at most one of 'q' and 'joints'", f"{at}joints")
    bones_field = f"{at}bones"
    skeleton = view.skeleton
    if skeleton is None:
        if output is not None and (output.local_rotations or output.world):
            raise invalid_problem(
                "bone data needs a skeleton chain (format gltf or bvh) and this chain has "
                "no bones; leave 'bones' out: the answer's 'effectors' hold the tips' poses",
                bones_field,
            )
    else:
        output = DEFAULT_FK_BONES if output is None else output
        check_bone_output(output, skeleton, bones_field)
    pose, clipped = current, []
    if q is not None or joints is not None:
        sent = S.PoseIn(q=q, joints=joints)
        pose = pose_vector(sent, view, current, field)
        clipped = clipped_dofs(sent, view)
    out: dict[str, Any] = {"q": pose.tolist(), "effectors": effectors_out(view, pose)}
    if skeleton is not None:
        assert output is not None
        out["bones"] = bones_dict(view, pose, output)
    out["clipped"] = clipped
    return out
