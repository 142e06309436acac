"""A request's targets -> solver targets, checked against the chain's effectors.

The pydantic path of every frame (HTTP, and WebSocket messages the fast path declines,
``fast_path.py``); errors are ``invalid_problem`` naming the target's field
(``frames[3].targets[0].effector``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import schemas as S
from solver.arrays import Vector
from solver.errors import InvalidProblem
from solver.ik import Pole as SolverPole
from solver.ik import Target as SolverTarget
from solver.ik import pole_node
from solver.model import EffectorMode

from ..errors import invalid_problem
from .chains import ChainView
from .geometry import rotation_matrix, vec3
from .poses import frame_pose

# One frame to solve: (the client's frame id, None if it sent none; its solver targets;
# the animated pose it starts from, None to start from the previous answer: see
# ``poses.frame_pose``). A plain tuple, not a NamedTuple: one is built per WebSocket
# frame, and a NamedTuple's constructor costs 0.2 us more (measured), for names that
# only ever get unpacked.
FrameJob = tuple[int | None, Sequence[SolverTarget], Vector | None]


def clip_jobs(
    frames: Sequence[S.Frame], view: ChainView, limit: int, *, plan: bool = False
) -> list[FrameJob]:
    """The frame jobs of a clip, at most ``limit`` frames
    (IK_MAX_FRAMES_PER_REQUEST); the same over HTTP and WebSocket. A frame of a
    tracked clip may carry its animated ``pose``; a planned clip's may not (the plan
    has one start: the session's pose).

    Raises:
        ServiceError: too many frames (``frames``), a frame's targets (``targets``), a
            frame's pose (``frames[i].pose...``).
    """
    if len(frames) > limit:
        raise invalid_problem(
            f"at most {limit} frames per request (IK_MAX_FRAMES_PER_REQUEST)", "frames"
        )
    jobs: list[FrameJob] = []
    for i, f in enumerate(frames):
        if plan and f.pose is not None:
            raise invalid_problem(
                "a planned clip starts from the session's pose: its frames take no 'pose' "
                "(send the clip without 'plan', or set the pose first with PUT .../pose)",
                f"frames[{i}].pose",
            )
        ts = targets(f.targets, view, f"frames[{i}].targets")
        jobs.append((f.id, ts, frame_pose(f.pose, view, f"frames[{i}].pose")))
    return jobs


def targets(ts: Sequence[S.Target], view: ChainView, field: str) -> Sequence[SolverTarget]:
    """Solver targets for one frame, checked against the chain's effectors.

    Raises:
        ServiceError: unknown effector, two targets for one effector, or a target that
            lacks (or adds) what the effector's mode uses; ``field`` names it.
    """
    out: list[SolverTarget] = []
    seen: set[str] = set()
    for j, t in enumerate(ts):
        where = f"{field}[{j}]"
        mode = view.effector_modes.get(t.effector)
        if mode is None:
            raise invalid_problem(
                f"unknown effector {t.effector!r} (effectors: {sorted(view.effector_modes)})",
                f"{where}.effector",
            )
        if t.effector in seen:
            raise invalid_problem(f"two targets for effector {t.effector!r}", f"{where}.effector")
        seen.add(t.effector)
        if mode is EffectorMode.POSITION:
            _require(
                t.position is not None, "a position effector needs 'position'", where, "position"
            )
            _require(
                t.orientation is None,
                "a position effector takes no 'orientation'",
                where,
                "orientation",
            )
            _require(
                t.direction is None, "a position effector takes no 'direction'", where, "direction"
            )
        elif mode is EffectorMode.POSE:
            _require(
                t.orientation is not None,
                "a pose effector needs 'orientation'",
                where,
                "orientation",
            )
            _require(
                t.direction is None, "a pose effector takes no 'direction'", where, "direction"
            )
        else:
            _require(
                t.direction is not None, "an aim effector needs 'direction'", where, "direction"
            )
            _require(
                t.orientation is None,
                "an aim effector takes no 'orientation'",
                where,
                "orientation",
            )
        direction = None
        if t.direction is not None:
            d = t.direction
            if not math.sqrt(d.x * d.x + d.y * d.y + d.z * d.z) > 1e-9:
                raise invalid_problem("direction must not be zero", f"{where}.direction")
            direction = vec3(d)
        pole = None
        if t.pole is not None:
            pole = _pole(t.pole, view, t.effector, where)
        out.append(
            SolverTarget(
                effector=t.effector,
                position=None if t.position is None else vec3(t.position),
                rotation=None if t.orientation is None else rotation_matrix(t.orientation),
                direction=direction,
                position_weight=t.position_weight,
                rotation_weight=t.rotation_weight,
                pole=pole,
            )
        )
    return view.convention.targets_in(out)


def _pole(p: S.Pole, view: ChainView, effector: str, where: str) -> SolverPole:
    """The solver's pole (in the client's frame: ``targets_in`` converts it), a named
    bone checked against the effector's path to the root (``pole_node``; the default
    bone is the solver's choice, cached per session), a pole without a bone refused
    where the limb has no default (``ChainView.no_default_pole``)."""
    if p.bone is not None and (effector, p.bone) not in view.accepted_poles:
        chain = view.chain
        try:
            pole_node(chain, chain.effector_index(effector), p.bone)
        except InvalidProblem as e:
            raise invalid_problem(str(e), f"{where}.pole.bone") from None
        view.accepted_poles.add((effector, p.bone))
    elif effector in view.no_default_pole:
        raise invalid_problem(
            f"pole for {effector!r}: its limb has no bone that the moving joints carry "
            "between its top and its tip, so there is no default to pull; name one in "
            "pole.bone",
            f"{where}.pole",
        )
    return SolverPole(vec3(p.position), p.bone)


def _require(ok: bool, message: str, where: str, name: str) -> None:
    if not ok:
        raise invalid_problem(message, f"{where}.{name}")
