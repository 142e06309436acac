"""Joint vectors -> what a game engine applies: bone local rotations and world
transforms, in the session's conventions (``conventions.py``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import schemas as S
from solver.arrays import Vector
from solver.model import matrix_to_quaternion

from ..errors import ServiceError, invalid_problem
from .chains import ChainView, check_bone_output
from .poses import pose_vector
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
            px, py, pz = conv.position_out(m[:3, 3]).tolist()
            w, x, y, z = matrix_to_quaternion(conv.rotation_out(m[:3, :3])).tolist()
            world[name] = {
                "position": {"x": px, "y": py, "z": pz},
                "rotation": {"w": w, "x": x, "y": y, "z": z},
            }
        out["world"] = world
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


def fk_dict(
    view: ChainView,
    current: Vector,
    q: list[float] | None,
    joints: dict[str, float] | None,
    output: S.BoneOutput,
    field: str,
) -> dict[str, Any]:
    """An ``FkResult``: the pose (``q`` or ``joints`` over ``current``, clipped into the
    limits; neither: ``current``) and its bone data. ``field`` prefixes the error
    fields (``body`` over HTTP; empty for a WebSocket message).

    Raises:
        ServiceError: ``invalid_problem``: both ``q`` and ``joints``, a wrong length or
            DOF name, a chain without bones, an unknown bone.
    """
    if q is not None and joints is not None:
        raise invalid_problem("give at most one of 'q' and 'joints'", field or None)
    if view.skeleton is None:
        # Whatever the output asks (even nothing: found by schemathesis, a 500): FK
        # answers bones, and only skeleton chains have them.
        raise invalid_problem(
            "FK needs a skeleton chain (format gltf or bvh); this chain has no bones",
            field or None,
        )
    check_bone_output(output, view.skeleton, f"{field}.bones" if field else "bones")
    pose = current
    if q is not None or joints is not None:
        try:
            pose = pose_vector(S.PoseIn(q=q, joints=joints), view, current, field or "_")
        except ServiceError as e:
            if not field and e.field is not None:  # a WebSocket message: "q", not "_.q"
                e.field = e.field.removeprefix("_.")
                e.detail = e.detail.removeprefix("_.")
            raise
    return {"q": pose.tolist(), "bones": bones_dict(view, pose, output)}
