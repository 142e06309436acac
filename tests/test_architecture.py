"""The layout's rules (ARCHITECTURE.md), checked on every run.

- The import contracts in pyproject.toml ([tool.importlinter]): import-linter builds the
  import graph of the packages and checks each contract (layers, forbidden imports,
  private modules, no cycles between siblings).
- No module imports an underscore *name* from another top-level package
  (import-linter sees modules only, so ``from solver.ik import _Planner`` needs this).
- No Python file of the product is over 500 lines, unless its docstring says why.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("solver", "schemas", "service")
CHECKED = (*PRODUCT, "bench", "loadtest", "tests")
MAX_LINES = 500
# A file may be longer when its docstring gives the reason with these words.
LONG_FILE_MARK = "longer than 500 lines because"


def _lint_imports() -> Path:
    script = Path(sys.executable).parent / "lint-imports"
    if not script.exists():
        pytest.fail(f"import-linter is not installed beside {sys.executable} (test extra)")
    return script


def test_import_contracts_hold() -> None:
    out = subprocess.run(
        [str(_lint_imports()), "--no-cache"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    assert "0 broken" in out.stdout, out.stdout


def _python_files(*packages: str) -> list[Path]:
    files: list[Path] = []
    for package in packages:
        files += [
            p for p in sorted((ROOT / package).rglob("*.py")) if "node_modules" not in p.parts
        ]
    return files


def _top_package(path: Path) -> str:
    return path.relative_to(ROOT).parts[0]


def _private_imports(path: Path) -> list[str]:
    """``from other_package... import _name`` where other_package is not path's own."""
    tree = ast.parse(path.read_text(), filename=str(path))
    own = _top_package(path)
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.ImportFrom) or node.level != 0 or node.module is None:
            continue
        top = node.module.split(".")[0]
        if top == own or top not in CHECKED:
            continue
        found += [
            f"{path.relative_to(ROOT)}:{node.lineno}: from {node.module} import {alias.name}"
            for alias in node.names
            if alias.name.startswith("_") and not alias.name.startswith("__")
        ]
    return found


def test_no_private_names_imported_across_packages() -> None:
    found = [line for path in _python_files(*CHECKED) for line in _private_imports(path)]
    assert found == [], "\n".join(found)


def test_private_name_check_can_fail(tmp_path: Path) -> None:
    # The check above must see what it forbids: a file of `tests` reaching into solver.
    bad = ROOT / "tests" / "_architecture_probe_tmp.py"
    bad.write_text("from solver.errors import _hidden\n")
    try:
        assert _private_imports(bad) == [
            "tests/_architecture_probe_tmp.py:1: from solver.errors import _hidden"
        ]
    finally:
        bad.unlink()


def test_product_files_are_small_or_say_why() -> None:
    too_long = []
    for path in _python_files(*PRODUCT):
        text = path.read_text()
        lines = text.count("\n")
        if lines <= MAX_LINES:
            continue
        doc = ast.get_docstring(ast.parse(text)) or ""
        if LONG_FILE_MARK not in doc:
            too_long.append(f"{path.relative_to(ROOT)}: {lines} lines")
    assert too_long == [], "\n".join(too_long)
