"""The long schemathesis run: tests/live/test_openapi_fuzz.py with many examples per
operation and the coverage phase on, against a real `python -m service` on 127.0.0.1.

    python -m loadtest.fuzz --examples 200 [--phases examples,coverage,fuzzing] [--append]

Prints the pytest summary, the wall time and the server's /metrics error counts;
``--append`` adds the figures to bench/RESULTS.md under "## Fuzzing".
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import re
import subprocess
import sys
import time

from .service_process import ROOT

RESULTS = ROOT / "bench" / "RESULTS.md"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=200, help="examples per operation")
    ap.add_argument("--phases", default="examples,coverage,fuzzing")
    ap.add_argument("--append", action="store_true", help="append to bench/RESULTS.md")
    args = ap.parse_args()
    env = {
        **os.environ,
        "IK_FUZZ_EXAMPLES": str(args.examples),
        "IK_FUZZ_PHASES": args.phases,
        "OPENBLAS_NUM_THREADS": "1",
    }
    cmd = [
        sys.executable,
        "-m",
        "pytest",
        "tests/live/test_openapi_fuzz.py",
        "-q",
        "-p",
        "no:cacheprovider",
        "--timeout",
        "3600",
        "-rA",
    ]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    wall_s = time.perf_counter() - t0
    out = proc.stdout + proc.stderr
    summary = [ln for ln in out.splitlines() if re.search(r"\d+ (passed|failed)", ln)]
    failures = sorted(set(re.findall(r"- (ST\d+ [^\n]+)", out)))
    print(out[-4000:])
    line = summary[-1] if summary else "(no summary)"
    print(f"wall {wall_s:.0f} s; exit {proc.returncode}; {line}")
    if args.append:
        when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        text = RESULTS.read_text()
        if "\n## Fuzzing\n" not in text:
            text += "\n## Fuzzing\n"
        text += (
            f"\nCommand: `python -m loadtest.fuzz --examples {args.examples} "
            f"--phases {args.phases} --append` (run {when}, 2 shared cores).\n\n"
            f"- operations x examples: every operation of /openapi.json, up to "
            f"{args.examples} generated examples each, phases {args.phases}, "
            f"derandomized\n"
            f"- result: `{line.strip('= ')}` (exit {proc.returncode}) in {wall_s:.0f} s\n"
            f"- distinct check failures: {', '.join(failures) if failures else 'none'}\n"
        )
        RESULTS.write_text(text)
    return proc.returncode


if __name__ == "__main__":
    raise SystemExit(main())
