"""A monotonic clock usable inside numba-compiled code.

numba cannot call ``time.perf_counter``; a ctypes pointer to ``clock_gettime``
would work but makes the caller uncacheable (the address is baked in). This
intrinsic emits a call to the libc symbol by name instead, which numba's on-disk
cache keeps. ``CLOCK_MONOTONIC`` is what ``time.perf_counter`` reads on Linux, so
deadlines computed in Python as ``perf_counter() + budget`` compare directly.
Under ``NUMBA_DISABLE_JIT=1`` the plain-Python ``now_s`` is used instead.
"""

from __future__ import annotations

import time
from typing import Any

from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic, overload

_CLOCK_MONOTONIC = 1


@intrinsic
def _monotonic_ns(typingctx: Any) -> Any:
    sig = types.int64()

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        i64 = ir.IntType(64)
        i32 = ir.IntType(32)
        timespec = ir.LiteralStructType([i64, i64])
        fnty = ir.FunctionType(i32, [i32, timespec.as_pointer()])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "clock_gettime")
        ts = cgutils.alloca_once(builder, timespec)
        builder.call(fn, [ir.Constant(i32, _CLOCK_MONOTONIC), ts])
        sec = builder.load(cgutils.gep_inbounds(builder, ts, 0, 0))
        nsec = builder.load(cgutils.gep_inbounds(builder, ts, 0, 1))
        return builder.add(builder.mul(sec, ir.Constant(i64, 1_000_000_000)), nsec)

    return sig, codegen


def now_s() -> float:
    """Seconds on the ``time.perf_counter`` clock, callable from compiled code."""
    return time.perf_counter()


@overload(now_s)
def _now_s_compiled() -> Any:
    def impl() -> float:
        return _monotonic_ns() * 1e-9  # type: ignore[call-arg]  # typingctx is numba's

    return impl
