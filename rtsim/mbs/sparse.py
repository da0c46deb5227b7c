"""The tangent matrix's Cholesky factor in compressed sparse columns, on a fill-reducing ordering.

W, M and the forces' tangent stay in envelope storage (rtsim.mbs.envelope: cheap to add entries to and
to multiply with); the factorization gathers A = W + bq Phi_q^T alpha Phi_q into the factor's own
pattern and factors it there. The ordering is the cheaper (fewer multiply-adds) of minimum degree and
the envelope's reverse Cuthill-McKee; only the structural nonzeros of L are stored and visited, where
the envelope factorization also runs over the zeros inside the profile (for the 50-coordinate
motorcycle: 387 column updates and 437 entries instead of 5654 multiply-adds over 692 entries).

L is stored by columns in factor-permuted indices: column j holds rows rowidx[colptr[j]:colptr[j+1]],
the diagonal first, the others ascending. The diagonal is stored inverted, 1 / L[j, j], so that the
substitutions multiply instead of divide (a division's latency sits on their dependency chain: about
15 % of a solve of the motorcycle's tangent). Column j is updated by every earlier column k with L[j, k] != 0;
upos[uptr[j]:uptr[j+1]] lists the positions of those L[j, k], and since rows ascend within a column,
the update by column k runs from that position to the column's end. Where those rows are consecutive
(the dense trailing block a vehicle's tangent ends in), the updates and substitutions index directly
instead of through rowidx: the same operations in the same order, which the compiler can vectorise.
"""
from __future__ import annotations

import numpy as np
from rtsim.jit import kernel


def _adjacency(n: int, pairs: np.ndarray) -> list[set]:
    adj = [set() for _ in range(n)]
    for i, j in np.asarray(pairs, dtype=np.int64).reshape(-1, 2):
        if i != j:
            adj[i].add(int(j))
            adj[j].add(int(i))
    return adj


def minimum_degree(n: int, pairs: np.ndarray) -> np.ndarray:
    """Elimination order (new -> old) by minimum degree on the explicit elimination graph (ties: lowest
    index). Build time only."""
    adj = _adjacency(n, pairs)
    alive = set(range(n))
    order = []
    for _ in range(n):
        k = min(alive, key=lambda v: (len(adj[v]), v))
        nb = adj[k]
        for a in nb:
            adj[a].discard(k)
            adj[a] |= nb - {a}
        order.append(k)
        alive.discard(k)
        adj[k] = set()
    return np.array(order, dtype=np.int64)


def symbolic(n: int, pairs: np.ndarray, perm: np.ndarray) -> dict:
    """The pattern of L for ordering `perm` (new -> old) and the update lists of the numeric kernel:
    pinv, colptr, rowidx, uptr, upos, pcol (each position's column), and the multiply-adds it costs."""
    perm = np.asarray(perm, dtype=np.int64)
    pinv = np.empty(n, dtype=np.int64)
    pinv[perm] = np.arange(n)
    adj = _adjacency(n, pairs)
    nadj = [set(int(pinv[a]) for a in adj[perm[r]]) for r in range(n)]
    cols = []
    for k in range(n):
        below = sorted(a for a in nadj[k] if a > k)
        cols.append(below)
        for a in below:
            nadj[a].update(b for b in below if b != a)
    colptr = np.zeros(n + 1, dtype=np.int64)
    for k in range(n):
        colptr[k + 1] = colptr[k] + 1 + len(cols[k])
    rowidx = np.array([r for k in range(n) for r in [k] + cols[k]], dtype=np.int64)
    pcol = np.repeat(np.arange(n, dtype=np.int64), np.diff(colptr))
    upd = [[] for _ in range(n)]
    for k in range(n):
        for p in range(colptr[k] + 1, colptr[k + 1]):
            upd[rowidx[p]].append(p)
    uptr = np.zeros(n + 1, dtype=np.int64)
    for j in range(n):
        uptr[j + 1] = uptr[j] + len(upd[j])
    upos = np.array([p for j in range(n) for p in upd[j]], dtype=np.int64)
    macs = int(sum(colptr[pcol[p] + 1] - p for p in upos))
    return dict(perm=perm, pinv=pinv, colptr=colptr, rowidx=rowidx, uptr=uptr, upos=upos, pcol=pcol, macs=macs)


def position(s: dict, i: int, j: int) -> int:
    """Storage position of entry (i, j) (original indices) in the factor's pattern, or -1."""
    r, c = int(s["pinv"][i]), int(s["pinv"][j])
    if c > r:
        r, c = c, r
    rows = s["rowidx"][s["colptr"][c]:s["colptr"][c + 1]]
    hit = np.nonzero(rows == r)[0]
    return int(s["colptr"][c] + hit[0]) if hit.size else -1


@kernel
def cholesky(a, colptr, rowidx, uptr, upos, pcol, out, work):
    """out = L with L L^T = A, both in the factor's pattern (a may alias out), the diagonal stored as
    1 / L[j, j]; work: length-n scratch. Returns the permuted index of the first non-positive pivot, or -1.

    Columns before the dense trailing block (the last columns, each full below its diagonal: a car's
    tangent ends in an 18 x 18 one) are factored left-looking through `work`. The block's columns receive
    their updates from the sparse columns the same way and are stored unscaled; the block is then factored
    right-looking in place (after column k is scaled, it updates every later column of the block). Every
    entry still receives its updates in ascending k, so the result is the same bit for bit; the block's
    rank-one updates are independent of each other, where the left-looking updates of one column chain
    through `work`."""
    n = colptr.shape[0] - 1
    jd = n                      # first column of the dense trailing block
    while jd > 0 and colptr[jd] - colptr[jd - 1] == n - jd + 1:
        jd -= 1
    for j in range(n):
        c0 = colptr[j]
        c1 = colptr[j + 1]
        for p in range(c0, c1):
            work[rowidx[p]] = a[p]
        nd = j - jd if j > jd else 0        # the last nd updates come from the block: done below
        for u in range(uptr[j], uptr[j + 1] - nd):
            p0 = upos[u]
            ljk = out[p0]
            p1 = colptr[pcol[p0] + 1]
            off = rowidx[p0] - p0
            if rowidx[p1 - 1] - p1 + 1 == off:      # consecutive rows (a dense block): direct indices
                for p in range(p0, p1):
                    work[p + off] -= out[p] * ljk
            else:
                for p in range(p0, p1):
                    work[rowidx[p]] -= out[p] * ljk
        if j < jd:
            s = work[j]
            if not (s > 0.0):
                return j
            inv = 1.0 / np.sqrt(s)
            out[c0] = inv           # the updates of later columns read only off-diagonal entries
            for p in range(c0 + 1, c1):
                out[p] = work[rowidx[p]] * inv
        else:
            for p in range(c0, c1):
                out[p] = work[rowidx[p]]
    for k in range(jd, n):      # the dense block, right-looking; L[r, k] is at colptr[k] + r - k
        c0 = colptr[k]
        c1 = colptr[k + 1]
        s = out[c0]
        if not (s > 0.0):
            return k
        inv = 1.0 / np.sqrt(s)
        out[c0] = inv
        for p in range(c0 + 1, c1):
            out[p] = out[p] * inv
        bk = c0 - k
        for j in range(k + 1, n):
            ljk = out[bk + j]
            bj = colptr[j] - j
            for r in range(j, n):
                out[bj + r] -= out[bk + r] * ljk
    return -1


@kernel
def solve(l, colptr, rowidx, perm, pinv, b, x, work):
    """Solve (L L^T) x = b in original indices (l from `cholesky`, its diagonal inverted); b may alias x.
    work: length-n scratch."""
    n = colptr.shape[0] - 1
    for i in range(n):
        work[pinv[i]] = b[i]
    for j in range(n):           # L y = b, by columns
        c0 = colptr[j]
        c1 = colptr[j + 1]
        y = work[j] * l[c0]
        work[j] = y
        if rowidx[c1 - 1] - c1 + 1 == j - c0:       # consecutive rows below the diagonal: direct indices
            for p in range(c0 + 1, c1):
                work[p + j - c0] -= l[p] * y
        else:
            for p in range(c0 + 1, c1):
                work[rowidx[p]] -= l[p] * y
    for j in range(n - 1, -1, -1):   # L^T x = y
        c0 = colptr[j]
        c1 = colptr[j + 1]
        s = work[j]
        if rowidx[c1 - 1] - c1 + 1 == j - c0:
            for p in range(c0 + 1, c1):
                s -= l[p] * work[p + j - c0]
        else:
            for p in range(c0 + 1, c1):
                s -= l[p] * work[rowidx[p]]
        work[j] = s * l[c0]
    for r in range(n):
        x[perm[r]] = work[r]
