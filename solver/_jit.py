"""The one decorator every compiled function of the solver uses, and its cache policy.

- ``cache=True``: compiled code goes to ``NUMBA_CACHE_DIR`` when it is set and
  writable, else to each module's ``__pycache__`` (about 0.2 s to load instead of
  seconds to compile; ``solver.precompile.cache_location`` says which).
- ``error_model="numpy"``: division by zero gives inf/nan instead of raising. The
  core detects non-finite values itself (NONFINITE), and a function that can raise
  embeds a pointer to the exception object, which stops numba from caching any
  caller that receives it as a function argument.
- ``nogil=True``: a solve never touches Python objects, so other threads (the
  service's event loop) keep running while it works.

Cache invalidation. numba stamps a cached function with its *own* source file only;
a caller in ik/frame.py keeps its cached machine code, with the old callee compiled
in, after ik/kinematics.py changes. That is how an upgrade would silently run old
code. So every function compiled through ``jit`` is stamped with a hash of all of
solver/'s sources, its subpackages' included, plus its own file: any change anywhere
in the package recompiles everything, except in the files of ``_NOT_COMPILED``
(pure-Python modules no compiled code reads: the importers, the example chains,
precompile.py).

One gap the stamp cannot close: an objective registered from outside solver/
(``solver.optim.register_objective``, e.g. the tests' MGH problems) is compiled into
the core's cached code under solver/'s stamp. After editing such an objective, empty
the cache (the ``__pycache__`` directories under solver/, or ``NUMBA_CACHE_DIR``; or
point ``NUMBA_CACHE_DIR`` at a fresh directory) so that the core is compiled again.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

import numba
from numba import njit
from numba.core import caching

F = TypeVar("F")

_MARK = "__ik_solver_cache__"
_SOLVER_DIR = Path(__file__).resolve().parent


# Files left out of the stamp: they define no compiled function (no jit, jit_leaf or
# jit_inline) and no compiled module imports them, so no compiled code can read their
# constants (numba freezes a global's value into the machine code that reads it, which
# is why model/layout.py's columns stay in). Editing one of them, the importers and the
# example chains (pure Python that only *calls* compiled code), must not throw away
# minutes of compilation. tests/solver/test_jit_stamp.py checks both conditions.
_NOT_COMPILED = frozenset(
    {
        "precompile.py",
        "model/bones.py",
        "model/bvh.py",
        "model/examples.py",
        "model/gltf.py",
        "model/gltf_container.py",
        "model/notes.py",
        "model/skeleton.py",
        "model/skeleton_settings.py",
        "model/urdf.py",
        "model/urdf_xml.py",
    }
)


def _package_digest() -> bytes:
    h = hashlib.sha256(numba.__version__.encode())
    for path in sorted(_SOLVER_DIR.rglob("*.py")):
        name = path.relative_to(_SOLVER_DIR).as_posix()
        if name in _NOT_COMPILED:
            continue
        h.update(name.encode())
        h.update(path.read_bytes())
    return h.digest()


_PACKAGE_DIGEST = _package_digest()


class _PackageStamp:
    """A numba cache locator's source stamp over all of solver/ (module docstring),
    for the functions ``jit`` marks only (numba's own locators serve the rest)."""

    _py_file: str

    def get_source_stamp(self) -> Any:
        own = Path(self._py_file).read_bytes()
        return hashlib.sha256(_PACKAGE_DIGEST + own).hexdigest()

    @classmethod
    def from_function(cls, py_func: Any, py_file: str) -> Any:
        if not getattr(py_func, _MARK, False):
            return None
        return super().from_function(py_func, py_file)  # type: ignore[misc]


class _SolverUserDirLocator(_PackageStamp, caching.UserProvidedCacheLocator):
    """``NUMBA_CACHE_DIR``, when set, as numba's own locators honour it: first."""


class _SolverPackageLocator(_PackageStamp, caching.InTreeCacheLocator):
    """numba's in-tree locator (each module's ``__pycache__``), when no directory is set."""


# Ours before numba's (which would stamp by the file alone), and among ours the user's
# directory before the tree, as numba orders its own: an image that compiles as root
# into NUMBA_CACHE_DIR and runs as another user must find its cache there, not in a
# site-packages __pycache__ that user cannot write (numba skips a cache directory it
# cannot write to, and would compile again).
for _locator in (_SolverPackageLocator, _SolverUserDirLocator):
    if _locator not in caching.CacheImpl._locator_classes:
        caching.CacheImpl._locator_classes.insert(0, _locator)


def _compile(fn: Any, **options: Any) -> Any:
    setattr(fn, _MARK, True)
    return njit(cache=True, error_model="numpy", nogil=True, **options)(fn)


def jit(fn: F) -> F:
    compiled: F = _compile(fn)
    return compiled


def jit_inline(fn: F) -> F:
    """``jit`` plus numba-IR inlining into callers.

    For helpers of the objective: a call that passes the data tuple costs reference
    counting per array; inlined, numba prunes those reference counts.
    """
    compiled: F = _compile(fn, inline="always")
    return compiled


def jit_leaf(fn: F) -> F:
    """``jit`` without numba's reference counting (``_nrt=False``), for the solve's hot
    functions: the objective, the metric, forward kinematics and the core loop.

    Why: numba counts references to every array a function receives or slices, with
    an atomic increment and decrement per array per call. ``perf`` on a solve loop put
    46% of the samples on those two instructions (NRT_incref / NRT_decref) after the
    per-joint helpers had already been made scalar; with the hot path compiled this
    way a 7-DOF iteration went from ~1.7 us to ~0.7 us, iterates unchanged
    (bench/RESULTS.md).

    The rules, which the type checker cannot see: such a function allocates nothing
    (no ``np.empty``; numba refuses to compile it), returns no array, and every array
    it touches is owned by its caller for the whole call (the caller holds the
    references; views made inside live no longer than the call). numba compiles the
    functions it calls with the same flag when it compiles them first from here, so
    they must follow the rules too (work arrays come from the caller: ``run_solver``'s
    ``work`` block, DD's rows). That inheritance depends on call order (whichever
    caller compiles a helper first decides its build) and numba's on-disk cache key
    does not record it, so an allocation added to a shared helper could compile with
    a warm cache and fail in a fresh one: every helper the IK path reaches is
    therefore marked ``jit_leaf`` itself (``optim.line_search.curvature_phase``
    excepted: it calls ``minimize()``'s objectives, which may allocate; it allocates
    nothing itself).
    """
    compiled: F = _compile(fn, _nrt=False)
    return compiled


def compiled_entry(dispatcher: Any, args: tuple[Any, ...]) -> Callable[..., Any]:
    """The compiled overload of ``dispatcher`` for these arguments' types, called
    directly: skips the dispatcher's per-call type resolution (~0.3 us of a ~20 us
    solve). Only for callers whose argument types never change, as an IKSolver's
    (its arrays are its own; seeds and H pass ``check_seed`` / the H check, which
    fix dtype, layout and writeability). The dispatcher itself if there is no such
    overload (``NUMBA_DISABLE_JIT``).
    """
    overloads = getattr(dispatcher, "overloads", None)
    if overloads is None:
        return cast(Callable[..., Any], dispatcher)
    compiled = overloads.get(tuple(numba.typeof(a) for a in args))
    return cast(Callable[..., Any], dispatcher if compiled is None else compiled.entry_point)
