"""docs/solver.md's example of the solver used on its own, run as written."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path
from typing import Any

PAGE = Path(__file__).resolve().parents[2] / "docs" / "solver.md"


def test_solver_page_example_runs_and_plans_no_rougher_than_tracking() -> None:
    text = PAGE.read_text()
    m = re.search(r"<!-- solver-example:start -->\s*```python\n(.*?)```", text, re.DOTALL)
    assert m is not None, "docs/solver.md has no solver-example block"
    namespace: dict[str, Any] = {}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(m.group(1), str(PAGE), "exec"), namespace)  # noqa: S102
    assert out.getvalue().startswith("solved ")
    tracked, plan = namespace["r"], namespace["plan"]
    assert tracked.success
    assert len(plan.results) == 10 and all(r.success for r in plan.results)
    assert plan.largest_step <= plan.tracked_largest_step
