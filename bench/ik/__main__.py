"""``python -m bench.ik``: the command line (see the package's docstring)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

from bench.ik_chains import CHAINS, BenchChain, load
from bench.peers import SKIPPED, PeerSolver, available_peers
from solver.model.forward import effector_poses

from . import __doc__ as PACKAGE_DOC
from .adapters import peer_key
from .config import SOLVER_KEYS, Config, progress
from .judging import Row
from .report import report
from .runners import run_solves, run_tracking
from .streams import uniform_q


def peers_for(
    bc: BenchChain, solvers: tuple[str, ...], fk_lines: list[str], peer_settings: dict[str, str]
) -> tuple[list[PeerSolver], dict[str, str]]:
    """The peers that run on ``bc`` (their FK checked against ours first) and why each other
    wanted peer does not; adds the FK rows to ``fk_lines`` and the settings to ``peer_settings``."""
    name = bc.name
    skipped: dict[str, str] = {}
    peers = []
    if bc.spec is not None and any(k in solvers for k in ("rtb", "ikpy", "clik")):
        before = set(SKIPPED)
        for p in available_peers(bc.spec):
            if peer_key(p) not in solvers:
                continue
            qs = uniform_q(np.random.default_rng(99), bc, 20)
            diff = max(
                float(np.abs(p.fk(bc.to_peer(q)) - effector_poses(bc.pose, q)[0]).max()) for q in qs
            )
            fk_lines.append(f"| {name} | {bc.pose.n_dof} | {bc.source} | {p.name} | {diff:.1e} |")
            if diff > 1e-9:
                skipped[peer_key(p)] = f"FK differs from ours by {diff:.1e}"
                continue
            peers.append(p)
            peer_settings[peer_key(p)] = p.settings
        modules = {"rtb_peer": "rtb", "ikpy_peer": "ikpy", "pin_clik": "clik"}
        for k in set(SKIPPED) - before:  # "bench.peers.rtb_peer on panda" -> "rtb"
            key = modules.get(k.split(" ")[0].rsplit(".", 1)[-1])
            if key:
                skipped[key] = SKIPPED[k]
    elif bc.spec is None:
        skipped = {k: "no URDF for this chain" for k in ("rtb", "ikpy", "clik")}
    return peers, skipped


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m bench.ik",
        description=(PACKAGE_DOC or "").split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        "--n", type=int, default=None, help="targets per chain in (a) and (b) (default 10000)"
    )
    ap.add_argument(
        "--peer-n",
        type=int,
        default=None,
        help="targets for the slow Python-driven solvers scipy/ikpy/clik (default 1000)",
    )
    ap.add_argument(
        "--quick", action="store_true", help="smoke run: N=200, peer N=200, 1 tracking stream"
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout-ms", type=float, default=5.0, help="budget per solve / frame")
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--fps", type=float, default=60.0)
    ap.add_argument(
        "--streams", type=int, default=None, help="tracking streams per chain (default 3)"
    )
    ap.add_argument("--chains", default=",".join(CHAINS), help=f"comma list of {','.join(CHAINS)}")
    ap.add_argument(
        "--solvers", default=",".join(SOLVER_KEYS), help=f"comma list of {','.join(SOLVER_KEYS)}"
    )
    ap.add_argument("--parts", default="a,b,c")
    ap.add_argument(
        "--markdown", type=Path, default=None, help="also write the report to this file"
    )
    args = ap.parse_args(argv)

    n = args.n if args.n is not None else (200 if args.quick else 10_000)
    peer_n = args.peer_n if args.peer_n is not None else (200 if args.quick else 1000)
    streams = args.streams if args.streams is not None else (1 if args.quick else 3)
    chains = tuple(c for c in args.chains.split(",") if c)
    solvers = tuple(s for s in args.solvers.split(",") if s)
    parts_wanted = tuple(p for p in args.parts.split(",") if p)
    for c in chains:
        if c not in CHAINS:
            ap.error(f"unknown chain {c!r}")
    for s in solvers:
        if s not in SOLVER_KEYS:
            ap.error(f"unknown solver {s!r}")
    cfg = Config(
        n,
        peer_n,
        args.seed,
        args.timeout_ms * 1e-3,
        args.frames,
        args.fps,
        streams,
        solvers,
        chains,
    )
    load_start = os.getloadavg()
    if os.environ.get("OPENBLAS_NUM_THREADS") != "1":
        progress(
            f"warning: OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')} (should be 1)"
        )
    progress(f"N={n}, peer N={peer_n}, {streams} stream(s) x {args.frames} frames, chains {chains}")

    parts: dict[str, list[Row]] = {"a": [], "b": [], "c": []}
    fk_lines = [
        "| robot | DOF | model | peer | FK max abs diff vs ours (20 random q) |",
        "|---|---|---|---|---|",
    ]
    peer_settings: dict[str, str] = {}
    for name in chains:
        progress(f"{name}: loading chain and peers")
        bc = load(name)
        peers, skipped = peers_for(bc, solvers, fk_lines, peer_settings)
        if "a" in parts_wanted:
            progress(f"(a) {name}: pose, {n} targets")
            parts["a"] += run_solves(cfg, bc, peers, False, skipped, "(a)")
        if "b" in parts_wanted:
            progress(f"(b) {name}: position only, {n} targets")
            parts["b"] += run_solves(cfg, bc, peers, True, skipped, "(b)")
        if "c" in parts_wanted:
            progress(f"(c) {name}: tracking, {streams} x {args.frames} frames")
            parts["c"] += run_tracking(cfg, bc, peers, skipped)

    lines = report(cfg, parts, fk_lines, peer_settings, load_start, parts_wanted)
    text = "\n".join(lines) + "\n"
    sys.stdout.write(text)
    if args.markdown:
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text(text)
        progress(f"wrote {args.markdown}")
    progress("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
