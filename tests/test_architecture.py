"""The layout's rules (ARCHITECTURE.md), checked on every run.

- The import contracts in pyproject.toml ([tool.importlinter]): import-linter builds the
  import graph of the packages and checks each contract (layers, forbidden imports,
  private modules, no cycles between siblings).
- No module imports an underscore *name* from another top-level package
  (import-linter sees modules only, so ``from solver.ik import _Planner`` needs this).
- No Python file of the product (the service's packages and the Python client) is over
  500 lines, unless its docstring says why; nor is a TypeScript file of the TypeScript
  client's src/, unless its leading comment says why.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("solver", "schemas", "service")
# The clients are product too: what a game or a robot runs to reach the service.
PYTHON_CLIENT = "clients/python/ik_client"
TYPESCRIPT_CLIENT = "clients/typescript/src"
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


def _too_long(path: Path) -> str | None:
    """``path: N lines`` when ``path`` is over MAX_LINES and its docstring (a Python
    module's; a TypeScript file's leading ``/** ... */`` comment) does not say why."""
    text = path.read_text()
    lines = text.count("\n")
    if lines <= MAX_LINES:
        return None
    if path.suffix == ".py":
        doc = ast.get_docstring(ast.parse(text)) or ""
    else:
        leading = re.match(r"\s*/\*\*(.*?)\*/", text, re.DOTALL)
        doc = " ".join(leading.group(1).replace("*", " ").split()) if leading else ""
    if LONG_FILE_MARK in doc:
        return None
    return f"{path.relative_to(ROOT)}: {lines} lines"


def _product_files() -> list[Path]:
    return [
        *_python_files(*PRODUCT, PYTHON_CLIENT),
        *sorted((ROOT / TYPESCRIPT_CLIENT).glob("*.ts")),
    ]


def test_product_files_are_small_or_say_why() -> None:
    files = _product_files()
    # The clients are in the list: a path that moved would otherwise check nothing.
    assert ROOT / PYTHON_CLIENT / "__init__.py" in files
    assert ROOT / TYPESCRIPT_CLIENT / "index.ts" in files
    too_long = [line for path in files if (line := _too_long(path)) is not None]
    assert too_long == [], "\n".join(too_long)


@pytest.mark.parametrize("suffix", [".py", ".ts"])
def test_line_cap_can_fail(suffix: str) -> None:
    # The check above must see a long file, and let one through whose docstring says why.
    probe = ROOT / "tests" / f"_architecture_probe_tmp{suffix}"
    body = "x = 1\n" * (MAX_LINES + 1)
    if suffix == ".py":
        because = f'"""A probe, {LONG_FILE_MARK} it must be."""\n'
    else:
        because = "/**\n * A probe, longer than 500\n * lines because it must be.\n */\n"
    try:
        probe.write_text(body)
        assert _too_long(probe) == f"tests/{probe.name}: {MAX_LINES + 1} lines"
        probe.write_text(because + body)
        assert _too_long(probe) is None
    finally:
        probe.unlink()
