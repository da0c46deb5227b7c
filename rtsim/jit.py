"""How rtsim compiles its kernels.

`kernel` is numba's njit with the on-disk cache and with the numba runtime (NRT) off. Kernels take the
model and state as named tuples of arrays and never allocate; with NRT on, every call between kernels
increments and decrements the reference count of each of the ~70 arrays it passes (measured here:
about 400 ns per call, most of a 10 us step); with NRT off that cost is gone (about 7 ns per call),
and any allocation inside a kernel becomes a compile error, which enforces the no-allocation rule.
"""
from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba.core import cgutils, types
from numba.extending import intrinsic

kernel = nb.njit(cache=True, _nrt=False, forceinline=False)

#: a kernel whose machine code LLVM inlines into every compiled caller (numba's ``forceinline``: the
#: function attribute alwaysinline), for the stages of a step. A call between kernels passes each array
#: of its named tuples as its pointers, sizes and strides, one argument each: about 540 machine words for
#: the model and the state, 1000 with a car's parts, copied at every call and every nested call. Measured on
#: the X-by-wire car's step steer (rtsim bench --suite vehicle): 10.0 us a step with the integrator's stages
#: and the car's forces called, 8.0 us with them and the constraint, factor, solve and projection kernels
#: inlined this way; the results the same bytes. numba's own ``inline="always"`` (inline_kernel) gave the
#: same speed but copies the callee's IR at each inlining: the benchmark's first compile took 427 s
#: instead of 153 s. ``kernel`` sets forceinline off explicitly, as numba passes it on to callees that do not.
stage_kernel = nb.njit(cache=True, _nrt=False, forceinline=True)

#: an index known to be >= 0, as an unsigned integer for a hot loop: ``a[uidx(i)]``. numba tests every
#: signed index for a negative value (wrapping it around the array's end) on each access; an unsigned
#: one is used as it is. Measured on the sparse factor's 18 x 18 dense block: 1.8 times as fast. Mixed
#: with a signed integer in arithmetic an unsigned one gives a float: convert both sides.
uidx = np.uint64


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


def _paired_reading(tries: int = 20) -> tuple[float, int]:
    """(monotonic clock in s, cycle counter) read together: the counter read between two clock readings,
    the clock taken at their midpoint; of ``tries`` pairs the one with the narrowest bracket, so that a
    pause of the process between the two readings (milliseconds on a loaded machine) cannot enter it."""
    import time

    best = None
    for _ in range(tries):
        ta = time.perf_counter()
        c = _cycles_now()
        tb = time.perf_counter()
        if best is None or tb - ta < best[0]:
            best = (tb - ta, 0.5 * (ta + tb), c)
    return best[1], best[2]


def cycles_per_second(interval: float = 0.05) -> float:
    """The cycle counter's rate, measured against the monotonic clock over ``interval`` s (each end a
    bracketed pair of readings, ``_paired_reading``: a pause between reading one clock and the other
    would otherwise skew the rate by pause / interval, a few per cent)."""
    import time

    _cycles_now()
    t0, c0 = _paired_reading()
    while time.perf_counter() - t0 < interval:
        pass
    t1, c1 = _paired_reading()
    return (c1 - c0) / (t1 - t0)
