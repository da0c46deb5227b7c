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
from rtsim.jit import kernel, uidx


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
    pinv, colptr, rowidx, uptr, upos, uend (where each update's rows end: the end of the column holding
    upos[u], negated when those rows are consecutive), pcol (each position's column), and the
    multiply-adds it costs."""
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
    uend = np.empty(upos.shape[0], dtype=np.int64)
    for u, p in enumerate(upos):
        end = colptr[pcol[p] + 1]
        uend[u] = -end if rowidx[end - 1] - rowidx[p] == end - 1 - p else end
    macs = int(sum(colptr[pcol[p] + 1] - p for p in upos))
    return dict(perm=perm, pinv=pinv, colptr=colptr, rowidx=rowidx, uptr=uptr, upos=upos, uend=uend, pcol=pcol,
                macs=macs)


def position(s: dict, i: int, j: int) -> int:
    """Storage position of entry (i, j) (original indices) in the factor's pattern, or -1."""
    r, c = int(s["pinv"][i]), int(s["pinv"][j])
    if c > r:
        r, c = c, r
    rows = s["rowidx"][s["colptr"][c]:s["colptr"][c + 1]]
    hit = np.nonzero(rows == r)[0]
    return int(s["colptr"][c] + hit[0]) if hit.size else -1


@kernel
def cholesky(a, colptr, rowidx, uptr, upos, uend, out, work):
    """out = L with L L^T = A, both in the factor's pattern (a may alias out), the diagonal stored as
    1 / L[j, j]; work: length-n scratch. Returns the permuted index of the first non-positive pivot, or -1.

    Columns before the dense trailing block (the last columns, each full below its diagonal: a car's
    tangent ends in an 18 x 18 one) are factored left-looking through `work`. The block's columns receive
    their updates from the sparse columns the same way and are stored unscaled; the block is then factored
    in place, column by column, each column taking the updates of the block's earlier columns two at a
    time (one load and store of its entries per two updates). Every entry receives its updates in
    ascending k, each rounded in its turn, so the factor is the same bit for bit as one made by rank-one
    updates.

    Positions and rows are indexed as unsigned integers (rtsim.jit.uidx), and each update reads where its
    rows end from `uend` (symbolic) instead of through the column of its position: with signed indices
    and that chain of loads the factor of the X-by-wire car's tangent took 3.4 us, now about 1.5 us."""
    n = colptr.shape[0] - 1
    jd = n                      # first column of the dense trailing block
    while jd > 0 and colptr[jd] - colptr[jd - 1] == n - jd + 1:
        jd -= 1
    one = uidx(1)
    for j in range(n):
        c0 = uidx(colptr[j])
        c1 = uidx(colptr[j + 1])
        for p in range(c0, c1):
            work[uidx(rowidx[p])] = a[p]
        nd = j - jd if j > jd else 0        # the last nd updates come from the block: done below
        for u in range(uidx(uptr[j]), uidx(uptr[j + 1] - nd)):
            p0 = uidx(upos[u])
            ljk = out[p0]
            end = uend[u]
            if end < 0:         # consecutive rows (a dense block): direct indices
                r0 = uidx(rowidx[p0])
                for i in range(uidx(-end) - p0):
                    work[r0 + i] -= out[p0 + i] * ljk
            else:
                for p in range(p0, uidx(end)):
                    work[uidx(rowidx[p])] -= out[p] * ljk
        if j < jd:
            s = work[j]
            if not (s > 0.0):
                return j
            inv = 1.0 / np.sqrt(s)
            out[c0] = inv           # the updates of later columns read only off-diagonal entries
            for p in range(c0 + one, c1):
                out[p] = work[uidx(rowidx[p])] * inv
        else:
            for p in range(c0, c1):
                out[p] = work[uidx(rowidx[p])]
    for j in range(jd, n):      # the dense block, left-looking; L[r, k] is at colptr[k] + r - k
        bj = uidx(colptr[j])
        m = uidx(n - j)
        k = jd
        while k + 1 < j:        # the updates of two earlier block columns a pass, each in its turn
            bk0 = uidx(colptr[k]) + uidx(j - k)             # L[j, k], then the rows below it
            bk1 = uidx(colptr[k + 1]) + uidx(j - k - 1)
            l0 = out[bk0]
            l1 = out[bk1]
            for i in range(m):
                out[bj + i] = (out[bj + i] - out[bk0 + i] * l0) - out[bk1 + i] * l1
            k += 2
        if k < j:
            bk0 = uidx(colptr[k]) + uidx(j - k)
            l0 = out[bk0]
            for i in range(m):
                out[bj + i] -= out[bk0 + i] * l0
        s = out[bj]
        if not (s > 0.0):
            return j
        inv = 1.0 / np.sqrt(s)
        out[bj] = inv
        for i in range(one, m):
            out[bj + i] = out[bj + i] * inv
    return -1


@kernel
def solve(l, colptr, rowidx, perm, pinv, b, x, work):
    """Solve (L L^T) x = b in original indices (l from `cholesky`, its diagonal inverted); b may alias x.
    work: length-n scratch. Unsigned indices as in `cholesky` (0.86 against 0.63 us on the same tangent)."""
    n = colptr.shape[0] - 1
    one = uidx(1)
    for i in range(n):
        work[uidx(pinv[i])] = b[i]
    for j in range(n):           # L y = b, by columns
        c0 = uidx(colptr[j])
        c1 = uidx(colptr[j + 1])
        y = work[j] * l[c0]
        work[j] = y
        if uidx(rowidx[c1 - one]) - uidx(j) == c1 - one - c0:   # consecutive rows below the diagonal: direct
            for i in range(one, c1 - c0):
                work[uidx(j) + i] -= l[c0 + i] * y
        else:
            for p in range(c0 + one, c1):
                work[uidx(rowidx[p])] -= l[p] * y
    for j in range(n - 1, -1, -1):   # L^T x = y
        c0 = uidx(colptr[j])
        c1 = uidx(colptr[j + 1])
        s = work[j]
        if uidx(rowidx[c1 - one]) - uidx(j) == c1 - one - c0:
            for i in range(one, c1 - c0):
                s -= l[c0 + i] * work[uidx(j) + i]
        else:
            for p in range(c0 + one, c1):
                s -= l[p] * work[uidx(rowidx[p])]
        work[j] = s * l[c0]
    for r in range(n):
        x[uidx(perm[r])] = work[r]
