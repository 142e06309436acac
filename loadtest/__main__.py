"""``python -m loadtest``: simulated game clients against a running IK service.

Example (a server on 127.0.0.1:8000; 20 clients at 60 Hz for 10 s over WebSocket):

    OPENBLAS_NUM_THREADS=1 python -m loadtest --url http://127.0.0.1:8000 \\
        --clients 20 --rate 60 --duration 10 --json run.json --png run.png

Prints a progress line each second, then the table. Exit status 1 when any error was
counted or any session was lost, 0 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy: solves are tiny here

from .cli import add_load_options, parser, run_config  # noqa: E402
from .paths import DEFAULT_CHAINS  # noqa: E402
from .report import summarize, table  # noqa: E402
from .run import run  # noqa: E402


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = parser("python -m loadtest", __doc__)
    ap.add_argument("--url", default="http://127.0.0.1:8000", help="the service's base URL")
    add_load_options(ap, clients=20, duration_s=10.0)
    ap.add_argument(
        "--drain",
        type=float,
        default=10.0,
        help="seconds to wait for the last answers after the last frame",
    )
    ap.add_argument(
        "--chains",
        default=",".join(DEFAULT_CHAINS),
        help="example chains, assigned to clients in turn",
    )
    ap.add_argument(
        "--processes",
        type=int,
        default=1,
        help="generator processes (clients are split between them)",
    )
    ap.add_argument(
        "--time-budget-us",
        type=float,
        default=None,
        help="session option time_budget_us (server default if left out)",
    )
    ap.add_argument("--json", type=Path, help="write the summary as JSON here ('-': stdout)")
    ap.add_argument("--png", type=Path, help="write latency over time + histogram here")
    ap.add_argument("--quiet", action="store_true", help="no progress line")
    ap.add_argument(
        "--allow-remote",
        action="store_true",
        help="allow a non-loopback URL (only against a server you run)",
    )
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    a = parse_args(argv)
    options = {} if a.time_budget_us is None else {"time_budget_us": a.time_budget_us}
    cfg = run_config(
        a,
        url=a.url,
        drain_s=a.drain,
        chains=tuple(c.strip() for c in a.chains.split(",") if c.strip()),
        processes=a.processes,
        options=options,
        allow_remote=a.allow_remote,
    )
    try:
        cfg.check()
    except ValueError as e:
        print(f"python -m loadtest: {e}", file=sys.stderr)
        return 2
    tty = sys.stderr.isatty()

    def progress(line: str) -> None:
        # One line rewritten in place on a terminal; plain lines in a log.
        print(
            ("\r\033[K" if tty else "") + line, end="" if tty else "\n", file=sys.stderr, flush=True
        )

    out = run(cfg, None if a.quiet else progress)
    if tty and not a.quiet:
        print(file=sys.stderr)
    summary = summarize(out)
    if a.json is not None:
        text = json.dumps(summary, indent=2)
        if str(a.json) == "-":
            print(text)
        else:
            a.json.write_text(text + "\n")
    if a.json is None or str(a.json) != "-":
        print(table(summary))
    if a.png is not None:
        from .plot import write_png

        write_png(out, summary, a.png)
    bad = sum(summary["errors"].values()) + summary["sessions"]["lost"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
