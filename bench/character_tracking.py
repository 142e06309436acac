"""Character tracking: does a game character driven by real motion pop? (issue #22)

The game-character counterpart of bench/tracking.py. walk.bvh (CMU motion capture,
shared/assets) is replayed as ``--streams`` streams drawn from a seeded generator
(bench/mocap_streams.py: a random start frame, a random speed in [0.5, 2], the clip
resampled at 60 Hz and looped back and forth, a random 2-4 of both hands and both
feet), ``--frames`` frames each. The reference joint path is the clip's own rotation
channels; the targets are the chain's FK of it at the chosen effectors. Each stream
runs in every variant:

- policy: ``smooth`` (what a session gets, 0.1 rad per frame) or ``reach``, both
  with the options a service session gets (``service.convert.session_defaults``:
  tolerances 1e-4 m / 1e-3 rad, a 1000 us budget per frame);
- effectors: all positions, or the hands as pose effectors (position and rotation);
- moving bones: the chosen effectors' limbs (shoulder or hip down to the hand or
  foot), or every bone of the skeleton.

The solver starts each stream at the reference's first pose (``set_pose``) and
follows it with ``IKSolver.track``. Per variant: frames within the tolerances (our FK
of the answer against the target, every effector), the streams with a frame outside
them and the largest position error, the reference's largest joint step per stream
(median, largest), streams whose largest joint step
is at most twice the reference's, the worst joint step, streams with a joint step
over 0.5 rad (a pop), the worst bone-rotation step (the angle of a moving bone's
local rotation from one frame to the next, ``SkeletonChain.local_rotations``: what a
game sees; a full turn of a variable is none) and the streams over 0.5 rad, and the
per-frame wall time of ``track`` (median, p99). The streams that pop are listed with
the frame, the bone and what its angles looked like.

    OPENBLAS_NUM_THREADS=1 python -m bench.character_tracking [--streams 100]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from bench.character_steps import (
    bone_rotations,
    bone_steps,
    describe_pop,
    effector_frames,
    joint_steps,
    within_tolerance,
)
from bench.mocap_streams import (
    EFFECTORS,
    FIRST_FRAME,
    StreamSpec,
    character,
    draw,
    reference,
    walk,
    walk_path,
)
from service.config import Settings
from service.convert import session_defaults
from solver.ik import Continuity, IKOptions, IKSolver, Target
from solver.model import EffectorMode
from solver.model.skeleton import SkeletonChain

FPS = 60.0
POP_RAD = 0.5
EFFECTOR_MODES = ("position", "hands pose")
MOVING_SETS = ("limbs", "every bone")


def policies(budget_us: float | None, max_step_rad: float | None = None) -> dict[str, IKOptions]:
    """A service session's options (``smooth``) and the same under ``reach``;
    ``budget_us``: None for the session's budget, 0 for none, else that budget;
    ``max_step_rad``: None for the session's ``max_joint_step_rad``, else that limit."""
    base = session_defaults(Settings(), skeleton=True)
    assert base.continuity is Continuity.SMOOTH
    if budget_us is not None:
        base = replace(base, time_budget_us=budget_us or None)
    if max_step_rad is not None:
        base = replace(base, max_joint_step_rad=max_step_rad)
    return {"smooth": base, "reach": replace(base, continuity=Continuity.REACH)}


@dataclass
class Row:
    """One variant over all streams."""

    bones: set[int] = field(default_factory=set)
    variables: set[int] = field(default_factory=set)
    frames: int = 0
    within_tol: int = 0
    missed_streams: int = 0
    missed_at_cap: int = 0  # smooth: missed frames whose answer stepped its full limit
    misses: list[str] = field(default_factory=list)  # per stream with a miss (--misses)
    worst_error_m: float = 0.0
    streams: int = 0
    within_2x: int = 0
    worst_step: float = 0.0
    worst_ratio: float = 0.0
    popped: int = 0
    worst_turn: float = 0.0
    worst_turn_ratio: float = 0.0
    turned: int = 0
    reference_steps: list[float] = field(default_factory=list)
    times_us: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class Pop:
    variant: tuple[str, str, str]
    spec: StreamSpec
    frame: int
    step: float
    reference_step: float
    turn: float
    turn_bone: str
    reference_turn: float
    pose: str


def targets_of(built: SkeletonChain, frames: np.ndarray) -> list[list[Target]]:
    """Per frame, one target per effector from its reference pose (``effector_frames``)."""
    effs = built.chain.effectors
    return [
        [
            Target(
                effector=e.name,
                position=f[i, :3, 3].copy(),
                rotation=f[i, :3, :3].copy() if e.mode is EffectorMode.POSE else None,
            )
            for i, e in enumerate(effs)
        ]
        for f in frames
    ]


def run(
    built: SkeletonChain, opts: IKOptions, start: np.ndarray, targets: list[list[Target]]
) -> tuple[np.ndarray, list[float]]:
    """``track``'s answers over a stream and the wall time of each call [us]."""
    solver = IKSolver(built.chain, opts)
    solver.set_pose(start)
    qs = np.empty((len(targets), built.chain.n_dof))
    times = []
    clock = time.perf_counter
    for k, t in enumerate(targets):
        t0 = clock()
        r = solver.track(t)
        times.append((clock() - t0) * 1e6)
        qs[k] = r.q
    return qs, times


def one_stream(
    path: Path,
    spec: StreamSpec,
    runs: dict[str, IKOptions],
    frames: int,
    rows: dict[tuple[str, str, str], Row],
    pops: list[Pop],
) -> None:
    for effectors in EFFECTOR_MODES:
        for moving in MOVING_SETS:
            built = character(
                path,
                spec.effectors,
                hands_pose=effectors == "hands pose",
                limbs_only=moving == "limbs",
            )
            ref = reference(built, path, spec, frames, FPS)
            poses = effector_frames(built, ref)
            targets = targets_of(built, poses)
            ref_step = float(joint_steps(ref[0], ref[1:])[0].max())
            ref_turn = float(bone_steps(bone_rotations(built, ref[0], ref[1:]))[0].max())
            for label, opts in runs.items():
                row = rows.setdefault((label, effectors, moving), Row())
                qs, times = run(built, opts, ref[0], targets)
                tol, error = within_tolerance(
                    built, qs, poses, opts.position_tolerance_m, opts.rotation_tolerance_rad
                )
                steps, which = joint_steps(ref[0], qs)
                turns, bone = bone_steps(bone_rotations(built, ref[0], qs))
                worst, turn = float(steps.max()), float(turns.max())
                row.bones.add(len(built.moving))
                row.variables.add(built.chain.n_dof)
                row.frames += frames
                row.within_tol += int(tol.sum())
                row.missed_streams += not tol.all()
                if not tol.all():
                    if opts.continuity is Continuity.SMOOTH:
                        cap = steps >= opts.max_joint_step_rad - 1e-9
                        row.missed_at_cap += int(np.sum(~tol & cap))
                    row.misses.append(
                        f"stream {spec.index} (speed {spec.speed:.2f}, ref step {ref_step:.3f}): "
                        f"{int(np.sum(~tol))} frames, first {int(np.argmin(tol))}, "
                        f"largest error {float(error.max()):.1e} m"
                    )
                row.worst_error_m = max(row.worst_error_m, float(error.max()))
                row.streams += 1
                row.reference_steps.append(ref_step)
                row.within_2x += worst <= 2.0 * ref_step
                row.worst_step = max(row.worst_step, worst)
                row.worst_ratio = max(row.worst_ratio, worst / ref_step)
                row.popped += worst > POP_RAD
                row.worst_turn = max(row.worst_turn, turn)
                row.worst_turn_ratio = max(row.worst_turn_ratio, turn / ref_turn)
                row.turned += turn > POP_RAD
                row.times_us += times
                if worst > POP_RAD or turn > POP_RAD:
                    k = int(np.argmax(steps)) if worst > POP_RAD else int(np.argmax(turns))
                    prev = qs[k - 1] if k else ref[0]
                    pose = describe_pop(built, prev, qs[k], ref[max(k - 1, 0)], int(which[k]))
                    pops.append(
                        Pop(
                            (label, effectors, moving),
                            spec,
                            k,
                            float(steps[k]),
                            ref_step,
                            float(turns[k]),
                            built.moving[int(bone[k])],
                            ref_turn,
                            pose,
                        )
                    )


def warm_up(path: Path, runs: dict[str, IKOptions], n_clip: int) -> None:
    """A few untimed frames per policy on every bone (the first solves of a process
    load the compiled code: tens of milliseconds)."""
    built = character(path, EFFECTORS, hands_pose=True, limbs_only=False)
    ref = reference(built, path, draw(0, 0, n_clip), 10, FPS)
    targets = targets_of(built, effector_frames(built, ref))
    for opts in runs.values():
        run(built, opts, ref[0], targets)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--bvh", default=None, help="walk.bvh (default: shared/assets)")
    ap.add_argument("--streams", type=int, default=100)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--seed", type=int, default=0, help="generator seeds [seed, 0..streams-1]")
    ap.add_argument(
        "--budget-us",
        type=float,
        default=None,
        help="per-frame time budget (0: none; default: a session's)",
    )
    ap.add_argument(
        "--max-step-rad",
        type=float,
        default=None,
        help="smooth's step limit per frame (default: a session's max_joint_step_rad)",
    )
    ap.add_argument("--misses", action="store_true", help="list the streams with a missed frame")
    args = ap.parse_args(argv)
    path = walk_path(args.bvh)
    runs = policies(args.budget_us, args.max_step_rad)
    n_clip = walk(path)[1].n_frames - FIRST_FRAME
    warm_up(path, runs, n_clip)
    rows: dict[tuple[str, str, str], Row] = {}
    pops: list[Pop] = []
    started = time.perf_counter()
    for i in range(args.streams):
        one_stream(path, draw(args.seed, i, n_clip), runs, args.frames, rows, pops)
        print(f"# stream {i} done ({time.perf_counter() - started:.0f} s)", file=sys.stderr)
    report(args, runs, rows, pops)
    return 0


def span(values: set[int]) -> str:
    lo, hi = min(values), max(values)
    return f"{lo}" if lo == hi else f"{lo}-{hi}"


def report(
    args: argparse.Namespace,
    runs: dict[str, IKOptions],
    rows: dict[tuple[str, str, str], Row],
    pops: list[Pop],
) -> None:
    o = runs["smooth"]
    budget = "none" if o.time_budget_us is None else f"{o.time_budget_us:g} us"
    print(
        f"walk.bvh, {args.streams} streams per variant, {args.frames} frames at {FPS:g} Hz; "
        f"generator seeds [{args.seed}, 0..{args.streams - 1}]; session options: tolerances "
        f"{o.position_tolerance_m:g} m / {o.rotation_tolerance_rad:g} rad, budget {budget} per "
        f"frame, max_joint_step_rad {o.max_joint_step_rad:g} (smooth), max_iter {o.max_iter}, "
        f"max_restarts {o.max_restarts}; a pop: a step over {POP_RAD:g} rad"
    )
    print()
    print(
        "| policy | effectors | moving | bones / variables | frames within tol (smooth: missed at the step limit) | streams with a miss | worst position error m | ref's largest "
        "step median / max | streams <= 2x ref step | worst joint step rad (x ref) | streams with a joint step > 0.5 | worst "
        "bone turn rad (x ref) | streams with a bone turn > 0.5 | median us | p99 us |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    order = {name: i for i, name in enumerate((*runs, *EFFECTOR_MODES, *MOVING_SETS))}
    for (label, effectors, moving), r in sorted(
        rows.items(), key=lambda kv: tuple(order[part] for part in kv[0])
    ):
        t = np.array(r.times_us)
        at_cap = f" ({r.missed_at_cap})" if label == "smooth" else ""
        print(
            f"| {label} | {effectors} | {moving} | {span(r.bones)} / {span(r.variables)} | "
            f"{100.0 * r.within_tol / r.frames:.2f}%{at_cap} | {r.missed_streams} | "
            f"{r.worst_error_m:.1e} | {np.median(r.reference_steps):.3f} / "
            f"{max(r.reference_steps):.3f} | {r.within_2x}/{r.streams} | "
            f"{r.worst_step:.3f} ({r.worst_ratio:.1f}x) | {r.popped} | "
            f"{r.worst_turn:.3f} ({r.worst_turn_ratio:.1f}x) | {r.turned} | "
            f"{np.median(t):.0f} | {np.percentile(t, 99):.0f} |"
        )
    if args.misses:
        for (label, effectors, moving), r in rows.items():
            for line in r.misses:
                print(f"# miss: {label} / {effectors} / {moving}: {line}")
    if pops:
        print()
        print(f"Streams with a joint step or a bone turn over {POP_RAD:g} rad:")
        for p in pops:
            s = p.spec
            print(
                f"  {' / '.join(p.variant)}: stream {s.index} (start {s.start_frame}, speed "
                f"{s.speed:.2f}, {'+'.join(s.effectors)}) frame {p.frame}: joint step "
                f"{p.step:.3f} rad (ref {p.reference_step:.3f}), largest bone turn {p.turn:.3f} "
                f"rad on {p.turn_bone} (ref {p.reference_turn:.3f}); {p.pose}"
            )


if __name__ == "__main__":
    raise SystemExit(main())
