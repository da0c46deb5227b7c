"""How rtsim compiles its kernels.

`kernel` is numba's njit with the on-disk cache and with the numba runtime (NRT) off. Kernels take the
model and state as named tuples of arrays and never allocate; with NRT on, every call between kernels
increments and decrements the reference count of each of the ~70 arrays it passes (measured here:
about 400 ns per call, most of a 10 us step); with NRT off that cost is gone (about 7 ns per call),
and any allocation inside a kernel becomes a compile error, which enforces the no-allocation rule.
"""
from __future__ import annotations

import numba as nb

kernel = nb.njit(cache=True, _nrt=False)


def inline_kernel(fn):
    """A small kernel inlined into its callers at numba-IR level."""
    return nb.njit(cache=True, _nrt=False, inline="always")(fn)
