"""Server CPU per frame at one fixed load: the service and the floors, in one short run.

For each app given (``service``, ``floors``) it starts a one-worker deployment
(``loadtest.serve``, as ``loadtest.capacity`` does), waits for /readyz, runs
``--clients`` clients at ``--rate`` for ``--duration`` seconds and prints the worker's
user + system CPU per answered frame, with the ratio to the floor when both ran.
Unlike ``loadtest.capacity`` it does not search for a client count: the load is fixed,
so before/after figures of a change are taken at the same load (per-frame cost depends
on it: a busier loop does more per wake-up). ``--repeat`` alternates the apps.

    OPENBLAS_NUM_THREADS=1 python -m loadtest.cost --transport ws --clients 12 --duration 6
    OPENBLAS_NUM_THREADS=1 python -m loadtest.cost --apps service --profile /tmp/p.txt
    OPENBLAS_NUM_THREADS=1 python -m loadtest.cost --clients 2 --characters 50 --duration 10
    OPENBLAS_NUM_THREADS=1 python -m loadtest.cost --transport ws --store memory,redis,behind

With ``--characters N`` each client drives N sessions (``--chain``, default the 7-DOF
panda_arm) over one WebSocket, one ``batch`` message per tick (loadtest.batch_load),
and the figure is CPU per character; the floor is the bare echo of the same messages.

``--store redis`` runs the service with its sessions in a real ``redis-server`` started
for the run (IK_REDIS_URL; loadtest.cluster.RedisServer), each frame written before its
answer: the app is then named ``service+redis``; ``behind`` the same, written behind
every 20 ms (IK_REDIS_WRITE_BEHIND_MS): ``service+behind``. ``--store memory,redis,behind``
measures all three beside the floors in one run.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from .batch_load import run_batches, summary
from .capacity import Deployment, Scenario, summarize_profile, trial
from .cli import add_load_options, parser
from .cluster import RedisServer
from .service_process import ROOT

# The service with its sessions in Redis: written through, written behind (every 20 ms).
STORE_APPS = {"redis": "service+redis", "behind": "service+behind"}
BEHIND_MS = "20"


def measure(app: str, args: argparse.Namespace, log: Path, profile: Path | None) -> dict[str, Any]:
    """One deployment, one trial (optionally under py-spy); the trial's summary.

    ``app`` is ``service``, ``floors``, or ``service@DIR``: the service of another
    checkout (e.g. ``git archive HEAD service schemas loadtest | tar -x -C DIR`` plus a
    link to this solver/), to compare two versions of service/ at the same load.
    """
    name, _, root = app.partition("@")
    redis = None
    if name in STORE_APPS.values():  # the service, its sessions in a redis-server of its own
        redis = RedisServer()
        os.environ["IK_REDIS_URL"] = redis.url
        if name == STORE_APPS["behind"]:
            os.environ["IK_REDIS_WRITE_BEHIND_MS"] = BEHIND_MS
        name = "service"
    try:
        dep = Deployment(name, 1, "reuseport", log, Path(root) if root else ROOT)
    finally:
        os.environ.pop("IK_REDIS_URL", None)
        os.environ.pop("IK_REDIS_WRITE_BEHIND_MS", None)
    try:
        dep.wait_ready()
        rec = None
        if profile is not None:
            spy = shutil.which("py-spy")
            if spy is None:
                raise SystemExit("py-spy is not installed")
            rec = subprocess.Popen(
                [spy, "record", "-p", str(dep.pids()[0]), "-r", "200", "-d",
                 str(int(args.duration)), "-f", "raw", "-o", str(profile), 
                 *(["--native"] if args.native else ["--nonblocking"]),
                 *(["--gil"] if args.gil else [])],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
            )  # fmt: skip
        if args.characters > 1:
            s = batch_trial(dep, app, args)
        else:
            sc = Scenario(f"{app}-{args.transport}", name, 1, args.transport, args.clients)
            s = trial(dep, sc, args.clients, args)
        if rec is not None:
            _, err = rec.communicate(timeout=args.duration + 60)
            if profile is not None and profile.exists():
                s["profile"] = summarize_profile(profile)
            else:
                print(f"py-spy failed: {err.decode(errors='replace').strip()}", file=sys.stderr)
        return s
    finally:
        dep.stop()
        if redis is not None:
            redis.stop()


def batch_trial(dep: Deployment, app: str, args: argparse.Namespace) -> dict[str, Any]:
    """``--characters N``: each client sends one batch of N sessions' frames per tick;
    the figure is the worker's CPU per character (entry) answered."""
    run = run_batches(
        dep.url, clients=args.clients, characters=args.characters, chain=args.chain,
        rate_hz=args.rate, duration_s=args.duration, warmup_s=0.0, results=args.results,
        cpu_s=dep.cpu_s, deflate=args.deflate,
    )  # fmt: skip
    s = summary(run)
    s["server_cpu_s"] = run.server_cpu_s  # sessions created before it starts
    s["server_cpu_us_per_frame"] = 1e6 * run.server_cpu_s / max(1, run.entries)
    print(
        f"  {app}: {args.clients} clients x {args.characters} {args.chain}  "
        f"{run.messages} batches  {run.entries} entries  p50 {s['rtt_ms_p50'] or 0:.2f} ms  "
        f"errors {sum(run.errors.values())}  server {s['server_cpu_us_per_frame']:5.1f} us "
        "CPU/character",
        flush=True,
    )
    return s


def main(argv: list[str] | None = None) -> int:
    ap = parser("python -m loadtest.cost", __doc__)
    ap.add_argument("--apps", default="service,floors", help="comma-separated: service, floors")
    add_load_options(ap, clients=12, duration_s=6.0)
    ap.add_argument(
        "--store",
        default="memory",
        help="comma-separated session stores for the service: memory, redis, behind",
    )
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument(
        "--characters",
        type=int,
        default=1,
        help="sessions per client, sent together as one batch message per tick (WebSocket)",
    )
    ap.add_argument("--chain", default="panda_arm", help="example chain of --characters mode")
    ap.add_argument("--processes", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument(
        "--profile",
        type=Path,
        help="py-spy raw stacks of each worker, to <stem>-<app><suffix> (e.g. /tmp/p-service.txt)",
    )
    ap.add_argument("--native", action="store_true", help="py-spy --native (C frames too)")
    ap.add_argument("--gil", action="store_true", help="py-spy --gil (GIL holders only)")
    ap.add_argument("--json", type=Path, help="write the summaries here")
    args = ap.parse_args(argv)
    stores = [s for s in args.store.split(",") if s]
    if not stores or set(stores) - {"memory", *STORE_APPS}:
        ap.error("--store: memory, redis, behind")
    apps = []
    for a in (a for a in args.apps.split(",") if a):
        if a == "service":
            apps += [STORE_APPS.get(s, a) for s in stores]
        else:
            apps.append(a)
    known = ("service", "floors", *STORE_APPS.values())
    if not apps or any(a.partition("@")[0] not in known for a in apps):
        ap.error("--apps: service, floors or service@DIR")
    out: dict[str, list[dict[str, Any]]] = {a: [] for a in apps}
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "servers.log"
        for _ in range(args.repeat):
            for app in apps:
                prof = None
                if args.profile is not None:
                    tag = app.replace("@", "-").replace("/", "_")
                    prof = args.profile.with_name(f"{args.profile.stem}-{tag}{args.profile.suffix}")
                out[app].append(measure(app, args, log, prof))
    cost = {a: [s["server_cpu_us_per_frame"] for s in runs] for a, runs in out.items()}
    for a, c in cost.items():
        print(f"{a}: server CPU per frame [us]: {', '.join(f'{x:.0f}' for x in c)}")
    if "floors" in cost:
        for a in cost:
            if a != "floors":
                ratios = [f / s for s, f in zip(cost[a], cost["floors"], strict=True)]
                print(f"floors / {a} CPU per frame: {', '.join(f'{r:.0%}' for r in ratios)}")
    for app, runs in out.items():
        prof_summary = runs[-1].get("profile")
        if not prof_summary:
            continue
        print(f"profile of {app}: {prof_summary['samples']} samples; self %:")
        for f, pct in prof_summary["self_pct"][:20]:
            print(f"  {pct:5.1f}  {f}")
        print("inclusive %:")
        for f, pct in prof_summary["inclusive_pct"][:45]:
            print(f"  {pct:5.1f}  {f}")
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1, default=str) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
