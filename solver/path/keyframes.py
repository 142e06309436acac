"""Keyframe plans (``PathOptions.key_every``): the programme over keyframes only, the
frames between filled in, and the stretches that step well above the keyframes' pace
planned again densely (``plan_keyed``). ``target_jumps`` finds cuts in an animation,
which the pace leaves out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..ik import Target
from .kernels import project_onto
from .programme import Planner, frame_steps


def plan_keyed(planner: Planner, start: np.ndarray, walk: bool) -> np.ndarray:
    """The keyframe plan (``PathOptions.key_every``): a coarse dynamic programme
    over keyframes, the frames between filled in, and the stretches that step
    much more than the keyframes' pace re-planned densely. ``walk``: every
    frame's task has one free direction (else none has)."""
    popts = planner.popts
    n = len(planner.frames)
    per = max(2, n // popts.key_every)
    span = n / per  # frames per interval
    # The first frame is a keyframe too: the way from the start pose to the clip
    # (a jump, when the clip starts away from it) is then taken in one step, not
    # spread over the frames before the next keyframe. The programme ranks that
    # step as if it were a keyframe gap (span x itself), else a first frame far
    # along the self-motion would cost nothing beside the longer gaps.
    keys = [0] + [((i + 1) * n) // per - 1 for i in range(per)]
    count = len(keys)
    key_path, _ = planner.dense(
        start,
        keys,
        spacing=popts.key_spacing_rad,
        cap=popts.max_nodes_per_frame,
        walk=[walk] * len(keys),
        span=round(span),
        first_span=round(span),
        reserve=n,  # the repairs' share
    )
    path = np.empty((n, start.shape[0]))
    fill(planner, start, keys, key_path, path)
    # The keyframes' pace: a path through them moving evenly steps about this much
    # per frame. A stretch stepping well above it passed a keyframe badly
    # (interpolation cut a corner of the self-motion, e.g. near a singularity).
    # Measured between keyframes that are reached: a jump to a frame nothing
    # reaches says nothing of the pace elsewhere, nor does the way from the start
    # pose to the first keyframe (a clip may start away from the current pose),
    # nor a jump of the targets themselves (a cut in an animation). No such pair
    # of keyframes: no pace to judge by.
    bounds = [-1, *keys]
    reached = [planner.solved_at(k, q) for k, q in zip(keys, key_path, strict=True)]
    gaps = frame_steps(start, key_path)
    cuts = target_jumps(planner.frames, 2 * round(span))
    both = [i for i in range(1, count) if reached[i] and reached[i - 1]]
    uncut = [i for i in both if not any(keys[i - 1] < k <= keys[i] for k in cuts)]
    paced = [gaps[i] for i in (uncut or both)]  # a cut in every interval: all count
    pace = max(popts.repair_ratio * max(paced, default=math.inf) / span, popts.spacing_rad)
    # Frames no longer judged. Those a dense plan has left unreached: nothing
    # reaches them (the tracker's restarts failed there too). And after the first
    # round, the steps where the targets jump: a repair has spread what it can of
    # the jump, the rest is the targets'. Retrying either widened every such
    # clip's repairs to a dense plan of the whole clip (measured: 2-4x the time
    # of the clip without that frame; a cut, up to 27x).
    given_up: set[int] = set()
    for widen in (1, 3, 9):
        bad = bad_intervals(
            planner, start, path, bounds, pace, given_up if widen == 1 else given_up | cuts
        )
        if not bad:
            break
        windows = repair_windows(bad, widen, count)
        if 2 * sum(hi - lo + 1 for lo, hi in windows) > count:
            # Past half the clip, one dense plan of it all costs less than the
            # stretches, and sees everything they would.
            repair(planner, start, path, -1, n - 1, walk)
            break
        for lo, hi in windows:
            repair(planner, start, path, bounds[lo], bounds[hi + 1], walk)
            given_up.update(
                k
                for k in range(bounds[lo] + 1, bounds[hi + 1] + 1)
                if not planner.solved_at(k, path[k])
            )
    return path


def bad_intervals(
    planner: Planner,
    start: np.ndarray,
    path: np.ndarray,
    bounds: list[int],
    pace: float,
    given_up: set[int],
) -> list[int]:
    """Keyframe intervals holding a frame left unreached, or a step above
    ``pace`` between two reached frames (the step from the start pose is whatever
    the first frame needs: not judged); frames in ``given_up`` are not judged."""
    steps = frame_steps(start, path)
    solved = [planner.solved_at(k, path[k]) for k in range(len(path))]
    bad = []
    for i in range(len(bounds) - 1):
        frames = range(bounds[i] + 1, bounds[i + 1] + 1)
        if not all(solved[k] or k in given_up for k in frames) or any(
            steps[k] > pace
            for k in frames
            if k > 0 and solved[k] and solved[k - 1] and k not in given_up
        ):
            bad.append(i)
    return bad


def fill(
    planner: Planner, start: np.ndarray, keys: list[int], key_path: np.ndarray, path: np.ndarray
) -> None:
    """Frames between keyframes: the straight line between the two keyframes'
    poses, projected onto each frame's targets; where that fails, the tracker's
    answer."""
    before, q_before = -1, start
    lower, upper = planner.solver.chain.lower, planner.solver.chain.upper
    for i, k in enumerate(keys):
        path[k] = key_path[i]
        for f in range(before + 1, k):
            a = (f - before) / (k - before)
            q = np.clip((1.0 - a) * q_before + a * key_path[i], lower, upper)
            data, box = planner.load(f, q)
            if project_onto(q, data, box, 30) > 1.0:
                q = planner.tracked[f].q.copy()
            path[f] = q
        planner.considered += k - before - 1
        before, q_before = k, key_path[i]


def repair(
    planner: Planner, start: np.ndarray, path: np.ndarray, first: int, last: int, walk: bool
) -> None:
    """Re-plan frames first+1..last densely, from path[first] (the start pose when
    first is -1), ending on path[last] unless last is the clip's last frame; kept
    where it reaches more frames, or as many with a smaller largest step (see
    ``_stretch_score``)."""
    n = len(planner.frames)
    ks = list(range(first + 1, last + 1))
    before = start if first < 0 else path[first]
    end = None if last == n - 1 else path[last]
    popts = planner.popts
    new, _ = planner.dense(
        before,
        ks,
        spacing=popts.spacing_rad,
        cap=popts.max_nodes_per_frame,
        walk=[walk] * len(ks),
        along=path[first + 1 : last + 1],
        end=end,
    )
    old = path[first + 1 : last + 1]
    if stretch_score(planner, before, first, new, path) < stretch_score(
        planner, before, first, old, path
    ):
        path[first + 1 : last + 1] = new


def stretch_score(
    planner: Planner, before: np.ndarray, first: int, rows: np.ndarray, path: np.ndarray
) -> tuple[int, float, float]:
    """How good ``rows`` are as frames first+1.. of ``path`` (smaller is better):
    the frames they leave unreached; the largest step between two reached frames
    (the stretch's joins included: a jump into or out of an unreached frame, or
    from the start pose, is there whichever way the stretch goes); then the
    largest step of all."""
    last = first + len(rows)
    seq = [before, *rows]
    ok = [first >= 0 and planner.solved_at(first, before)]
    ok += [planner.solved_at(first + 1 + i, q) for i, q in enumerate(rows)]
    if last + 1 < len(path):  # the join after the stretch
        seq.append(path[last + 1])
        ok.append(planner.solved_at(last + 1, path[last + 1]))
    steps = np.abs(np.diff(np.array(seq), axis=0)).max(axis=1)
    between = [steps[i] for i in range(len(steps)) if ok[i] and ok[i + 1]]
    unreached = sum(not x for x in ok[1 : 1 + len(rows)])
    return unreached, max(between, default=0.0), float(steps.max(initial=0.0))


def target_jumps(
    frames: Sequence[Sequence[Target]], half: int, factor: float = 4.0, floor: float = 1e-3
) -> set[int]:
    """Frames whose targets jump (a cut in an animation): the largest change of any
    target number (position [m], rotation matrix entry, direction) from the frame
    before is above ``factor`` x its median over the frames that move within ``half``
    frames on each side, plus ``floor``; or the targeted effectors or parts change."""
    n = len(frames)
    if n < 2:
        return set()
    motion = np.zeros(n)
    shape = [(t.effector, t.given) for t in frames[0]]
    if all([(t.effector, t.given) for t in f] == shape for f in frames):
        if shape:  # one task throughout: the numbers of all frames as one array
            rows = np.array([[t.packed for t in f] for f in frames])
            motion[1:] = np.nanmax(np.abs(np.diff(rows, axis=0)), axis=(1, 2))
    else:
        for k in range(1, n):
            before = {t.effector: t for t in frames[k - 1]}
            if set(before) != {t.effector for t in frames[k]}:
                motion[k] = math.inf
                continue
            for t in frames[k]:
                if before[t.effector].given != t.given:
                    motion[k] = math.inf
                    break
                change = np.abs(t.packed - before[t.effector].packed)
                motion[k] = max(motion[k], float(np.nanmax(change, initial=0.0)))
    # Typical: the median over the frames around each one that move at all (above
    # floor): a clip that holds still between moves (a gesture between holds, poses
    # held for several frames) moves in only some frames, and a median over all of
    # them would be 0, every move a jump. None moving around it: 0.
    window = np.lib.stride_tricks.sliding_window_view(
        np.pad(motion, half, constant_values=0.0), 2 * half + 1
    ).copy()
    window[:, half] = 0.0  # the frame itself
    window[window <= floor] = math.nan  # still frames, frame 0 and the padding
    window[np.isnan(window).all(axis=1)] = 0.0
    typical = np.nanmedian(window, axis=1)
    return {k for k in range(1, n) if motion[k] > factor * typical[k] + floor}


def repair_windows(bad: list[int], widen: int, count: int) -> list[tuple[int, int]]:
    """Intervals ``bad`` widened by ``widen`` on each side, overlapping ones merged:
    (first, last) interval indices."""
    out: list[tuple[int, int]] = []
    for i in bad:
        lo, hi = max(0, i - widen), min(count - 1, i + widen)
        if out and lo <= out[-1][1] + 1:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out
