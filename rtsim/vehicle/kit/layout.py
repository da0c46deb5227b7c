"""Index layouts of the flat float arrays the kernels share (parameters, states, inputs, outputs),
declared once as a sequence of block sizes and generated: no offset is kept by hand.

    class PartPar(IntEnum):
        '''The part's parameter array.'''
        A, B, LAG, SIZE = offsets(1, 1, LAG_NPAR)

gives the start of each block in declaration order, then the total size, as members of a named
enumeration: `p[PartPar.LAG]` says which array the index belongs to, where a bare prefix (`SP_`) meant
a different array in each module. numba reads an IntEnum member as a compile-time constant (the same
machine code as a plain int); module-level ints from `offsets` are the older form, still used by
layouts whose prefix no other module shares.
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
