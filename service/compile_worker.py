"""``python -m service.compile_worker [STEP ...]``: compile the solver into numba's
on-disk cache, then exit (started by ``service.startup``; no steps = all of them).

Prints one JSON line per progress report (``solver.precompile.WarmupProgress``) on stdout.
When its stdin is a pipe, exits as soon as that closes: its parent died, so nobody
waits for the compile.
"""

from __future__ import annotations

import json
import os
import stat
import sys
import threading
from dataclasses import asdict

from solver.precompile import WarmupProgress, warmup


def _print(p: WarmupProgress) -> None:
    print(json.dumps(asdict(p)), flush=True)


def _exit_when_orphaned() -> None:
    # os.read, not sys.stdin: a daemon thread blocked in a buffered reader holds its
    # lock, and the interpreter aborts at exit when it cannot take that lock.
    while os.read(0, 4096):  # b"" at EOF: the parent closed the pipe or died
        pass
    os._exit(1)


def main(argv: list[str]) -> int:
    if stat.S_ISFIFO(os.fstat(0).st_mode):  # started by service.startup (not by hand)
        threading.Thread(target=_exit_when_orphaned, name="orphan-watch", daemon=True).start()
    warmup(_print, steps=argv or None)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
