"""How rtsim compiles its kernels.

`kernel` is numba's njit with the on-disk cache and with the numba runtime (NRT) off. Kernels take the
model and state as named tuples of arrays and never allocate; with NRT on, every call between kernels
increments and decrements the reference count of each of the ~70 arrays it passes (measured here:
about 400 ns per call, most of a 10 us step); with NRT off that cost is gone (about 7 ns per call),
and any allocation inside a kernel becomes a compile error, which enforces the no-allocation rule.
"""
from __future__ import annotations

import numba as nb
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

kernel = nb.njit(cache=True, _nrt=False)


def inline_kernel(fn):
    """A small kernel inlined into its callers at numba-IR level."""
    return nb.njit(cache=True, _nrt=False, inline="always")(fn)


@intrinsic
def read_cycles(typingctx):
    """The processor's cycle counter (``llvm.readcyclecounter``: the TSC on x86-64), for timing code
    inside kernels at a cost of a few nanoseconds; convert with ``cycles_per_second()``."""
    sig = types.int64()

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(64), [])
        fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.readcyclecounter")
        return builder.call(fn, [])
    return sig, codegen


@kernel
def _cycles_now():
    return read_cycles()


def cycles_per_second(interval: float = 0.05) -> float:
    """The cycle counter's rate, measured against the monotonic clock over ``interval`` s."""
    import time

    _cycles_now()
    t0, c0 = time.perf_counter(), _cycles_now()
    while time.perf_counter() - t0 < interval:
        pass
    t1, c1 = time.perf_counter(), _cycles_now()
    return (c1 - c0) / (t1 - t0)
