"""A road as plain arrays (MuJoCo-style model/data separation), whatever its kind.

Every road is one `Road` named tuple with the same field types, so one compiled query
(`rtsim.road.query.road_query`) serves all of them and the vehicle kernel calls a single function.

Kinds (`ipar[IP_KIND]`):

- `ROAD_PLANE` (0): an unbounded analytic plane z = c + gx (x - x0) + gy (y - y0), with one friction
  scale and one rolling-resistance coefficient. A flat road has gx = gy = 0; a constant grade g (rise
  over run, positive uphill along the heading psi measured from +x towards +y) has
  gx = g cos(psi), gy = g sin(psi). The mesh arrays are empty. The query reports face 0.
- `ROAD_MESH` (1): a triangle mesh that is a height field over the x-y plane (one surface height per
  (x, y), which is what a survey gives, so no z hint is needed), with per-triangle friction and rolling
  resistance and a uniform 2D grid hash for O(1) lookup. Points outside every triangle are off the
  survey: without a declared ground (IP_GROUND = 0) they are off the road (height -inf); with one, the
  ground continues beyond the survey's outline (below).

Off the survey (IP_GROUND = 1): the world does not end where the survey does. At a point outside every
triangle, at horizontal distance r from the nearest point of the mesh's boundary edges, each boundary
edge j offers its nearest point B_j (distance r_j) with the mesh's height z_j, normal n_j (smooth or
facet) and triangle's mu_j, rr_j there. The edges within a relative band of the nearest one are
averaged with weights w_j = (1 - (r_j - r) / (OFF_SURVEY_BAND r))^2 (0 beyond the band, 1 for the
nearest), so the ground is continuous even where the nearest edge changes (a concave outline): height
z_B = sum w_j z_j / sum w_j (at the outline, r -> 0, the mesh's own height), unit normal
normalize((1 - w) n_B + w e_z) and friction scale and rolling resistance (1 - w) v_B + w v_off, with
n_B, v_B the same weighted means, v_off the declared off-survey values (FP_OFF_MU, FP_OFF_RR) and
w = smoothstep(r / OFF_SURVEY_BLEND). The query still reports face -1 there (off the survey), with
these finite values. The nearest boundary
point is found by a scan of the boundary edges (cost linear in the outline's length, paid only off
the survey).

Array layout (axes ISO 8855: x forward, y left, z up; SI units):

- `ipar` int64 (NIPAR,): IP_KIND, IP_NCX / IP_NCY (grid-hash cells along x / y), IP_NT (triangles),
  IP_NV (vertices).
- `fpar` float64 (NFPAR,): FP_X0, FP_Y0, FP_Z0, FP_GX, FP_GY (plane: reference point and height
  gradient), FP_NX, FP_NY, FP_NZ (plane: unit normal), FP_MU, FP_RR (plane: friction scale and
  rolling resistance), FP_GRID_X0, FP_GRID_Y0 (mesh: lower-left corner of the grid hash), FP_INV_H
  (mesh: 1 / cell size), FP_GRID_X1, FP_GRID_Y1 (mesh: upper-right corner), FP_OFF_MU, FP_OFF_RR
  (mesh: the ground beyond the survey).
- `vert` float64 (nv, 3): vertex x, y, z.
- `tri` int32 (nt, 3): vertex indices, counter-clockwise seen from above (+z).
- `tri_geom` float64 (nt, NGEOM): per triangle, relative to its vertex 0 (x0, y0, z0):
  TG_X0, TG_Y0, TG_Z0; TG_B11, TG_B12, TG_B21, TG_B22, the barycentric map
  l1 = B11 dx + B12 dy, l2 = B21 dx + B22 dy, l0 = 1 - l1 - l2 with dx = x - x0, dy = y - y0;
  TG_GX, TG_GY, the height gradient (z = z0 + GX dx + GY dy); TG_NX, TG_NY, TG_NZ, the unit normal
  (pointing up, nz > 0). Relative coordinates keep the inside test accurate far from the origin.
- `tri_mu`, `tri_rr` float64 (nt,): friction scale and rolling-resistance coefficient per triangle.
- `cell_start` int32 (ncx * ncy + 1,), `cell_tri` int32 (nnz,): the grid hash in CSR form. Cell
  (ix, iy) = iy * ncx + ix covers [X0 + ix h, X0 + (ix + 1) h) x [Y0 + iy h, Y0 + (iy + 1) h) and lists
  the triangles that overlap it, those whose centroid is nearest the cell centre first.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from rtsim.errors import ConfigError

ROAD_PLANE = 0
ROAD_MESH = 1
ROAD_KIND_NAMES = ("plane", "mesh")

# ipar
IP_KIND = 0
IP_NCX = 1
IP_NCY = 2
IP_NT = 3
IP_NV = 4
IP_SMOOTH = 5   # mesh: 1 = normals interpolated from vertex normals (smooth across edges)
IP_GROUND = 6   # mesh: 1 = the ground continues beyond the survey (see "Off the survey" above)
NIPAR = 7

# fpar
FP_X0 = 0
FP_Y0 = 1
FP_Z0 = 2
FP_GX = 3
FP_GY = 4
FP_NX = 5
FP_NY = 6
FP_NZ = 7
FP_MU = 8
FP_RR = 9
FP_GRID_X0 = 10
FP_GRID_Y0 = 11
FP_INV_H = 12
FP_GRID_X1 = 13
FP_GRID_Y1 = 14
FP_OFF_MU = 15      # mesh: friction scale of the ground beyond the survey
FP_OFF_RR = 16      # mesh: rolling resistance of the ground beyond the survey
NFPAR = 17

# tri_geom columns
TG_X0 = 0
TG_Y0 = 1
TG_Z0 = 2
TG_B11 = 3
TG_B12 = 4
TG_B21 = 5
TG_B22 = 6
TG_GX = 7
TG_GY = 8
TG_NX = 9
TG_NY = 10
TG_NZ = 11
NGEOM = 12

#: Barycentric tolerance of the inside test: a point on a shared edge belongs to both triangles.
INSIDE_TOL = 1e-10

#: Largest grid hash (cells); the cell size grows if a mesh would need more.
MAX_CELLS = 4_000_000

Road = namedtuple("Road", [
    "ipar", "fpar", "vert", "tri", "tri_geom", "tri_mu", "tri_rr", "cell_start", "cell_tri",
    "vert_n",   # (nv, 3) area-weighted unit vertex normals (used with IP_SMOOTH)
    "bnd_vert",  # (nb, 2) int32: the two vertices of each boundary edge (an edge of one triangle only)
    "bnd_tri",   # (nb,) int32: the triangle each boundary edge belongs to
])

#: Distance beyond the survey's outline (m) over which the ground's normal, friction and rolling
#: resistance blend from the mesh's values at the nearest boundary point to a level surface with the
#: off-survey values (a C1 smoothstep of the distance), so a tyre rolling off the edge sees none jump.
OFF_SURVEY_BLEND = 1.0

#: Relative width of the band of boundary edges averaged for the ground beyond the survey: edges
#: whose nearest point is at most (1 + OFF_SURVEY_BAND) times the nearest distance away.
OFF_SURVEY_BAND = 0.5

#: Friction scale and rolling resistance accepted anywhere (configs and survey columns).
MU_RANGE = (0.0, 2.0)        # exclusive lower bound, inclusive upper bound
RR_RANGE = (0.0, 0.1)        # inclusive


def _empty_mesh_fields():
    return dict(
        vert=np.zeros((0, 3)), tri=np.zeros((0, 3), dtype=np.int32),
        tri_geom=np.zeros((0, NGEOM)), tri_mu=np.zeros(0), tri_rr=np.zeros(0),
        cell_start=np.zeros(1, dtype=np.int32), cell_tri=np.zeros(0, dtype=np.int32),
        vert_n=np.zeros((0, 3)), bnd_vert=np.zeros((0, 2), dtype=np.int32),
        bnd_tri=np.zeros(0, dtype=np.int32),
    )


def make_plane(height: float = 0.0, mu: float = 1.0, rolling_resistance: float = 0.0) -> Road:
    """A flat horizontal road at z = height."""
    return make_grade(0.0, 0.0, (0.0, 0.0, height), mu, rolling_resistance)


def make_grade(grade: float, heading: float = 0.0, origin=(0.0, 0.0, 0.0), mu: float = 1.0,
               rolling_resistance: float = 0.0) -> Road:
    """A plane of constant grade: rise over run `grade` along `heading` (rad from +x towards +y),
    positive uphill when travelling along the heading; passes through `origin` (x, y, z)."""
    x0, y0, z0 = (float(v) for v in origin)
    gx, gy = grade * np.cos(heading), grade * np.sin(heading)
    k = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    fpar = np.zeros(NFPAR)
    fpar[[FP_X0, FP_Y0, FP_Z0, FP_GX, FP_GY]] = x0, y0, z0, gx, gy
    fpar[[FP_NX, FP_NY, FP_NZ]] = -gx * k, -gy * k, k
    fpar[FP_MU], fpar[FP_RR] = mu, rolling_resistance
    ipar = np.zeros(NIPAR, dtype=np.int64)
    ipar[IP_KIND] = ROAD_PLANE
    return Road(ipar=ipar, fpar=fpar, **_empty_mesh_fields())


def triangle_geometry(vert: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """The `tri_geom` table (see the module docstring) of counter-clockwise triangles."""
    p0, p1, p2 = vert[tri[:, 0]], vert[tri[:, 1]], vert[tri[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    det = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
    geom = np.zeros((tri.shape[0], NGEOM))
    geom[:, TG_X0:TG_Z0 + 1] = p0
    # [l1, l2] = inv([[e1x, e2x], [e1y, e2y]]) [dx, dy]
    geom[:, TG_B11] = e2[:, 1] / det
    geom[:, TG_B12] = -e2[:, 0] / det
    geom[:, TG_B21] = -e1[:, 1] / det
    geom[:, TG_B22] = e1[:, 0] / det
    # z - z0 = l1 dz1 + l2 dz2 -> gradient
    gx = geom[:, TG_B11] * e1[:, 2] + geom[:, TG_B21] * e2[:, 2]
    gy = geom[:, TG_B12] * e1[:, 2] + geom[:, TG_B22] * e2[:, 2]
    k = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    geom[:, TG_GX], geom[:, TG_GY] = gx, gy
    geom[:, TG_NX], geom[:, TG_NY], geom[:, TG_NZ] = -gx * k, -gy * k, k
    return geom


def _overlaps(p: np.ndarray, xlo: float, ylo: float, xhi: float, yhi: float) -> bool:
    """Separating-axis test: does the CCW triangle p (3, 2) overlap the closed box?"""
    corners = ((xlo, ylo), (xhi, ylo), (xhi, yhi), (xlo, yhi))
    for k in range(3):
        ax, ay = p[k]
        bx, by = p[(k + 1) % 3]
        # the box is entirely on the outer (right) side of edge a->b
        if all((bx - ax) * (cy - ay) - (by - ay) * (cx - ax) < 0.0 for cx, cy in corners):
            return False
    return True


def build_grid_hash(vert: np.ndarray, tri: np.ndarray, cell_size: float):
    """Uniform grid over the mesh's x-y bounding box; each cell lists the triangles overlapping it
    (cells padded by a relative 1e-9 so that a point on a cell border still finds its triangle).
    Returns (x0, y0, h, ncx, ncy, cell_start, cell_tri)."""
    xy = vert[:, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    span = np.maximum(hi - lo, 1e-9)
    h = float(cell_size)
    if np.prod(np.ceil(span / h) + 1) > MAX_CELLS:
        h = float(np.sqrt(np.prod(span + h) / MAX_CELLS)) * 1.01
    pad = 1e-9 * max(h, float(span.max()))
    x0, y0 = lo[0] - pad, lo[1] - pad
    ncx = int(np.floor((hi[0] + pad - x0) / h)) + 1
    ncy = int(np.floor((hi[1] + pad - y0) / h)) + 1
    tol = 1e-9 * h
    pts = xy[tri]                                   # (nt, 3, 2)
    cen = pts.mean(axis=1)
    tlo = np.floor((pts.min(axis=1) - (x0, y0) - tol) / h).astype(np.int64)
    thi = np.floor((pts.max(axis=1) - (x0, y0) + tol) / h).astype(np.int64)
    tlo = np.maximum(tlo, 0)
    thi = np.minimum(thi, (ncx - 1, ncy - 1))
    cells, tris, dist = [], [], []
    for t in range(tri.shape[0]):
        p = pts[t]
        for iy in range(tlo[t, 1], thi[t, 1] + 1):
            for ix in range(tlo[t, 0], thi[t, 0] + 1):
                bx, by = x0 + ix * h, y0 + iy * h
                if (tlo[t, 0] == thi[t, 0] and tlo[t, 1] == thi[t, 1]) or \
                        _overlaps(p, bx - tol, by - tol, bx + h + tol, by + h + tol):
                    cells.append(iy * ncx + ix)
                    tris.append(t)
                    dist.append(np.hypot(cen[t, 0] - bx - 0.5 * h, cen[t, 1] - by - 0.5 * h))
    cells, tris, dist = np.asarray(cells, np.int64), np.asarray(tris, np.int64), np.asarray(dist)
    order = np.lexsort((tris, dist, cells))
    cell_tri = tris[order].astype(np.int32)
    counts = np.bincount(cells, minlength=ncx * ncy)
    cell_start = np.zeros(ncx * ncy + 1, dtype=np.int32)
    np.cumsum(counts, out=cell_start[1:])
    return x0, y0, h, ncx, ncy, cell_start, cell_tri


def boundary_edges(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The edges of a triangle list that belong to one triangle only: (vertex pairs (nb, 2) int32,
    their triangle (nb,) int32)."""
    e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    owner = np.tile(np.arange(tri.shape[0]), 3)
    key = np.sort(e, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    once = cnt[inv.ravel()] == 1
    return e[once].astype(np.int32), owner[once].astype(np.int32)


def make_mesh(vertices, triangles, tri_mu, tri_rr, cell_size: float | None = None,
              source: str = "mesh", smooth_normals: bool = False,
              off_survey_mu: float | None = None, off_survey_rr: float = 0.0) -> Road:
    """A triangle-mesh road from vertices (nv, 3), triangles (nt, 3) and per-triangle friction scale
    and rolling resistance (scalars broadcast). Triangles are re-oriented counter-clockwise; the
    grid-hash cell size defaults to the mean edge length. With `off_survey_mu` given, the ground
    continues beyond the mesh with that friction scale and `off_survey_rr` (see "Off the survey" in
    the module docstring); without it, points off the mesh are off the road. Bad input raises
    ConfigError naming `source`."""
    vert = np.ascontiguousarray(vertices, dtype=np.float64)
    tri = np.array(triangles, dtype=np.int64)
    if vert.ndim != 2 or vert.shape[1] != 3 or vert.shape[0] < 3:
        raise ConfigError(f"{source}: vertices must be an (nv >= 3, 3) array, got shape {vert.shape}")
    if tri.ndim != 2 or tri.shape[1] != 3 or tri.shape[0] < 1:
        raise ConfigError(f"{source}: triangles must be an (nt >= 1, 3) array, got shape {tri.shape}")
    if not np.all(np.isfinite(vert)):
        i = int(np.argwhere(~np.isfinite(vert))[0, 0])
        raise ConfigError(f"{source}: vertex {i} is not finite: {vert[i].tolist()}")
    if tri.min() < 0 or tri.max() >= vert.shape[0]:
        raise ConfigError(f"{source}: triangle vertex index out of range 0..{vert.shape[0] - 1}")
    nt = tri.shape[0]
    mu = np.broadcast_to(np.asarray(tri_mu, dtype=np.float64), (nt,)).copy()
    rr = np.broadcast_to(np.asarray(tri_rr, dtype=np.float64), (nt,)).copy()
    if not np.all((mu > MU_RANGE[0]) & (mu <= MU_RANGE[1])):
        raise ConfigError(f"{source}: friction scale mu out of range ({MU_RANGE[0]}, {MU_RANGE[1]}]")
    if not np.all((rr >= RR_RANGE[0]) & (rr <= RR_RANGE[1])):
        raise ConfigError(f"{source}: rolling resistance out of range [{RR_RANGE[0]}, {RR_RANGE[1]}]")
    p = vert[:, :2][tri]
    area2 = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    edges = np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2)
    scale = edges.max(axis=1)
    bad = np.abs(area2) <= 1e-9 * scale * scale
    if np.any(bad):
        t = int(np.argmax(bad))
        raise ConfigError(f"{source}: triangle {t} {tri[t].tolist()} has no area in the x-y plane "
                          "(a road mesh must be a height field)")
    cw = area2 < 0.0
    tri[cw] = tri[cw][:, [0, 2, 1]]
    tri = tri.astype(np.int32)
    geom = triangle_geometry(vert, tri)
    h = float(edges.mean()) if cell_size is None else float(cell_size)
    if not h > 0.0:
        raise ConfigError(f"{source}: grid-hash cell size must be > 0, got {h}")
    x0, y0, h, ncx, ncy, cell_start, cell_tri = build_grid_hash(vert, tri, h)
    ipar = np.zeros(NIPAR, dtype=np.int64)
    ipar[[IP_KIND, IP_NCX, IP_NCY, IP_NT, IP_NV]] = ROAD_MESH, ncx, ncy, nt, vert.shape[0]
    ipar[IP_SMOOTH] = int(smooth_normals)
    fpar = np.zeros(NFPAR)
    fpar[[FP_GRID_X0, FP_GRID_Y0, FP_INV_H]] = x0, y0, 1.0 / h
    fpar[FP_GRID_X1], fpar[FP_GRID_Y1] = x0 + ncx * h, y0 + ncy * h
    fpar[FP_NZ] = 1.0
    if off_survey_mu is not None:
        if not MU_RANGE[0] < off_survey_mu <= MU_RANGE[1]:
            raise ConfigError(f"{source}: off-survey friction scale {off_survey_mu} out of range "
                              f"({MU_RANGE[0]}, {MU_RANGE[1]}]")
        if not RR_RANGE[0] <= off_survey_rr <= RR_RANGE[1]:
            raise ConfigError(f"{source}: off-survey rolling resistance {off_survey_rr} out of range "
                              f"[{RR_RANGE[0]}, {RR_RANGE[1]}]")
        ipar[IP_GROUND] = 1
        fpar[FP_OFF_MU], fpar[FP_OFF_RR] = off_survey_mu, off_survey_rr
    bnd_vert, bnd_tri = boundary_edges(tri)
    # vertex normals: area-weighted mean of the adjacent facets' normals (the cross product of two
    # edges is the normal times twice the area)
    e1 = vert[tri[:, 1]] - vert[tri[:, 0]]
    e2 = vert[tri[:, 2]] - vert[tri[:, 0]]
    fn = np.cross(e1, e2)
    vert_n = np.zeros_like(vert)
    for k in range(3):
        np.add.at(vert_n, tri[:, k], fn)
    norm = np.linalg.norm(vert_n, axis=1)
    vert_n[norm > 0] /= norm[norm > 0, None]
    vert_n[norm == 0] = (0.0, 0.0, 1.0)
    return Road(ipar=ipar, fpar=fpar, vert=vert, tri=tri, tri_geom=geom, tri_mu=mu, tri_rr=rr,
                cell_start=cell_start, cell_tri=cell_tri, vert_n=vert_n, bnd_vert=bnd_vert,
                bnd_tri=bnd_tri)
