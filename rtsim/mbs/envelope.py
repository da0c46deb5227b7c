"""Sparse symmetric matrices in envelope (skyline) storage, and their Cholesky factorization.

The ALI3-P tangent matrix M + (dt/2) C + (dt^2/4)(Phi_q^T alpha Phi_q + K) has a sparsity pattern that
is fixed once the mechanism is compiled. We order its rows with reverse Cuthill-McKee (scipy) to make
the profile small, then store, for each permuted row r, the columns first[r]..r contiguously. The
Cholesky factor of a matrix fits in the same envelope (fill-in stays inside the profile), so
factorization costs O(n b^2) and a solve O(n b) for an average half-bandwidth b: a chain of bodies
(the N-four-bar) costs linear time in N instead of the O(N^3) of a dense solve.
The integrator keeps M, W and the forces' tangent here, and factors A in its own sparse pattern
(rtsim.mbs.sparse), which skips the zeros inside the profile.

All kernels work in *permuted* indices: entry (i, j) of the original matrix lives at permuted
(pinv[i], pinv[j]).
"""
from __future__ import annotations

import numpy as np
from rtsim.jit import inline_kernel, kernel, uidx
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee


def symbolic(n: int, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ordering and envelope layout for a symmetric pattern.

    pairs: (k, 2) int array of structurally nonzero (i, j) entries in original indices (either
    triangle; the diagonal is always included). Returns perm (new -> old), pinv (old -> new),
    first (first stored column of each permuted row) and ptr (row start offsets, length n + 1).
    """
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(n)])
    pattern = coo_matrix((np.ones(rows.size), (rows, cols)), shape=(n, n)).tocsr()
    perm = np.asarray(reverse_cuthill_mckee(pattern, symmetric_mode=True), dtype=np.int64)
    pinv = np.empty(n, dtype=np.int64)
    pinv[perm] = np.arange(n)
    first = np.arange(n, dtype=np.int64)
    pr, pc = pinv[rows], pinv[cols]
    lower = pc <= pr
    np.minimum.at(first, pr[lower], pc[lower])
    ptr = np.zeros(n + 1, dtype=np.int64)
    ptr[1:] = np.cumsum(np.arange(n) - first + 1)
    return perm, pinv, first, ptr


@inline_kernel
def pos(first, ptr, r, c):
    """Storage offset of permuted entry (r, c) with c <= r."""
    return ptr[r] + c - first[r]


@inline_kernel
def add_entry(env, first, ptr, pinv, i, j, value):
    """Add value to the symmetric entry (i, j) (original indices). A diagonal entry gets it once;
    an off-diagonal pair (i, j) ~ (j, i) is stored once, so callers add each unordered pair once.
    A pair outside the envelope is dropped (it would land on another row's storage): declare every
    coupling a force's tangent needs in the pattern (MechanismBuilder.couple)."""
    r = pinv[uidx(i)]
    c = pinv[uidx(j)]
    if c > r:
        r, c = c, r
    fr = first[uidx(r)]
    if c >= fr:         # outside the profile there is no storage: the pattern must include the pair
        env[uidx(ptr[uidx(r)]) + uidx(c - fr)] += value


@kernel
def cholesky(a, first, ptr, out):
    """In-place-safe envelope Cholesky: out = L with L L^T = a. Returns the permuted row of the
    first non-positive pivot, or -1 on success."""
    n = first.shape[0]
    for r in range(n):
        fr = first[r]
        base_r = ptr[r] - fr
        for c in range(fr, r + 1):
            fc = first[c]
            base_c = ptr[c] - fc
            k0 = fr if fr > fc else fc
            s = a[base_r + c]
            for k in range(k0, c):
                s -= out[base_r + k] * out[base_c + k]
            if c < r:
                out[base_r + c] = s / out[base_c + c]
            else:
                if not (s > 0.0):
                    return r
                out[base_r + r] = np.sqrt(s)
    return -1


@kernel
def solve(l, first, ptr, perm, pinv, b, x, work):
    """Solve (L L^T) x = b in original indices; b may alias x. work: length-n scratch."""
    n = first.shape[0]
    for i in range(n):
        work[pinv[i]] = b[i]
    # forward: L y = b
    for r in range(n):
        fr = first[r]
        base = ptr[r] - fr
        s = work[r]
        for k in range(fr, r):
            s -= l[base + k] * work[k]
        work[r] = s / l[base + r]
    # backward: L^T x = y, column sweep
    for r in range(n - 1, -1, -1):
        fr = first[r]
        base = ptr[r] - fr
        xr = work[r] / l[base + r]
        work[r] = xr
        for k in range(fr, r):
            work[k] -= l[base + k] * xr
    for r in range(n):
        x[perm[r]] = work[r]


@kernel
def matvec_add(a, first, ptr, perm, pinv, x, y, scale):
    """y += scale * A x for a symmetric A in envelope storage (original indices)."""
    n = first.shape[0]
    for r in range(n):
        fr = first[r]
        base = uidx(ptr[r])             # entry (r, c) at base + c - fr
        i = uidx(perm[r])
        xi = x[i]
        acc = a[base + uidx(r - fr)] * xi
        for c in range(fr, r):
            arc = a[base + uidx(c - fr)]
            if arc != 0.0:
                j = uidx(perm[c])
                acc += arc * x[j]
                y[j] += scale * arc * xi
        y[i] += scale * acc


def to_envelope(dense: np.ndarray, first, ptr, perm) -> np.ndarray:
    """Envelope values of a dense symmetric matrix (build time only)."""
    n = first.shape[0]
    env = np.zeros(ptr[n])
    width = np.arange(n) - first + 1                       # entries of each row: columns first[r]..r
    rows = np.repeat(np.arange(n), width)
    k = np.arange(rows.size) - np.repeat(np.cumsum(width) - width, width)   # position in its row
    env[ptr[rows] + k] = dense[perm[rows], perm[first[rows] + k]]
    return env


def from_envelope(env: np.ndarray, first, ptr, perm) -> np.ndarray:
    """Dense symmetric matrix from envelope values (tests and diagnostics)."""
    n = first.shape[0]
    out = np.zeros((n, n))
    for r in range(n):
        for c in range(first[r], r + 1):
            v = env[ptr[r] + c - first[r]]
            out[perm[r], perm[c]] = v
            out[perm[c], perm[r]] = v
    return out
