"""bench.skeleton under the pole rule before 2026-11-29 22:4x: the shaped answer taken
every frame (``PoleShaper.solve`` as of 56b7547, patched over today's; the compiled code
is the same), for a same-run A/B with ``python -m bench.skeleton``:

    OPENBLAS_NUM_THREADS=1 python bench/history/poles_shaped_always.py --frames 300 --budget-us 0

Needs the repository's git history (it reads the old method with ``git show``).
"""

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from solver.ik import poles  # noqa: E402

source = subprocess.run(
    ["git", "show", "56b7547:solver/ik/poles.py"],
    cwd=ROOT,
    capture_output=True,
    text=True,
    check=True,
).stdout
shaper = next(
    n for n in ast.parse(source).body if isinstance(n, ast.ClassDef) and n.name == "PoleShaper"
)
method = next(n for n in shaper.body if isinstance(n, ast.FunctionDef) and n.name == "solve")
namespace = dict(vars(poles))
exec(textwrap.dedent(ast.get_source_segment(source, method) or ""), namespace)
poles.PoleShaper.solve = namespace["solve"]  # type: ignore[method-assign]

from bench.skeleton import main  # noqa: E402

if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
