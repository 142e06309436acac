"""What the load tools' command lines share: the parser, and the load options with one
name, default and meaning in ``python -m loadtest``, ``loadtest.cost`` and
``loadtest.capacity`` (``--rate``, ``--duration``, ``--warmup``, ``--results``, and where
the tool takes them, ``--transport`` and ``--clients``), turned into a ``RunConfig``."""

from __future__ import annotations

import argparse
from typing import Any

from .run import MAX_CLIENTS, MAX_DURATION_S, RunConfig


def parser(prog: str, doc: str | None) -> argparse.ArgumentParser:
    """A parser whose --help shows the module's docstring as written."""
    return argparse.ArgumentParser(
        prog=prog, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )


def add_load_options(
    ap: argparse.ArgumentParser, *, clients: int | None, duration_s: float
) -> None:
    """The load options; ``clients=None`` for a tool that chooses transport and client
    count itself (the capacity search)."""
    if clients is not None:
        ap.add_argument("--transport", choices=("ws", "http"), default="ws")
        ap.add_argument(
            "--clients", type=int, default=clients, help=f"sessions (at most {MAX_CLIENTS})"
        )
    ap.add_argument("--rate", type=float, default=60.0, help="frames per second per client")
    ap.add_argument(
        "--duration",
        type=float,
        default=duration_s,
        help=f"seconds each client streams (at most {MAX_DURATION_S:g})",
    )
    ap.add_argument(
        "--warmup",
        type=float,
        default=1.0,
        help="seconds at the start of each client not counted in the figures",
    )
    ap.add_argument(
        "--results",
        choices=("full", "compact"),
        default="full",
        help="ask for full frame results (default) or compact ones (?results=compact)",
    )
    ap.add_argument(
        "--deflate",
        action="store_true",
        help="WebSocket clients offer permessage-deflate, as browsers do (the server accepts "
        "it unless IK_WS_COMPRESSION=false); default: they do not",
    )


def run_config(args: argparse.Namespace, **fields: Any) -> RunConfig:
    """A RunConfig from the load options in ``args``; ``fields`` sets the rest and wins."""
    load: dict[str, Any] = {
        "rate_hz": args.rate,
        "duration_s": args.duration,
        "warmup_s": args.warmup,
        "results": args.results,
        "deflate": args.deflate,
    }
    if "clients" in args:
        load |= {"transport": args.transport, "clients": args.clients}
    return RunConfig(**(load | fields))
