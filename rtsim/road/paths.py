"""Reference paths on the road, shared by the lateral drivers and the two-wheeler's rider: polyline
geometry, nearest-segment tracking, curvature, and generators of the manoeuvres' paths (circle,
figure-eight, double lane change).

Geometry. `polyline(x, y, closed)` checks the points (m, road frame) and returns the arrays the kernels
use: vertices `px, py` (a closed path repeats its first point at the end), arc length `ps` at each
vertex, vertex headings `hd` (bisector of the adjacent segments, so the heading interpolated along a
segment is continuous) and segment lengths `seg_len`. An open path is extended straight beyond its
ends; a closed one wraps around.

Kernels (inlined, no allocation): `seg_project` projects a point on one segment, `nearest_segment`
walks from the previously nearest segment to its neighbours while the distance decreases (O(1) per
call amortised; it cannot jump to another branch of a self-crossing path), `point_ahead` walks a
distance along the path, `value_at` interpolates a per-vertex quantity (e.g. the curvature) at an arc
length.

Curvature. `vertex_curvature` gives the signed curvature at each vertex (1/m, positive turning left,
ISO 8855) as that of the circle through the vertex and its two neighbours (exact for points sampled on
a circle), optionally averaged over an arc-length window.
"""
from __future__ import annotations

import math

import numpy as np

from rtsim.jit import inline_kernel

# --------------------------------------------------------------------------------------------------
# Geometry


def polyline(x, y, closed: bool = False):
    """(px, py, ps, hd, seg_len, closed) for the polyline through (x[i], y[i]) (m). A path whose first
    point equals its last is closed. ValueError for too few, non-finite or coincident points."""
    px = np.array(x, dtype=np.float64).reshape(-1)
    py = np.array(y, dtype=np.float64).reshape(-1)
    if px.shape != py.shape:
        raise ValueError(f"path has {px.size} x and {py.size} y values")
    if not (np.all(np.isfinite(px)) and np.all(np.isfinite(py))):
        raise ValueError("path has non-finite coordinates")
    if px.size >= 2 and px[0] == px[-1] and py[0] == py[-1]:
        closed = True
        px, py = px[:-1], py[:-1]
    if px.size < 2 or (closed and px.size < 3):
        raise ValueError(f"path needs at least {3 if closed else 2} distinct points")
    if closed:
        px = np.append(px, px[0])
        py = np.append(py, py[0])
    seg = np.hypot(np.diff(px), np.diff(py))
    if np.any(seg <= 0.0):
        i = int(np.argmin(seg > 0.0))
        raise ValueError(f"path points {i} and {i + 1} coincide ({px[i]}, {py[i]})")
    nseg = seg.size
    ps = np.concatenate(([0.0], np.cumsum(seg)))
    tx, ty = np.diff(px) / seg, np.diff(py) / seg
    # vertex headings: bisector of the adjacent segments (ends: the end segment's heading)
    vx = np.empty(nseg + 1)
    vy = np.empty(nseg + 1)
    vx[1:-1] = tx[:-1] + tx[1:]
    vy[1:-1] = ty[:-1] + ty[1:]
    if closed:
        vx[0] = vx[-1] = tx[-1] + tx[0]
        vy[0] = vy[-1] = ty[-1] + ty[0]
    else:
        vx[0], vy[0] = tx[0], ty[0]
        vx[-1], vy[-1] = tx[-1], ty[-1]
    hd = np.arctan2(vy, vx)
    # a U-turn vertex (bisector zero) takes the incoming segment's heading
    flat = np.hypot(vx, vy) < 1e-9
    if np.any(flat):
        seg_h = np.arctan2(ty, tx)
        idx = np.nonzero(flat)[0]
        hd[idx] = seg_h[np.maximum(idx - 1, 0)]
    return px, py, ps, hd, seg, bool(closed)


def vertex_curvature(px, py, closed: bool, smooth: float = 0.0) -> np.ndarray:
    """Signed curvature (1/m, left positive) at each vertex of a polyline as returned by `polyline`
    (closed: last vertex = first). Each is the curvature of the circle through the vertex and its
    neighbours; an open path's end vertices take their neighbour's value. smooth > 0 (m): averaged
    over a window of that length centred on the vertex (weights: half the adjacent segments)."""
    px = np.asarray(px, dtype=np.float64)
    py = np.asarray(py, dtype=np.float64)
    n = px.size
    if closed:
        x, y = px[:-1], py[:-1]
        xm, ym, xp, yp = np.roll(x, 1), np.roll(y, 1), np.roll(x, -1), np.roll(y, -1)
    else:
        x, y = px[1:-1], py[1:-1]
        xm, ym, xp, yp = px[:-2], py[:-2], px[2:], py[2:]
    ax, ay = x - xm, y - ym
    bx, by = xp - x, yp - y
    cross = ax * by - ay * bx
    la, lb, lc = np.hypot(ax, ay), np.hypot(bx, by), np.hypot(xp - xm, yp - ym)
    k = 2.0 * cross / np.maximum(la * lb * lc, 1e-300)
    if closed:
        kap = np.append(k, k[0])
    else:
        kap = np.empty(n)
        kap[1:-1] = k
        kap[0] = k[0] if k.size else 0.0
        kap[-1] = k[-1] if k.size else 0.0
    if smooth > 0.0:
        kap = _window_mean(px, py, kap, closed, 0.5 * smooth)
    return kap


def _window_mean(px, py, val, closed, half):
    seg = np.hypot(np.diff(px), np.diff(py))
    s = np.concatenate(([0.0], np.cumsum(seg)))
    length = s[-1]
    w = np.zeros(s.size)
    w[:-1] += 0.5 * seg
    w[1:] += 0.5 * seg
    if closed:                         # one vertex per point: the closing vertex merges with the first
        w[0] += w[-1]
        s1, v1, w1 = s[:-1], val[:-1], w[:-1]
        s3 = np.concatenate((s1 - length, s1, s1 + length))
        v3, w3 = np.tile(v1, 3), np.tile(w1, 3)
    else:
        s3, v3, w3 = s, val, w
    cw = np.concatenate(([0.0], np.cumsum(w3)))
    cv = np.concatenate(([0.0], np.cumsum(w3 * v3)))
    lo = np.searchsorted(s3, s - half, side="left")
    hi = np.searchsorted(s3, s + half, side="right")
    return (cv[hi] - cv[lo]) / np.maximum(cw[hi] - cw[lo], 1e-300)


# --------------------------------------------------------------------------------------------------
# Kernels


@inline_kernel
def wrap_angle(a):
    """a wrapped into [-pi, pi] (rad)."""
    return math.atan2(math.sin(a), math.cos(a))


@inline_kernel
def seg_project(px, py, i, x, y, nseg, closed):
    """Parameter u along segment i of the point nearest to (x, y), and the squared distance (m^2).
    u is clipped to [0, 1], except beyond the ends of an open path."""
    ax = px[i]
    ay = py[i]
    dx = px[i + 1] - ax
    dy = py[i + 1] - ay
    u = ((x - ax) * dx + (y - ay) * dy) / (dx * dx + dy * dy)
    if closed:
        u = min(max(u, 0.0), 1.0)
    else:
        if u < 0.0 and i > 0:
            u = 0.0
        if u > 1.0 and i < nseg - 1:
            u = 1.0
    qx = ax + u * dx
    qy = ay + u * dy
    return u, (x - qx) * (x - qx) + (y - qy) * (y - qy)


@inline_kernel
def nearest_segment(px, py, nseg, closed, first, i, x, y):
    """Segment nearest to (x, y): a search of the whole path if `first`, else a walk from segment i
    to its neighbours while the distance decreases."""
    if first:
        best = 0
        u, dbest = seg_project(px, py, 0, x, y, nseg, closed)
        for j in range(1, nseg):
            u, d = seg_project(px, py, j, x, y, nseg, closed)
            if d < dbest:
                dbest = d
                best = j
        return best
    u, d = seg_project(px, py, i, x, y, nseg, closed)
    moved = False
    for _ in range(nseg):
        j = i + 1
        if j >= nseg:
            if not closed:
                break
            j = 0
        u, dj = seg_project(px, py, j, x, y, nseg, closed)
        if dj < d:
            i = j
            d = dj
            moved = True
        else:
            break
    if not moved:
        for _ in range(nseg):
            j = i - 1
            if j < 0:
                if not closed:
                    break
                j = nseg - 1
            u, dj = seg_project(px, py, j, x, y, nseg, closed)
            if dj < d:
                i = j
                d = dj
            else:
                break
    return i


@inline_kernel
def point_ahead(px, py, seg_len, nseg, closed, i, u, dist):
    """Point (m) at arc length `dist` ahead of parameter u on segment i (wraps on a closed path,
    extends the last segment of an open one)."""
    rem = u * seg_len[i] + dist
    for _ in range(4 * nseg + 4):
        if rem <= seg_len[i]:
            break
        if i == nseg - 1 and not closed:
            break
        rem -= seg_len[i]
        i = i + 1
        if i >= nseg:
            i = 0
    f = rem / seg_len[i]
    return (px[i] + f * (px[i + 1] - px[i]), py[i] + f * (py[i + 1] - py[i]))


@inline_kernel
def bracket(xs, n, x):
    """(lo, hi = lo + 1) with xs[lo] <= x < xs[hi] for increasing xs[:n] and xs[0] <= x <= xs[n-1]
    (binary search)."""
    lo = 0
    hi = n - 1
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if xs[mid] <= x:
            lo = mid
        else:
            hi = mid
    return lo, hi


@inline_kernel
def on_segment(px, py, hd, seg_len, i, f, x, y):
    """Signed offset of (x, y) from segment i (left positive, m) and the path heading at the fraction f
    along it (vertex headings interpolated, rad)."""
    ax = px[i]
    ay = py[i]
    tx = (px[i + 1] - ax) / seg_len[i]
    ty = (py[i + 1] - ay) / seg_len[i]
    fc = min(max(f, 0.0), 1.0)
    return tx * (y - ay) - ty * (x - ax), hd[i] + fc * wrap_angle(hd[i + 1] - hd[i])


@inline_kernel
def value_at(ps, val, closed, s, beyond):
    """val (one per vertex) interpolated linearly at arc length s (m); a closed path wraps s, an open
    one returns `beyond` outside [0, length]. Binary search: O(log n)."""
    n = ps.size
    length = ps[n - 1]
    if closed:
        s = s - length * math.floor(s / length)
    elif s < 0.0 or s > length:
        return beyond
    lo, hi = bracket(ps, n, s)
    ds = ps[hi] - ps[lo]
    f = (s - ps[lo]) / ds if ds > 0.0 else 0.0
    f = min(max(f, 0.0), 1.0)
    return val[lo] + f * (val[hi] - val[lo])


# --------------------------------------------------------------------------------------------------
# Path generators (all start at the origin heading +x unless stated)


def circle_points(radius: float, spacing: float = 0.5, center=(0.0, 0.0), start_angle: float = -0.5 * math.pi,
                  ccw: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Points of a closed circle (first point not repeated), `spacing` m apart at most. The default
    start angle puts the first point below the centre, heading +x when counter-clockwise."""
    n = max(int(math.ceil(2.0 * math.pi * radius / spacing)), 8)
    a = start_angle + (1.0 if ccw else -1.0) * 2.0 * math.pi * np.arange(n) / n
    return center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)


def figure_eight(radius: float, straight: float = 0.0, spacing: float = 0.5,
                 left_first: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A closed figure-eight (first point not repeated): two loops of radius `radius` (m), one turning
    left and one right, joined by two straights of length `straight` (m) that cross at the origin
    (straight = 0: the circles touch there). The heading is continuous; the curvature is +-1/radius on
    the loops and 0 on the straights. Starts at the origin heading +x, into the left loop if
    left_first (else the right one). Points at most `spacing` m apart."""
    if not (radius > 0.0 and straight >= 0.0 and spacing > 0.0):
        raise ValueError("figure_eight: radius and spacing must be > 0, straight >= 0")
    h = 0.5 * straight
    beta = math.atan2(radius, h)              # angle of the straights to the line of centres
    sweep = math.pi + 2.0 * beta              # rad, each loop
    xs, ys = [], []

    def line(x0, y0, hd, length):
        n = int(math.ceil(length / spacing)) if length > 0.0 else 0
        f = np.arange(n) / max(n, 1) * length
        xs.append(x0 + f * math.cos(hd))
        ys.append(y0 + f * math.sin(hd))
        return x0 + length * math.cos(hd), y0 + length * math.sin(hd)

    def arc(x0, y0, hd, turn):                # turn = +1 left, -1 right
        cx, cy = x0 - turn * radius * math.sin(hd), y0 + turn * radius * math.cos(hd)
        a0 = math.atan2(y0 - cy, x0 - cx)
        n = int(math.ceil(sweep * radius / spacing))
        a = a0 + turn * sweep * np.arange(n) / n
        xs.append(cx + radius * np.cos(a))
        ys.append(cy + radius * np.sin(a))
        a1 = a0 + turn * sweep
        return cx + radius * math.cos(a1), cy + radius * math.sin(a1), hd + turn * sweep

    # in a frame where the first straight leaves the origin at +beta from the line of centres, then
    # rotated so that it heads +x
    turn = 1.0 if left_first else -1.0
    x, y = line(0.0, 0.0, 0.0, h)
    x, y, hd = arc(x, y, 0.0, turn)
    x, y = line(x, y, hd, 2.0 * h)
    x, y, hd = arc(x, y, hd, -turn)
    line(x, y, hd, h)
    x, y = np.concatenate(xs), np.concatenate(ys)
    x[0] = y[0] = 0.0                          # the origin, without rounding
    return x, y


def double_lane_change(offset: float = 3.5, entry: float = 50.0, transition: float = 50.0,
                       hold: float = 30.0, exit: float = 50.0, spacing: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """An open double lane change along +x from the origin: `entry` m straight, a move of `offset` m to
    the left over `transition` m, `hold` m in the other lane, the move back over `transition` m, `exit`
    m straight. Each move is y = offset (xi - sin(2 pi xi) / (2 pi)), xi in [0, 1] over the
    transition: its curvature is a full sine period, zero at both ends, so the path is curvature
    continuous; the peak curvature is about 2 pi offset / transition^2 (1/m)."""
    if not (transition > 0.0 and spacing > 0.0 and min(entry, hold, exit) >= 0.0):
        raise ValueError("double_lane_change: transition and spacing must be > 0, the straights >= 0")
    total = entry + 2.0 * transition + hold + exit
    n = int(math.ceil(total / spacing))
    x = np.linspace(0.0, total, n + 1)

    def move(xi):
        xi = np.clip(xi, 0.0, 1.0)
        return offset * (xi - np.sin(2.0 * math.pi * xi) / (2.0 * math.pi))

    y = move((x - entry) / transition) - move((x - entry - transition - hold) / transition)
    return x, y
