"""Every URDF of example-robot-data and pybullet_data, as a user would bring it.

For each file: does it import (``chain_from_urdf``), and if not, why (the error's
field, and whether pinocchio rejects the file too); does its forward kinematics agree
with pinocchio's (``buildModelFromXML(..., mimic=True)``) on every chain; and how well
the chains solve random reachable targets within the default 5 ms budget.

Chains. A file's root link is the base (or, when a ``floating`` / ``planar`` joint
hangs the robot from a world link, the link that joint moves: what the importer's
message tells a user to choose). Every leaf link whose path from the base has at
least 2 variables is a single-tip chain; all of a file's leaves together are one
multi-tip chain (if there are at least 2 and at most ``--max-multi-dof`` variables),
and so are the issue's many-tip cases (``NAMED_MULTI``: Tiago's three fingertips, the
human's hands and head).

Targets. For each chain, ``--poses`` random joint vectors within the limits
(``[-pi, pi]`` or ``[-0.5, 0.5]`` m where a joint is unlimited) give the targets by
FK: the tip's full pose where its own path has at least 6 variables, its position
otherwise; each is solved from the middle of the limits with the default options
(``IKSolver``, 5 ms budget). "Solved" counts ``success`` within the budget.

On a shared machine the 5 ms of wall time are partly other processes' time. For a
figure that does not depend on the load, give the solver a larger budget
(``--budget-us 100000``): each solve then runs until it succeeds, and "within 5 ms
of CPU" counts the successes whose thread CPU time was at most 5 ms; the tables also
give each chain's iterations (the median and p99 over its solved targets) and the
largest count of restarts. ``--full-restart-every 1`` gives the restarts before
partial restarts (every restart re-draws every variable), for an A/B in one checkout.

    pip download --no-deps pybullet==3.2.7 -d /tmp/pyb
    unzip -q /tmp/pyb/pybullet-*.whl 'pybullet_data/*' -d /tmp/pyb
    OPENBLAS_NUM_THREADS=1 python -m bench.urdf_sweep --pybullet-data /tmp/pyb/pybullet_data

needs pinocchio and example-robot-data (the ``bench`` extras); pybullet_data comes
from the pybullet wheel (only its data files are read; pybullet is not imported).
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import importlib.util
import math
import statistics
import sys
import time
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from solver.errors import InvalidModel
from solver.ik import IKOptions, IKSolver, Target
from solver.model import Chain, EffectorMode, build_chain
from solver.model.forward import link_poses
from solver.model.urdf import chain_from_urdf
from solver.optim import Action, GoalStatus, Termination

_MOVING = {"revolute", "continuous", "prismatic"}
_FREE = {"floating", "planar"}
# The many-tip cases, beyond "every leaf at once" (over 30 DOF on these files).
NAMED_MULTI = {
    "tiago.urdf": [["hand_index_flex_3_link", "hand_middle_flex_3_link", "hand_thumb_flex_2_link"]],
    "human.urdf": [["left_hand", "right_hand", "middle_head"]],
}
FK_TOLERANCE = 1e-12
BUDGET_US = 5000.0


@dataclass
class Tree:
    """A file's structure: each link's parent joint (type, name, parent link)."""

    parent: dict[str, tuple[str, str, str]]  # child link -> (joint, type, parent link)
    links: list[str]
    mimics: set[str]

    def path(self, tip: str, base: str) -> list[tuple[str, str]]:
        out = []
        link = tip
        while link != base and link in self.parent:
            joint, kind, link = self.parent[link]
            out.append((joint, kind))
        return out


@dataclass
class ChainRun:
    file: str
    tips: tuple[str, ...]
    n_dof: int = 0
    fk_error: float = math.nan
    reference: str = ""  # why pinocchio gave no model (or one read with mimic=False)
    times_us: list[float] = field(default_factory=list)
    solved: int = 0
    solved_cpu: int = 0  # solved within BUDGET_US of the thread's CPU time
    iterations: list[int] = field(default_factory=list)  # of the solved targets
    restarts: int = 0  # the most a solved target needed
    statuses: collections.Counter[str] = field(default_factory=collections.Counter)


def urdf_files(pybullet_data: Path | None) -> list[tuple[str, Path]]:
    spec = importlib.util.find_spec("example_robot_data")
    roots: list[tuple[str, Path]] = []
    erd = Path(sys.prefix) / "lib" / f"python{sys.version_info.major}.{sys.version_info.minor}"
    erd = erd / "site-packages" / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
    if erd.is_dir():
        roots.append(("example-robot-data", erd))
    elif spec is not None and spec.origin is not None:
        roots.append(("example-robot-data", Path(spec.origin).parent))
    if pybullet_data is None:
        found = importlib.util.find_spec("pybullet_data")
        if found is not None and found.origin is not None:
            pybullet_data = Path(found.origin).parent
    if pybullet_data is not None:
        roots.append(("pybullet_data", pybullet_data))
    return [(name, p) for name, root in roots for p in sorted(root.rglob("*.urdf"))]


def read_text(path: Path) -> str:
    data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def tree_of(text: str) -> Tree | None:
    try:
        root = ET.fromstring(text.lstrip("\ufeff \t\r\n").rstrip("\x00 \t\r\n"))
    except ET.ParseError:
        return None
    tag = lambda e: e.tag.rsplit("}", 1)[-1] if isinstance(e.tag, str) else ""  # noqa: E731
    links = [e.get("name", "") for e in root if tag(e) == "link"]
    parent: dict[str, tuple[str, str, str]] = {}
    mimics: set[str] = set()
    for e in root:
        if tag(e) != "joint":
            continue
        p = next((c for c in e if tag(c) == "parent"), None)
        c = next((c for c in e if tag(c) == "child"), None)
        if p is None or c is None:
            continue
        parent[c.get("link", "")] = (e.get("name", ""), e.get("type", ""), p.get("link", ""))
        if any(tag(m) == "mimic" for m in e):
            mimics.add(e.get("name", ""))
    return Tree(parent, links, mimics)


def chains_of(tree: Tree) -> tuple[str, list[list[str]]]:
    """(base link, tips of each single-tip chain)."""
    roots = [link for link in tree.links if link not in tree.parent]
    if not roots:
        return "", []
    base = roots[0]
    has_children = {p for (_, _, p) in tree.parent.values()}
    leaves = [link for link in tree.links if link not in has_children and link != base]
    # Below a floating / planar joint: its child is the base a user would choose.
    for leaf in leaves:
        for joint, kind in reversed(tree.path(leaf, base)):
            if kind in _FREE:
                base = next(c for c, (j, _, _) in tree.parent.items() if j == joint)
                break
    tips = []
    for leaf in leaves:
        path = tree.path(leaf, base)
        variables = [j for j, k in path if k in _MOVING and j not in tree.mimics]
        reaches_base = leaf == base or _reaches(tree, leaf, base)
        if reaches_base and len(variables) >= 2:
            tips.append([leaf])
    return base, tips


def _reaches(tree: Tree, leaf: str, base: str) -> bool:
    link = leaf
    while link in tree.parent:
        link = tree.parent[link][2]
        if link == base:
            return True
    return False


def random_q(chain: Chain, rng: np.random.Generator) -> np.ndarray:
    lo = chain.lower.copy()
    hi = chain.upper.copy()
    rotation = np.array([j.kind.value != "prismatic" for j in chain.joints if j.dof_names])
    free = ~np.isfinite(lo)
    lo[free] = np.where(rotation[free], -math.pi, -0.5)
    hi[free] = np.where(rotation[free], math.pi, 0.5)
    return rng.uniform(lo, hi)


def pinocchio_model(text: str) -> tuple[object | None, str]:
    import pinocchio as pin

    try:
        return pin.buildModelFromXML(text, mimic=True), ""
    except Exception as e:  # pinocchio raises ValueError / RuntimeError / std::exception
        why = str(e).splitlines()[0][:120] if str(e) else type(e).__name__
    # pinocchio 4.1 refuses some mimic files (a leader declared after its follower's
    # parent: "The parent joint of the mimic joint is not in the kinematic tree");
    # without mimic it reads every joint as free, and fk_error sets the followers.
    try:
        return pin.buildModelFromXML(text, mimic=False), f"mimic=False ({why})"
    except Exception:
        return None, why


def fk_error(chain: Chain, model: object, base: str, rng: np.random.Generator) -> float:
    """Largest difference of a tip's pose in the base frame, ours vs pinocchio's."""
    import pinocchio as pin

    m = model
    data = m.createData()  # type: ignore[attr-defined]
    worst = 0.0
    for _ in range(10):
        q = random_q(chain, rng)
        qp = pin.neutral(m)
        values = dict(zip(chain.dof_names, q, strict=True))
        followers = chain.followers
        values.update(zip(followers.names, followers.values(q), strict=True))
        for name, value in values.items():
            j = m.joints[m.getJointId(name)]  # type: ignore[attr-defined]
            if j.nq == 0:
                continue  # a mimic joint of a mimic=True model has no q of its own
            if j.nq == 2:  # continuous: (cos, sin)
                qp[j.idx_q], qp[j.idx_q + 1] = math.cos(value), math.sin(value)
            else:
                qp[j.idx_q] = value
        pin.framesForwardKinematics(m, data, qp)
        ours = link_poses(chain, q)
        b = data.oMf[m.getFrameId(base, pin.BODY)]  # type: ignore[attr-defined]
        for e in chain.effectors:
            t = data.oMf[m.getFrameId(e.link, pin.BODY)]  # type: ignore[attr-defined]
            theirs = (b.inverse() * t).homogeneous
            worst = max(worst, float(np.max(np.abs(ours[e.link] - theirs))))
    return worst


def with_modes(chain: Chain) -> Chain:
    """The chain with a pose effector where the tip's own path has 6 variables or more,
    a position effector elsewhere."""
    effectors = [
        dataclasses.replace(
            e,
            mode=EffectorMode.POSE if _variables_to(chain, e.link) >= 6 else EffectorMode.POSITION,
        )
        for e in chain.effectors
    ]
    return build_chain(list(chain.joints), effectors)


def solve_run(
    run: ChainRun, chain: Chain, poses: int, rng: np.random.Generator, options: IKOptions
) -> None:
    chain = with_modes(chain)
    solver = IKSolver(chain, options)
    full = {e.name: e.mode is EffectorMode.POSE for e in chain.effectors}
    seed = chain.mid_limits()
    for _ in range(poses):
        frames = link_poses(chain, random_q(chain, rng))
        targets = [
            Target(
                effector=e.name,
                position=frames[e.link][:3, 3].copy(),
                rotation=frames[e.link][:3, :3].copy() if full[e.name] else None,
            )
            for e in chain.effectors
        ]
        cpu0 = time.thread_time()
        r = solver.solve(targets, seed=seed)
        cpu_us = (time.thread_time() - cpu0) * 1e6
        run.times_us.append(r.solve_us)
        ok = r.success and r.solve_us <= BUDGET_US
        run.solved += ok
        # Both bound the core's CPU time from above: its wall time, and the call's CPU
        # time (which also counts the Python around it, a millisecond on the first call).
        run.solved_cpu += r.success and min(r.solve_us, cpu_us) <= BUDGET_US
        if r.success:
            run.iterations.append(r.iterations)
            run.restarts = max(run.restarts, r.restarts)
        if ok:
            run.statuses["solved"] += 1
        elif cpu_us < 0.8 * r.solve_us:
            # The thread ran for less than 80% of the solve's wall time: the machine
            # took the budget (other processes on the shared cores), not the solver.
            run.statuses["descheduled"] += 1
        else:
            run.statuses["late" if r.success else r.status.value] += 1


def _variables_to(chain: Chain, link: str) -> int:
    by_child = {j.child: j for j in chain.joints}
    n = 0
    while link in by_child:
        j = by_child[link]
        n += len(j.dof_names)
        link = j.parent
    return n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pybullet-data", type=Path, default=None)
    parser.add_argument("--poses", type=int, default=1000, help="targets per chain")
    parser.add_argument("--max-multi-dof", type=int, default=30)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument(
        "--only",
        default="",
        help="sweep the files whose path contains one of these comma-separated substrings",
    )
    parser.add_argument("--multi-only", action="store_true", help="solve only the multi-tip chains")
    parser.add_argument(
        "--budget-us", type=float, default=BUDGET_US, help="the solver's time budget [us]"
    )
    parser.add_argument(
        "--full-restart-every",
        type=int,
        default=IKOptions().full_restart_every,
        help="IKOptions.full_restart_every (1: every restart re-draws every variable)",
    )
    parser.add_argument(
        "--no-turn-restarts",
        action="store_true",
        help="IKOptions.turn_restarts=False (restarts as before turn restarts)",
    )
    parser.add_argument(
        "--no-split-limbs",
        action="store_true",
        help="IKOptions.split_limbs=False (every effector group in one solve, as before)",
    )
    parser.add_argument(
        "--no-inner-first",
        action="store_true",
        help="IKOptions.inner_first=False (a group's trunk effectors not solved first)",
    )
    parser.add_argument(
        "--metric-every",
        type=int,
        default=None,
        help="IKOptions.metric_every (default: IKOptions' own)",
    )
    parser.add_argument(
        "--ftol", type=float, default=None, help="IKOptions.ftol (default: a solve's, 3e-2)"
    )
    parser.add_argument(
        "--stall-window", type=int, default=IKOptions().stall_window, help="IKOptions.stall_window"
    )
    parser.add_argument(
        "--stall-restarts",
        action="store_true",
        help="a stalled pass that misses the goal restarts at once (no RESET_H pass)",
    )
    args = parser.parse_args()
    options = IKOptions(
        ftol=args.ftol,
        stall_window=args.stall_window,
        time_budget_us=args.budget_us,
        full_restart_every=args.full_restart_every,
        turn_restarts=not args.no_turn_restarts,
        split_limbs=not args.no_split_limbs,
        inner_first=not args.no_inner_first,
    )
    if args.stall_restarts:
        policy = options.policy.with_rule(
            Termination.STALLED, GoalStatus.MISSED, Action.RESTART_RANDOM
        )
        options = dataclasses.replace(options, policy=policy)
    if args.metric_every is not None:
        options = dataclasses.replace(options, metric_every=args.metric_every)
    warnings.simplefilter("ignore")
    rng = np.random.default_rng(args.seed)
    only = [part for part in args.only.split(",") if part] or [""]
    files = [f for f in urdf_files(args.pybullet_data) if any(o in str(f[1]) for o in only)]
    import_classes: collections.Counter[str] = collections.Counter()
    notes: collections.Counter[str] = collections.Counter()
    refused: list[tuple[str, str, str]] = []
    singles: list[ChainRun] = []
    multis: list[ChainRun] = []
    no_chain = 0
    t0 = time.perf_counter()
    for package, path in files:
        label = f"{package}/{path.name}"
        text = read_text(path)
        tree = tree_of(text)
        model, why = pinocchio_model(text)
        if tree is None:
            import_classes[
                "not XML (pinocchio: " + ("rejects" if model is None else "accepts") + ")"
            ] += 1
            refused.append((label, "not well-formed XML", why))
            continue
        base, tips = chains_of(tree)
        if not tips:
            no_chain += 1
            continue
        groups = [] if args.multi_only else [(tip, singles) for tip in tips]
        if len(tips) >= 2:
            groups.append(([t[0] for t in tips], multis))
        groups += [(named, multis) for named in NAMED_MULTI.get(path.name, [])]
        for tip_links, sink in groups:
            try:
                chain = chain_from_urdf(text, base_link=base, tip_links=tip_links)
            except InvalidModel as e:
                both = "pinocchio also rejects" if model is None else "pinocchio accepts"
                import_classes[f"refused: {e.field} ({both})"] += 1
                refused.append((f"{label} -> {','.join(tip_links)}", str(e)[:110], why))
                continue
            if sink is multis and chain.n_dof > args.max_multi_dof:
                import_classes[f"multi-tip over {args.max_multi_dof} DOF (not solved)"] += 1
                continue
            import_classes["imported" + (" (with notes)" if chain.notes else "")] += 1
            for n in chain.notes:
                notes[n.kind.value] += 1
            run = ChainRun(label, tuple(tip_links), chain.n_dof, reference=why)
            try:
                if model is not None:
                    run.fk_error = fk_error(chain, model, base, rng)
                solve_run(run, chain, args.poses, rng, options)
            except Exception as e:  # a sweep finds what breaks: record it, go on
                import_classes[f"sweep error: {type(e).__name__}"] += 1
                refused.append((f"{label} -> {','.join(tip_links)}", f"sweep: {e}"[:110], ""))
                continue
            sink.append(run)
    elapsed = time.perf_counter() - t0
    report(files, import_classes, notes, refused, singles, multis, no_chain, args, elapsed)


def _rate(run: ChainRun) -> float:
    return run.solved / max(1, len(run.times_us))


def _rate_cpu(run: ChainRun) -> float:
    """Solved within BUDGET_US of the thread's CPU time (with a larger solver budget:
    what the solver does with 5 ms of CPU, whatever the machine's load)."""
    return run.solved_cpu / max(1, len(run.times_us))


def _rate_on_cpu(run: ChainRun) -> float:
    """The rate with the descheduled misses left out (what the solver did with the
    CPU time it got)."""
    return run.solved / max(1, len(run.times_us) - run.statuses["descheduled"])


def report(files, import_classes, notes, refused, singles, multis, no_chain, args, elapsed):  # type: ignore[no-untyped-def]
    by_package = collections.Counter(p for p, _ in files)
    print(f"## URDF sweep ({len(files)} files: {dict(by_package)}; {elapsed:.0f} s)\n")
    print(f"Files without a chain of >= 2 variables: {no_chain}\n")
    print("| import result | chains |\n|---|---:|")
    for k, v in sorted(import_classes.items()):
        print(f"| {k} | {v} |")
    if notes:
        print(
            "\nNotes (warnings) on imported chains: "
            + ", ".join(f"{k} {v}" for k, v in sorted(notes.items()))
        )
    if refused:
        print("\n| refused | our reason | pinocchio |\n|---|---|---|")
        for label, ours, theirs in refused:
            print(f"| {label} | {ours} | {theirs or 'accepts'} |")
    all_runs = singles + multis
    compared = [r for r in all_runs if not math.isnan(r.fk_error)]
    worst = max((r.fk_error for r in compared), default=math.nan)
    print(
        f"\nFK against pinocchio: {len(compared)} of {len(all_runs)} chains compared, "
        f"largest difference {worst:.2e} (bar {FK_TOLERANCE:g})"
    )
    for r in compared:
        if r.fk_error > FK_TOLERANCE:
            print(f"  - {r.file} {r.tips}: {r.fk_error:.2e}")
    unreferenced = collections.Counter(
        (r.file, r.reference) for r in all_runs if math.isnan(r.fk_error) or r.reference
    )
    if unreferenced:
        print("\nImported here, refused by pinocchio with mimic=True:\n")
        print("| file | chains | pinocchio's reason |\n|---|---:|---|")
        for (file, reason), n in sorted(unreferenced.items()):
            print(f"| {file} | {n} | {reason} |")
    for title, runs, bar in (("single-tip", singles, 0.999), ("multi-tip", multis, 0.995)):
        if not runs:
            continue
        rates = [_rate(r) for r in runs]
        meds = [statistics.median(r.times_us) for r in runs]
        p99 = [float(np.percentile(r.times_us, 99)) for r in runs]
        statuses: collections.Counter[str] = collections.Counter()
        for r in runs:
            statuses.update({k: v for k, v in r.statuses.items() if k != "solved"})
        below = [r for r in runs if _rate(r) < bar]
        below_cpu = [r for r in runs if _rate_on_cpu(r) < bar or _rate_cpu(r) < bar]
        print(
            f"\n### {title}: {len(runs)} chains, {args.poses} targets each "
            f"(budget {args.budget_us:g} us, full_restart_every {args.full_restart_every}, "
            f"turn_restarts {not args.no_turn_restarts})\n"
        )
        cpu_rates = [_rate_cpu(r) for r in runs]
        print(
            f"- solved within {BUDGET_US / 1000:g} ms of CPU: worst chain {min(cpu_rates):.2%}, "
            f"all targets "
            f"{sum(r.solved_cpu for r in runs) / sum(len(r.times_us) for r in runs):.3%}; "
            f"chains below {bar:.1%}: {sum(rate < bar for rate in cpu_rates)}"
        )
        print(
            f"- solved within {BUDGET_US / 1000:g} ms: worst chain {min(rates):.2%}, "
            f"all targets {sum(r.solved for r in runs) / sum(len(r.times_us) for r in runs):.3%}; "
            f"chains below {bar:.1%}: {len(below)}"
        )
        print(
            f"- leaving out the descheduled misses: worst chain "
            f"{min(_rate_on_cpu(r) for r in runs):.2%}; chains below {bar:.1%}: "
            f"{len(below_cpu)}"
        )
        print(
            f"- median solve time per chain: median {statistics.median(meds):.0f} us, "
            f"largest {max(meds):.0f} us; p99 per chain: median {statistics.median(p99):.0f} us, "
            f"largest {max(p99):.0f} us"
        )
        print(f"- misses by class: {dict(statuses) or 'none'}")
        # The table: the chains below the bar, and any chain with a target left unsolved
        # (not_reached with budget left: its restarts ran out) even above the bar.
        listed = [r for r in runs if r in below_cpu or r.statuses["not_reached"] > 0]
        if listed:
            print(
                "\n| chain | DOF | solved | on CPU | within 5 ms of CPU | median [us] | "
                "p99 [us] | iterations p50 / p99 | most restarts | misses |\n"
                "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"
            )
            for r in sorted(listed, key=_rate_cpu):
                misses = {k: v for k, v in r.statuses.items() if k != "solved"}
                its = r.iterations or [0]
                print(
                    f"| {r.file} -> {','.join(r.tips)[:60]} | {r.n_dof} | {_rate(r):.2%} | "
                    f"{_rate_on_cpu(r):.2%} | {_rate_cpu(r):.2%} | "
                    f"{statistics.median(r.times_us):.0f} | "
                    f"{np.percentile(r.times_us, 99):.0f} | "
                    f"{statistics.median(its):.0f} / {np.percentile(its, 99):.0f} | "
                    f"{r.restarts} | {misses} |"
                )


if __name__ == "__main__":
    main()
