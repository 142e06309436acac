"""The numba cache stamp's exclusions (``solver/_jit.py``, ``_NOT_COMPILED``) stay safe.

A file left out of the stamp can be edited without recompiling the solver, which is
only right while it holds no compiled function and no compiled code can read one of
its constants (numba freezes a global's value into the machine code that reads it).
These tests fail when a listed file gains a compiled function, or when a compiled
module starts importing a listed file.

The list is read from _jit.py's source (the module is private to ``solver``).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SOLVER = ROOT / "solver"
# The decorators that compile: solver/_jit.py's and numba's own (importing numba for
# its types or errors, as precompile.py does, compiles nothing).
COMPILERS = frozenset({"jit", "jit_leaf", "jit_inline", "njit", "generated_jit", "cfunc"})


def _not_compiled() -> frozenset[str]:
    """The names in ``_NOT_COMPILED = frozenset({...})``, read from _jit.py's source."""
    tree = ast.parse((SOLVER / "_jit.py").read_text())
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and [t.id for t in node.targets if isinstance(t, ast.Name)] == ["_NOT_COMPILED"]
            and isinstance(node.value, ast.Call)
        ):
            (literal,) = node.value.args
            return frozenset(ast.literal_eval(literal))
    raise AssertionError("solver/_jit.py has no _NOT_COMPILED = frozenset({...})")


def _compiler_uses(path: Path) -> list[str]:
    """Where a file imports solver/_jit.py or names a compiling decorator."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import | ast.ImportFrom):
            if isinstance(node, ast.Import):
                modules = [alias.name for alias in node.names]
            else:
                modules = [node.module or ""]
            if any(m.split(".")[-1] == "_jit" for m in modules):
                found.append(f"{path.name}:{node.lineno}: imports {', '.join(modules)}")
        elif isinstance(node, ast.Name) and node.id in COMPILERS:
            found.append(f"{path.name}:{node.lineno}: uses {node.id}")
        elif isinstance(node, ast.Attribute) and node.attr in COMPILERS:
            found.append(f"{path.name}:{node.lineno}: uses {node.attr}")
    return found


def _imported_files(path: Path, root: Path) -> set[str]:
    """Files under root (as paths relative to it) that path imports, directly or as
    ``from package import module``."""
    package = list(path.relative_to(root.parent).with_suffix("").parts[:-1])
    dotted: list[str] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            dotted += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            module = ".".join([*base, *(node.module.split(".") if node.module else [])])
            dotted += [module, *(f"{module}.{alias.name}" for alias in node.names)]
    files = set()
    for name in dotted:
        parts = name.split(".")
        if parts[0] != root.name:
            continue
        for candidate in (Path(*parts[1:]).with_suffix(".py"), Path(*parts[1:], "__init__.py")):
            if (root / candidate).is_file():
                files.add(candidate.as_posix())
    return files


def test_listed_files_exist() -> None:
    listed = _not_compiled()
    assert "model/gltf.py" in listed  # the list was read, not an empty parse
    missing = sorted(name for name in listed if not (SOLVER / name).is_file())
    assert missing == [], f"_NOT_COMPILED names files that do not exist: {missing}"


def test_listed_files_define_no_compiled_function() -> None:
    found = [use for name in sorted(_not_compiled()) for use in _compiler_uses(SOLVER / name)]
    assert found == [], "a file left out of the numba cache stamp compiles:\n" + "\n".join(found)


def test_no_compiled_module_imports_a_listed_file() -> None:
    listed = _not_compiled()
    found = []
    for path in sorted(SOLVER.rglob("*.py")):
        name = path.relative_to(SOLVER).as_posix()
        if name in listed or not _compiler_uses(path):
            continue
        found += [f"{name} imports {f}" for f in sorted(_imported_files(path, SOLVER) & listed)]
    assert found == [], "compiled code could read a file left out of the stamp:\n" + "\n".join(
        found
    )


def test_the_checks_see_what_they_forbid(tmp_path: Path) -> None:
    # A copy of the layout with a listed-style importer that gained a compiled helper,
    # and a compiled module that imports it relatively.
    root = tmp_path / "solver"
    (root / "model").mkdir(parents=True)
    (root / "model" / "__init__.py").write_text("")
    (root / "model" / "gltf.py").write_text(
        "from .._jit import jit_leaf\n\n@jit_leaf\ndef f(x):\n    return x\n\nLIMIT = 3\n"
    )
    kernel = root / "model" / "forward.py"
    kernel.write_text("from solver._jit import jit\nfrom . import gltf\nfrom .gltf import LIMIT\n")
    assert _compiler_uses(root / "model" / "gltf.py") == [
        "gltf.py:1: imports _jit",
        "gltf.py:3: uses jit_leaf",
    ]
    assert _imported_files(kernel, root) == {"model/__init__.py", "model/gltf.py"}
