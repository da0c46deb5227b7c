"""Kernels and named tuples for tests/test_boundcall.py: module level, so rtsim.boundcall's generated
wrappers can import them (also in a second process)."""
from __future__ import annotations

from collections import namedtuple

import numba as nb
import numpy as np

from rtsim.jit import kernel

Inner = namedtuple("Inner", ["flags", "img", "count", "empty"])
Outer = namedtuple("Outer", ["x", "inner", "pair", "zero_d", "ro", "ids"])


def make_outer(seed: int = 0) -> Outer:
    """Mixed dtypes and ranks: float64 1-d, bool 1-d, uint8 3-d, int32 2-d, float32 and complex128
    1-d, a 0-d array, an empty 2-d one, a readonly one, int64 1-d; a Python int inside; a plain tuple
    nested in a named tuple nested in a named tuple."""
    rng = np.random.default_rng(seed)
    ro = rng.normal(size=5)
    ro.setflags(write=False)
    return Outer(
        x=rng.normal(size=7),
        inner=Inner(flags=rng.random(6) > 0.5, img=rng.integers(0, 255, (2, 3, 4), dtype=np.uint8), count=3,
                    empty=np.zeros((0, 3))),
        pair=(rng.integers(-9, 9, (3, 2), dtype=np.int32),
              (rng.normal(size=4).astype(np.float32), rng.normal(size=3) + 1j * rng.normal(size=3))),
        zero_d=np.array(rng.normal()), ro=ro, ids=np.arange(4, dtype=np.int64))


@kernel
def mix(o, k, flag, scale, big, f32, out, dx):
    """Reads every part of ``o`` and the fixed scalars, writes into ``o`` and the free array ``out``,
    returns scalars of each type."""
    acc = 0.0
    for i in range(o.x.shape[0]):
        o.x[i] = o.x[i] * scale + dx
        acc += o.x[i]
    nflag = 0
    for i in range(o.inner.flags.shape[0]):
        if o.inner.flags[i]:
            nflag += 1
        o.inner.flags[i] = not o.inner.flags[i]
    isum = 0
    for a in range(o.inner.img.shape[0]):
        for b in range(o.inner.img.shape[1]):
            for c in range(o.inner.img.shape[2]):
                isum += o.inner.img[a, b, c]
                o.inner.img[a, b, c] += np.uint8(1)
    m32 = o.pair[0]
    for a in range(m32.shape[0]):
        for b in range(m32.shape[1]):
            m32[a, b] = m32[a, b] * np.int32(k) + np.int32(o.inner.count)
    fsum = np.float32(0.0)
    for v in o.pair[1][0]:
        fsum += v * f32
    csum = 0j
    for v in o.pair[1][1]:
        csum += v * v
    o.zero_d[()] += dx
    rsum = 0.0
    for v in o.ro:
        rsum += v
    for i in range(out.shape[0]):
        out[i] = acc + i + o.ids[i % o.ids.shape[0]]
    return (acc, nflag, isum, fsum, csum, o.zero_d[()], rsum, o.inner.empty.shape[0], o.inner.empty.shape[1],
            flag, big, k)


@kernel
def total(a, b):
    """Sum of the free pair (no fixed argument)."""
    return a + b


@kernel
def fill(x, v):
    """x[:] = v (a kernel with one fixed array; returns nothing)."""
    for i in range(x.shape[0]):
        x[i] = v


@kernel
def first(x, a):
    """Returns a (x: whatever the error tests pass)."""
    return a


@nb.njit(cache=True)
def with_nrt(x, a):
    """A kernel compiled with the numba runtime on (bind refuses it)."""
    return a
