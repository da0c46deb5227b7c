"""Index layouts of the flat float arrays the kernels share (parameters, states, inputs, outputs),
declared once as a sequence of block sizes and generated: no offset is kept by hand.

    SP_A, SP_B, SP_LAG, SP_SIZE = offsets(1, 1, LAG_NPAR)

gives the start of each block in declaration order, then the total size. The names on the left are
plain module-level ints, which the numba kernels read as compile-time constants.
"""
from __future__ import annotations


def offsets(*sizes: int) -> tuple[int, ...]:
    """Start offset of each consecutive block of the given sizes, then the total size."""
    out, at = [], 0
    for n in sizes:
        if int(n) != n or n < 0:
            raise ValueError(f"block size must be a non-negative integer, got {n!r}")
        out.append(at)
        at += int(n)
    return (*out, at)
