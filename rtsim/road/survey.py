"""From topographic survey points to a road mesh (offline: numpy and scipy.spatial, no kernels).

The pipeline (after the road section of the x-by-wire validation paper, reworded):

1. `read_survey`: scattered survey points from a CSV file (columns x, y, z in metres, optional mu and
   rolling_resistance per point; lines starting with '#' are comments), checked: enough points, all
   finite, no two at the same place in x-y, not all on one line.
2. `NaturalNeighbour`: Sibson natural-neighbour interpolation of z at any point inside the convex hull
   of the survey, implemented here on scipy's Delaunay triangulation.
3. `AlphaShape`: the outline of the survey in the x-y plane, the union of the Delaunay triangles whose
   circumradius is below a radius (1 / alpha), by default a multiple of the typical point spacing, so
   that the notches and bays of the surveyed area stay out of the road.
4. `survey_to_mesh`: a regular grid of adjustable spacing h, its nodes inside the alpha shape, their
   heights interpolated (2), triangulated by Delaunay, keeping the triangles that are half squares of
   the grid (Delaunay also bridges concave stretches of the outline with long thin triangles) and lie
   wholly inside the outline (3): centroid inside, no edge crossing the contour. The mesh therefore
   falls short of the outline by less than one grid diagonal. Each triangle takes friction and
   rolling resistance from the survey point nearest its centroid (or the defaults when the survey
   has no such columns).

Sibson coordinates by circumcentres. Inserting the query point q into the Delaunay triangulation
removes the triangles whose circumcircle contains q (the conflict region, found by walking from the
triangle that contains q). q's new Voronoi cell takes from each natural neighbour v (each vertex of the
conflict region) the part of v's old cell that is closer to q. That part is the polygon G_first, c_1,
..., c_k, G_last: the circumcentres c_i of the conflict triangles around v, in counter-clockwise order
(the old Voronoi vertices that disappear), closed by the two new Voronoi vertices G = circumcentre of
(q, v, w) for the two conflict-region boundary edges (v, w) at v, which lie on the bisector of q and v.
Its area (shoelace, coordinates relative to q) is the stolen area; the Sibson weights are the stolen
areas divided by their sum. Only boundary edges produce a G, and q never lies on the line of a boundary
edge unless it is on the convex hull, where the interpolant is linear along the hull edge and computed
so. The weights sum to 1 and reproduce q (sum w_i x_i = q), so linear functions are reproduced
exactly, and a survey point is reproduced exactly (it is matched before any geometry).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from rtsim.configfile import note_read
from rtsim.errors import ConfigError
from rtsim.road.model import MU_RANGE, RR_RANGE

#: Fewest survey points accepted.
MIN_POINTS = 10
#: Survey points closer than this in x-y are duplicates (m).
DUPLICATE_DISTANCE = 1e-6
#: Default alpha-shape radius, in median nearest-neighbour distances of the survey points.
ALPHA_RADIUS_FACTOR = 2.0
#: Most grid nodes survey_to_mesh accepts.
MAX_GRID_NODES = 2_000_000

COLUMNS_REQUIRED = ("x", "y", "z")
COLUMNS_OPTIONAL = ("mu", "rolling_resistance")


@dataclass(frozen=True)
class Survey:
    """Survey points: xyz (n, 3); per-point mu and rolling resistance (n,) or None; the source name
    (the file) and each point's line in it (for error messages)."""
    xyz: np.ndarray
    mu: np.ndarray | None
    rolling_resistance: np.ndarray | None
    source: str
    lines: np.ndarray


def read_survey(path) -> Survey:
    """Read and check a survey CSV file. Raises ConfigError naming the file, line and value."""
    path = Path(path)
    note_read(path)
    src = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{src}: survey file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{src}: cannot read the survey file: {exc}") from None
    header, header_line, rows, lines = None, 0, [], []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        if header is None:
            header, header_line = [f.lower() for f in fields], lineno
            for name in header:
                if name not in COLUMNS_REQUIRED + COLUMNS_OPTIONAL:
                    raise ConfigError(
                        f"{src}: line {lineno}: unknown column {name!r} (allowed: "
                        f"{', '.join(COLUMNS_REQUIRED + COLUMNS_OPTIONAL)})")
            for name in COLUMNS_REQUIRED:
                if name not in header:
                    raise ConfigError(f"{src}: line {lineno}: header lacks column {name!r} "
                                      f"(need x, y, z in metres; got {', '.join(header)})")
            if len(set(header)) != len(header):
                raise ConfigError(f"{src}: line {lineno}: repeated column in header {', '.join(header)}")
            continue
        if len(fields) != len(header):
            raise ConfigError(f"{src}: line {lineno}: {len(fields)} values, the header "
                              f"(line {header_line}) names {len(header)}")
        row = []
        for name, f in zip(header, fields):
            try:
                v = float(f)
            except ValueError:
                raise ConfigError(f"{src}: line {lineno}: column {name!r} value {f!r} "
                                  "is not a number") from None
            if not math.isfinite(v):
                raise ConfigError(f"{src}: line {lineno}: column {name!r} value {f!r} "
                                  "is not a finite number")
            row.append(v)
        rows.append(row)
        lines.append(lineno)
    if header is None:
        raise ConfigError(f"{src}: no header line (expected a line 'x,y,z' before the points)")
    data = np.array(rows, dtype=np.float64).reshape(-1, len(header))
    lines = np.array(lines, dtype=np.int64)
    col = {name: data[:, i] for i, name in enumerate(header)}
    mu = col.get("mu")
    rr = col.get("rolling_resistance")
    if mu is not None:
        bad = np.flatnonzero(~((mu > MU_RANGE[0]) & (mu <= MU_RANGE[1])))
        if bad.size:
            i = bad[0]
            raise ConfigError(f"{src}: line {lines[i]}: column 'mu' value {mu[i]:g} is out of range "
                              f"({MU_RANGE[0]:g}, {MU_RANGE[1]:g}]")
    if rr is not None:
        bad = np.flatnonzero(~((rr >= RR_RANGE[0]) & (rr <= RR_RANGE[1])))
        if bad.size:
            i = bad[0]
            raise ConfigError(f"{src}: line {lines[i]}: column 'rolling_resistance' value {rr[i]:g} "
                              f"is out of range [{RR_RANGE[0]:g}, {RR_RANGE[1]:g}]")
    xyz = np.column_stack([col["x"], col["y"], col["z"]])
    check_points(xyz, src, lines)
    return Survey(xyz=xyz, mu=mu, rolling_resistance=rr, source=src, lines=lines)


def check_points(xyz: np.ndarray, source: str = "survey", lines: np.ndarray | None = None) -> None:
    """ConfigError unless xyz (n, 3) has at least MIN_POINTS finite points, no two within
    DUPLICATE_DISTANCE in x-y, and not all on one line in x-y."""
    xyz = np.asarray(xyz, dtype=np.float64)
    n = xyz.shape[0]
    where = (lambda i: f"line {lines[i]}") if lines is not None else (lambda i: f"point {i}")
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ConfigError(f"{source}: survey points must be an (n, 3) array of x, y, z, got {xyz.shape}")
    if n < MIN_POINTS:
        raise ConfigError(f"{source}: only {n} survey points; at least {MIN_POINTS} are needed")
    bad = np.flatnonzero(~np.all(np.isfinite(xyz), axis=1))
    if bad.size:
        i = bad[0]
        raise ConfigError(f"{source}: {where(i)}: point {xyz[i].tolist()} is not finite")
    pairs = cKDTree(xyz[:, :2]).query_pairs(DUPLICATE_DISTANCE, output_type="ndarray")
    if len(pairs):
        i, j = sorted(pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))][0])
        raise ConfigError(
            f"{source}: {where(i)} and {where(j)}: duplicate survey points at x = {xyz[i, 0]:g}, "
            f"y = {xyz[i, 1]:g} (points must be at least {DUPLICATE_DISTANCE:g} m apart in x-y)")
    c = xyz[:, :2] - xyz[:, :2].mean(axis=0)
    _, s, vt = np.linalg.svd(c, full_matrices=False)
    off_line = np.abs(c @ vt[1]).max()
    if off_line <= 1e-6 * max(s[0] / math.sqrt(n), 1.0):
        raise ConfigError(f"{source}: all {n} survey points lie on one line in x-y (largest distance "
                          f"from it {off_line:.3g} m); a road surface needs points spread in two directions")


def _delaunay(xy: np.ndarray, source: str) -> Delaunay:
    try:
        return Delaunay(xy)
    except (QhullError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"{source}: the points cannot be triangulated: {first}") from None


def _ccw(tri: Delaunay):
    """Simplices and neighbours of a 2D Delaunay triangulation, all counter-clockwise."""
    simp = tri.simplices.copy()
    nbr = tri.neighbors.copy()
    p = tri.points[simp]
    area2 = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    cw = area2 < 0.0
    simp[cw] = simp[cw][:, [0, 2, 1]]
    nbr[cw] = nbr[cw][:, [0, 2, 1]]   # neighbour k stays opposite vertex k
    return simp, nbr, 0.5 * np.abs(area2)


def circumcircles(p: np.ndarray):
    """Circumcentres (m, 2) and squared radii (m,) of triangles p (m, 3, 2)."""
    a = p[:, 1] - p[:, 0]
    b = p[:, 2] - p[:, 0]
    d = 2.0 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    a2 = (a * a).sum(axis=1)
    b2 = (b * b).sum(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (b[:, 1] * a2 - a[:, 1] * b2) / d
        uy = (a[:, 0] * b2 - b[:, 0] * a2) / d
    return p[:, 0] + np.column_stack([ux, uy]), ux * ux + uy * uy


def _circumcentre0(a, b):
    """Circumcentre of (0, a, b), or None if the three points are (nearly) collinear."""
    d = 2.0 * (a[0] * b[1] - a[1] * b[0])
    a2 = a[0] * a[0] + a[1] * a[1]
    b2 = b[0] * b[0] + b[1] * b[1]
    if abs(d) <= 1e-13 * math.sqrt(a2 * b2):
        return None
    return ((b[1] * a2 - a[1] * b2) / d, (a[0] * b2 - b[0] * a2) / d)


class NaturalNeighbour:
    """Sibson natural-neighbour interpolation of values given at scattered points xy (n, 2).
    Calling it on query points (m, 2) returns (m,) values, NaN outside the convex hull."""

    def __init__(self, xy, values, source: str = "points"):
        self.xy = np.ascontiguousarray(xy, dtype=np.float64)
        self.values = np.asarray(values, dtype=np.float64)
        self.tri = _delaunay(self.xy, source)
        self.simp, self.nbr, _ = _ccw(self.tri)
        self.cc, self.r2 = circumcircles(self.xy[self.simp])
        nn = cKDTree(self.xy).query(self.xy, k=2)[0][:, 1]
        self.snap = 1e-10 * float(np.median(nn))

    def __call__(self, q) -> np.ndarray:
        q = np.atleast_2d(np.asarray(q, dtype=np.float64))
        s = self.tri.find_simplex(q)
        out = np.full(q.shape[0], np.nan)
        for i in np.flatnonzero(s >= 0):
            idx, w = self.weights(q[i], int(s[i]))
            out[i] = w @ self.values[idx]
        return out

    def weights(self, q, s: int | None = None):
        """Sibson coordinates of q: (indices of the natural neighbours, weights summing to 1).
        s is the index of a Delaunay triangle containing q (found if None). Empty outside the hull."""
        q = np.asarray(q, dtype=np.float64)
        if s is None:
            s = int(self.tri.find_simplex(q[None, :])[0])
        if s < 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        xy, simp, nbr, cc, r2 = self.xy, self.simp, self.nbr, self.cc, self.r2
        qx, qy = float(q[0]), float(q[1])
        for v in simp[s]:
            if math.hypot(xy[v, 0] - qx, xy[v, 1] - qy) <= self.snap:
                return np.array([v]), np.ones(1)
        conflict = {s}
        stack = [s]
        while stack:
            t = stack.pop()
            for nb in nbr[t]:
                if nb >= 0 and nb not in conflict:
                    dx, dy = cc[nb, 0] - qx, cc[nb, 1] - qy
                    if dx * dx + dy * dy < r2[nb]:
                        conflict.add(int(nb))
                        stack.append(int(nb))
        acc, g_first, g_last = {}, {}, {}
        for t in conflict:
            ct = (cc[t, 0] - qx, cc[t, 1] - qy)
            vs = simp[t]
            for k in range(3):
                v = int(vs[k])
                pv = (xy[v, 0] - qx, xy[v, 1] - qy)
                a = acc.get(v, 0.0)
                cw_nb = nbr[t, (k + 2) % 3]
                if cw_nb not in conflict:   # edge (v, v_{k+1}) bounds the conflict region
                    w = vs[(k + 1) % 3]
                    g = _circumcentre0(pv, (xy[w, 0] - qx, xy[w, 1] - qy))
                    if g is None:
                        return self._on_hull(q, s)
                    g_first[v] = g
                    a += g[0] * ct[1] - g[1] * ct[0]
                ccw_nb = nbr[t, (k + 1) % 3]
                if ccw_nb in conflict:
                    cn = (cc[ccw_nb, 0] - qx, cc[ccw_nb, 1] - qy)
                    a += ct[0] * cn[1] - ct[1] * cn[0]
                else:                       # edge (v, v_{k+2}) bounds the conflict region
                    w = vs[(k + 2) % 3]
                    g = _circumcentre0(pv, (xy[w, 0] - qx, xy[w, 1] - qy))
                    if g is None:
                        return self._on_hull(q, s)
                    g_last[v] = g
                    a += ct[0] * g[1] - ct[1] * g[0]
                acc[v] = a
        idx = np.fromiter(acc.keys(), dtype=np.int64, count=len(acc))
        area = np.empty(idx.size)
        for i, v in enumerate(idx):
            gl, gf = g_last[v], g_first[v]
            area[i] = acc[v] + gl[0] * gf[1] - gl[1] * gf[0]
        return idx, area / area.sum()

    def _on_hull(self, q, s):
        """q on a convex-hull edge of triangle s: Sibson coordinates there are the linear ones."""
        p = self.xy[self.simp[s]]
        m = np.array([[p[1, 0] - p[0, 0], p[2, 0] - p[0, 0]], [p[1, 1] - p[0, 1], p[2, 1] - p[0, 1]]])
        l12 = np.linalg.solve(m, q - p[0])
        return self.simp[s].astype(np.int64), np.array([1.0 - l12.sum(), l12[0], l12[1]])


def natural_neighbour(xy, values, q, source: str = "points") -> np.ndarray:
    """Sibson natural-neighbour interpolation of values at xy (n, 2) onto q (m, 2); NaN outside
    the convex hull of xy."""
    return NaturalNeighbour(xy, values, source)(q)


class AlphaShape:
    """The alpha shape of points xy (n, 2): the union of the Delaunay triangles whose circumradius is
    below `radius` (= 1 / alpha; default ALPHA_RADIUS_FACTOR times the median nearest-neighbour
    distance).

    Attributes: radius; triangles (k, 3) counter-clockwise point indices of the kept triangles; area;
    loops, the contour as closed loops of point indices (outer boundaries counter-clockwise, holes
    clockwise; the last index is not repeated)."""

    def __init__(self, xy, radius: float | None = None, source: str = "points"):
        self.xy = np.ascontiguousarray(xy, dtype=np.float64)
        self.tri = _delaunay(self.xy, source)
        simp, nbr, area = _ccw(self.tri)
        if radius is None:
            nn = cKDTree(self.xy).query(self.xy, k=2)[0][:, 1]
            radius = ALPHA_RADIUS_FACTOR * float(np.median(nn))
        self.radius = float(radius)
        _, r2 = circumcircles(self.xy[simp])
        self.keep = r2 < self.radius * self.radius
        if not np.any(self.keep):
            raise ConfigError(f"{source}: alpha-shape radius {self.radius:g} m keeps no triangle "
                              "(it must exceed the point spacing)")
        self.triangles = simp[self.keep]
        self.area = float(area[self.keep].sum())
        # boundary edges v_k -> v_{k+1} (interior on the left) whose far side is not kept
        nxt = {}
        for t in np.flatnonzero(self.keep):
            for k in range(3):
                nb = nbr[t, (k + 2) % 3]
                if nb < 0 or not self.keep[nb]:
                    nxt.setdefault(int(simp[t, k]), []).append(int(simp[t, (k + 1) % 3]))
        self.loops = []
        while nxt:
            start = next(iter(nxt))
            loop, v = [start], start
            while True:
                ends = nxt[v]
                w = ends.pop()
                if not ends:
                    del nxt[v]
                if w == start:
                    break
                loop.append(w)
                v = w
            self.loops.append(np.array(loop, dtype=np.int64))

    def contains(self, q) -> np.ndarray:
        """Boolean (m,): which points q (m, 2) lie in the alpha shape (boundary included)."""
        s = self.tri.find_simplex(np.atleast_2d(np.asarray(q, dtype=np.float64)))
        return (s >= 0) & self.keep[np.maximum(s, 0)]

    def segments(self) -> np.ndarray:
        """The contour as segments (m, 2, 2): start and end point of each boundary edge."""
        idx = np.concatenate([np.column_stack([lp, np.roll(lp, -1)]) for lp in self.loops])
        return self.xy[idx]

    def crosses(self, a, b, chunk: int = 4096) -> np.ndarray:
        """Boolean (k,): which segments a[i] -> b[i] (k, 2) properly cross the contour (touching it
        at a point or running along it does not count)."""
        a = np.atleast_2d(np.asarray(a, dtype=np.float64))
        b = np.atleast_2d(np.asarray(b, dtype=np.float64))
        seg = self.segments()
        c, d = seg[None, :, 0], seg[None, :, 1]
        out = np.zeros(a.shape[0], dtype=bool)

        def orient(p, q, r):
            return ((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
                    - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))

        for i0 in range(0, a.shape[0], chunk):
            pa, pb = a[i0:i0 + chunk, None], b[i0:i0 + chunk, None]
            hit = ((orient(pa, pb, c) * orient(pa, pb, d) < 0.0)
                   & (orient(c, d, pa) * orient(c, d, pb) < 0.0))
            out[i0:i0 + chunk] = hit.any(axis=1)
        return out


@dataclass(frozen=True)
class SurveyMesh:
    """A road mesh built from a survey: vertices (nv, 3), counter-clockwise triangles (nt, 3),
    per-triangle mu and rolling resistance (nt,), the alpha shape and the grid spacing used."""
    vertices: np.ndarray
    triangles: np.ndarray
    tri_mu: np.ndarray
    tri_rr: np.ndarray
    alpha: AlphaShape
    grid_spacing: float


def survey_to_mesh(survey: Survey, grid_spacing: float, alpha_radius: float | None = None,
                   mu: float = 1.0, rolling_resistance: float = 0.0) -> SurveyMesh:
    """Survey points -> regular-grid triangle mesh inside the survey's alpha shape (module docstring).
    Grid nodes sit at integer multiples of grid_spacing. mu and rolling_resistance are the
    per-triangle values when the survey has no such column."""
    src = survey.source
    h = float(grid_spacing)
    if not h > 0.0:
        raise ConfigError(f"{src}: grid spacing must be > 0 m, got {grid_spacing!r}")
    xy, z = survey.xyz[:, :2], survey.xyz[:, 2]
    alpha = AlphaShape(xy, alpha_radius, src)
    lo = np.floor(xy.min(axis=0) / h).astype(np.int64)
    hi = np.ceil(xy.max(axis=0) / h).astype(np.int64)
    nodes = int(np.prod(hi - lo + 1))
    if nodes > MAX_GRID_NODES:
        raise ConfigError(f"{src}: grid spacing {h:g} m needs {nodes} grid nodes over the survey "
                          f"(at most {MAX_GRID_NODES}); use a larger spacing")
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0] + 1) * h, np.arange(lo[1], hi[1] + 1) * h)
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    grid = grid[alpha.contains(grid)]
    if grid.shape[0] < 3:
        raise ConfigError(f"{src}: only {grid.shape[0]} grid nodes of spacing {h:g} m fall inside the "
                          "survey's outline; use a smaller grid spacing")
    gz = NaturalNeighbour(xy, z, src)(grid)
    mesh_tri = _delaunay(grid, src)
    simp, _, area = _ccw(mesh_tri)
    p = grid[simp]
    longest = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2).max(axis=1)
    # the grid's own half-squares (Delaunay also bridges concave stretches of the outline with long
    # thin triangles), wholly inside the outline: centroid inside and no edge crossing the contour
    keep = (area > 1e-9 * h * h) & (longest <= math.sqrt(2.0) * h * (1.0 + 1e-6))
    keep &= alpha.contains(p.mean(axis=1))
    for k in range(3):
        keep[keep] &= ~alpha.crosses(p[keep, k], p[keep, (k + 1) % 3])
    simp = simp[keep]
    if simp.shape[0] == 0:
        raise ConfigError(f"{src}: no grid triangle of spacing {h:g} m lies inside the survey's "
                          "outline; use a smaller grid spacing")
    used = np.unique(simp)
    remap = np.full(grid.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    vertices = np.column_stack([grid[used], gz[used]])
    triangles = remap[simp].astype(np.int32)
    nt = triangles.shape[0]
    if survey.mu is not None or survey.rolling_resistance is not None:
        centroid = vertices[triangles, :2].mean(axis=1)
        nearest = cKDTree(xy).query(centroid)[1]
    tri_mu = survey.mu[nearest] if survey.mu is not None else np.full(nt, float(mu))
    tri_rr = (survey.rolling_resistance[nearest] if survey.rolling_resistance is not None
              else np.full(nt, float(rolling_resistance)))
    return SurveyMesh(vertices=vertices, triangles=triangles, tri_mu=tri_mu, tri_rr=tri_rr,
                      alpha=alpha, grid_spacing=h)
