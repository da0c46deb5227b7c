"""ASAM OpenDRIVE roads (.xodr): reader, the standard's geometry, the drivable surface as a mesh, lane
centre lines and road markings.

Read with lxml; the equations are the standard's (OpenDRIVE 1.6-1.8, sections "Reference line",
"Elevation", "Superelevation", "Lanes"). Units SI (m, rad); axes ISO 8855 (x east/forward, y left, z up),
the file's inertial frame taken as rtsim's road frame.

Reference line (`<planView>`), each `<geometry s x y hdg length>` starting at (x, y) with heading hdg:

- `<line/>`: x = x0 + u cos hdg, y = y0 + u sin hdg (u = s - s0).
- `<arc curvature="k"/>`: heading hdg + k u, position on the circle of radius 1/|k|.
- `<spiral curvStart="k0" curvEnd="k1"/>` (clothoid): curvature k0 + c u with c = (k1 - k0) / length,
  heading hdg + k0 u + c u^2 / 2; the position integral of exp(i heading) in closed form with the Fresnel
  integrals C, S (scipy.special.fresnel): completing the square, for c > 0
  int_0^u exp(i (k0 v + c v^2 / 2)) dv = sqrt(pi / c) exp(-i k0^2 / (2 c)) [E(w(u)) - E(w(0))],
  E = C + i S, w(v) = (v + k0 / c) sqrt(c / pi); c < 0 is the mirror image (conjugate with -k0, |c|).
  A clothoid that is nearly an arc (|w(0)| > FRESNEL_MAX_ARG) is integrated by Gauss-Legendre quadrature.
- `<poly3 a b c d/>`: local v = a + b u + c u^2 + d u^3 over local u, `<paramPoly3 aU .. dV pRange>`:
  u(p), v(p) cubic, p in [0, 1] (`normalized`) or [0, length] (`arcLength`); both rotated by hdg and
  moved to (x, y). Their arc length is integrated numerically (cumulative Simpson on 2049 points per
  geometry, relative error < 1e-9 for these smooth cubics) and inverted by interpolation.

Elevation z(s) and superelevation (the cross section's roll angle about the reference line, positive:
the road falls to the right) and the lane offset are cubics a + b ds + c ds^2 + d ds^3 from their
record's s. A point at lateral position t (along the rolled cross section, left positive) is

    P(s, t) = (x(s), y(s), z(s)) + t (cos(sup) n(s) + sin(sup) e_z),  n = (-sin hdg, cos hdg, 0),

so the cross slope of a superelevated road is tan(sup) (4 % is sup = atan 0.04). Lanes: the centre lane
(id 0) lies at t = laneOffset(s); left lanes (ids 1, 2, ...) add their widths outwards, right lanes
(-1, -2, ...) subtract them; each width is a cubic in ds from its record's sOffset within the lane
section. A lane's friction is its `<material friction>` (the record in force at that s), used as
rtsim's friction scale; lanes without one take the road file's `mu`.

Not read (ignored, see docs/opendrive.md): junction connectivity and road links, lane `<height>`,
`<shape>` (lateral profile), `<border>` lane definitions, objects, signals, surface CRG, geoReference.
Road markings are drawn as ribbons; a lane's `<roadMark>` lies on its outer boundary (the centre lane's
on the lane offset line).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtsim.errors import ConfigError

#: Length of a dash and of the gap of a `broken` road mark, m (the common 3 m / 6 m of the standard's
#: examples; the file's `<type><line length space>` is not read).
DASH, GAP = 3.0, 6.0
#: Height of a drawn road mark above the surface, m (drawing only; the contact mesh has no marks).
MARK_LIFT = 0.01
#: Colours of the drawn marks by the roadMark's `color`.
MARK_COLOURS = {"yellow": "#f2c12e", "blue": "#3a6fd8", "green": "#3bb273", "red": "#d84a3a",
                "orange": "#f08a24"}
MARK_WHITE = "#f4f4f4"


# ---------------------------------------------------------------------------------------------------
# The file as data

@dataclass(frozen=True)
class Geometry:
    """One `<geometry>` of the plan view: start s, x, y, hdg, length and its kind's parameters."""
    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str                  # line | arc | spiral | poly3 | paramPoly3
    par: dict = field(default_factory=dict)


@dataclass
class Lane:
    id: int
    type: str
    widths: list               # [(sOffset, a, b, c, d)]
    friction: list             # [(sOffset, friction)]
    marks: list                # [(sOffset, type, width, colour)]


@dataclass
class LaneSection:
    s: float
    lanes: dict                # id -> Lane (centre lane id 0 included, width none)
    end: float = 0.0           # set from the next section or the road's length


@dataclass
class OdrRoad:
    id: str
    length: float
    rule: str                  # RHT | LHT
    geometries: list
    elevation: list            # [(s, a, b, c, d)]
    superelevation: list
    lane_offset: list
    sections: list
    _tables: dict = field(default_factory=dict, repr=False)


@dataclass
class OpenDrive:
    path: str
    roads: list

    def road(self, road_id: str | None = None) -> OdrRoad:
        """The road of this id (None: the only road of a one-road file)."""
        if road_id is None:
            if len(self.roads) != 1:
                raise ConfigError(f"{self.path}: {len(self.roads)} roads; name one by its id "
                                  f"({', '.join(r.id for r in self.roads)})")
            return self.roads[0]
        for r in self.roads:
            if r.id == str(road_id):
                return r
        raise ConfigError(f"{self.path}: no road with id {road_id!r} (ids: {', '.join(r.id for r in self.roads)})")


def _f(el, name, path, default=None) -> float:
    v = el.get(name)
    if v is None:
        if default is not None:
            return default
        raise ConfigError(f"{path}: line {el.sourceline}: <{el.tag}> has no attribute {name!r}")
    try:
        x = float(v)
    except ValueError:
        raise ConfigError(f"{path}: line {el.sourceline}: <{el.tag} {name}={v!r}>: not a number") from None
    if not math.isfinite(x):
        raise ConfigError(f"{path}: line {el.sourceline}: <{el.tag} {name}={v!r}>: not finite")
    return x


def _cubics(parent, tag, path, s_name="s"):
    if parent is None:
        return []
    out = [(_f(e, s_name, path), _f(e, "a", path), _f(e, "b", path), _f(e, "c", path), _f(e, "d", path))
           for e in parent.findall(tag)]
    return sorted(out, key=lambda r: r[0])


def read_opendrive(path) -> OpenDrive:
    """Parse an .xodr file. Raises ConfigError naming the file, the line and the problem."""
    from lxml import etree

    path = Path(path)
    try:
        root = etree.parse(str(path), etree.XMLParser(resolve_entities=False, no_network=True)).getroot()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None
    except etree.XMLSyntaxError as exc:
        raise ConfigError(f"{path}: not XML: {exc}") from None
    if etree.QName(root).localname != "OpenDRIVE":
        raise ConfigError(f"{path}: root element <{root.tag}>, expected <OpenDRIVE>")
    roads = []
    for r in root.findall("road"):
        rid = r.get("id", "")
        length = _f(r, "length", path)
        geoms = []
        pv = r.find("planView")
        for g in (pv.findall("geometry") if pv is not None else []):
            s, x, y, hdg, glen = (_f(g, k, path) for k in ("s", "x", "y", "hdg", "length"))
            if glen <= 0.0:
                raise ConfigError(f"{path}: line {g.sourceline}: road {rid}: geometry length {glen} must be > 0")
            kids = [c for c in g if isinstance(c.tag, str)]
            if len(kids) != 1:
                raise ConfigError(f"{path}: line {g.sourceline}: road {rid}: a <geometry> holds one shape")
            c = kids[0]
            kind = c.tag
            if kind == "line":
                par = {}
            elif kind == "arc":
                par = {"k": _f(c, "curvature", path)}
            elif kind == "spiral":
                par = {"k0": _f(c, "curvStart", path), "k1": _f(c, "curvEnd", path)}
            elif kind == "poly3":
                par = {k: _f(c, k, path) for k in "abcd"}
            elif kind == "paramPoly3":
                par = {k: _f(c, k, path) for k in ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV")}
                rng = c.get("pRange", "normalized")
                if rng not in ("normalized", "arcLength"):
                    raise ConfigError(f"{path}: line {c.sourceline}: pRange={rng!r} (allowed: normalized, "
                                      "arcLength)")
                par["pmax"] = 1.0 if rng == "normalized" else glen
            else:
                raise ConfigError(f"{path}: line {c.sourceline}: road {rid}: unknown geometry <{kind}> "
                                  "(allowed: line, arc, spiral, poly3, paramPoly3)")
            geoms.append(Geometry(s, x, y, hdg, glen, kind, par))
        if not geoms:
            raise ConfigError(f"{path}: road {rid}: no <planView><geometry>")
        geoms.sort(key=lambda g: g.s)
        lanes_el = r.find("lanes")
        if lanes_el is None:
            raise ConfigError(f"{path}: road {rid}: no <lanes>")
        sections = []
        for ls in lanes_el.findall("laneSection"):
            lanes = {}
            for side in ("left", "center", "right"):
                sel = ls.find(side)
                for ln in (sel.findall("lane") if sel is not None else []):
                    lid = int(_f(ln, "id", path))
                    if (side == "left" and lid <= 0) or (side == "right" and lid >= 0) or \
                            (side == "center" and lid != 0):
                        raise ConfigError(f"{path}: line {ln.sourceline}: road {rid}: lane id {lid} in <{side}>")
                    if side != "center" and not ln.findall("width"):
                        raise ConfigError(f"{path}: line {ln.sourceline}: road {rid}: lane {lid} has no <width> "
                                          "(lane <border> is not supported)")
                    fr = sorted((_f(m, "sOffset", path, 0.0), _f(m, "friction", path))
                                for m in ln.findall("material") if m.get("friction") is not None)
                    for _, mu in fr:
                        if not 0.0 < mu <= 2.0:
                            raise ConfigError(f"{path}: road {rid} lane {lid}: material friction {mu} out of "
                                              "range (0, 2]")
                    marks = sorted(((_f(m, "sOffset", path, 0.0), m.get("type", "none"),
                                     _f(m, "width", path, 0.12), m.get("color", "standard"))
                                    for m in ln.findall("roadMark")), key=lambda q: q[0])
                    lanes[lid] = Lane(lid, ln.get("type", "driving"), _cubics(ln, "width", path, "sOffset"),
                                      fr, marks)
            sections.append(LaneSection(_f(ls, "s", path), lanes))
        if not sections:
            raise ConfigError(f"{path}: road {rid}: no <laneSection>")
        sections.sort(key=lambda q: q.s)
        for a, b in zip(sections, sections[1:] + [None]):
            a.end = b.s if b is not None else length
        roads.append(OdrRoad(rid, length, r.get("rule", "RHT"), geoms,
                             _cubics(r.find("elevationProfile"), "elevation", path),
                             _cubics(r.find("lateralProfile"), "superelevation", path),
                             _cubics(lanes_el, "laneOffset", path), sections))
    if not roads:
        raise ConfigError(f"{path}: no <road>")
    return OpenDrive(str(path), roads)


# ---------------------------------------------------------------------------------------------------
# The standard's equations

def cubic_at(records, s, ds_base: float = 0.0) -> np.ndarray:
    """Value of a piecewise cubic [(s_i, a, b, c, d)] at s (array): the record with the largest s_i <= s
    (the first one before it), a + b ds + c ds^2 + d ds^3 with ds = s - s_i - ds_base. 0 without records."""
    s = np.asarray(s, dtype=float)
    if not records:
        return np.zeros_like(s)
    rec = np.asarray(records, dtype=float)
    i = np.clip(np.searchsorted(rec[:, 0], s, side="right") - 1, 0, len(rec) - 1)
    ds = s - ds_base - rec[i, 0]
    return rec[i, 1] + ds * (rec[i, 2] + ds * (rec[i, 3] + ds * rec[i, 4]))


#: Beyond this Fresnel argument (a clothoid that is nearly an arc: |k0| / sqrt(pi |c|) large) the closed form
#: subtracts two nearly equal values scaled by sqrt(pi / |c|) and loses precision; such a clothoid is
#: integrated by Gauss-Legendre quadrature instead (its heading is then nearly linear: exact to 1e-12 m).
FRESNEL_MAX_ARG = 100.0


def _spiral_quadrature(u, k0, c, panels: int = 16, order: int = 12):
    """Local x, y and heading of a clothoid at arc lengths u by composite Gauss-Legendre quadrature of
    exp(i (k0 v + c v^2 / 2)) over [0, u]."""
    u = np.asarray(u, dtype=float)
    xg, wg = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(0.0, 1.0, panels + 1)
    z = np.zeros(u.shape, dtype=complex)
    for a, b in zip(edges[:-1], edges[1:]):
        v = u[..., None] * (0.5 * (a + b) + 0.5 * (b - a) * xg)
        z += (0.5 * (b - a) * u[..., None] * wg * np.exp(1j * (k0 * v + 0.5 * c * v * v))).sum(axis=-1)
    return z.real, z.imag, k0 * u + 0.5 * c * u * u


def _spiral_local(u, k0, c):
    """Local position (x, y) and heading of a clothoid with start curvature k0 and rate c (1/m^2) from
    the origin heading +x, at arc lengths u (Fresnel integrals; c != 0)."""
    from scipy.special import fresnel

    if abs(k0) > FRESNEL_MAX_ARG * math.sqrt(math.pi * abs(c)):
        return _spiral_quadrature(u, k0, c)
    sign = 1.0 if c > 0 else -1.0
    a, k = abs(c), sign * k0                 # mirrored: curvature k + a v
    scale = math.sqrt(math.pi / a)
    w0 = (k / a) / scale
    w = (u + k / a) / scale
    s1, c1 = fresnel(w)
    s0, c0 = fresnel(w0)
    rot = np.exp(-1j * k * k / (2.0 * a))
    z = scale * rot * ((c1 - c0) + 1j * (s1 - s0))
    return z.real, sign * z.imag, sign * (k * u + 0.5 * a * u * u)


def _param_table(g: Geometry):
    """Arc-length table of a poly3 / paramPoly3: (p grid, s at p, u(p), v(p) callables)."""
    q = g.par
    if g.kind == "poly3":
        def uv(p):
            return p, q["a"] + p * (q["b"] + p * (q["c"] + p * q["d"]))

        def duv(p):
            return np.ones_like(p), q["b"] + p * (2 * q["c"] + 3 * p * q["d"])
        # u reaches the geometry's length at most at u = length (|dv/du| >= 0): bracket generously
        pmax = g.length
    else:
        def uv(p):
            return (q["aU"] + p * (q["bU"] + p * (q["cU"] + p * q["dU"])),
                    q["aV"] + p * (q["bV"] + p * (q["cV"] + p * q["dV"])))

        def duv(p):
            return (q["bU"] + p * (2 * q["cU"] + 3 * p * q["dU"]), q["bV"] + p * (2 * q["cV"] + 3 * p * q["dV"]))
        pmax = q["pmax"]
    n = 2048
    p = np.linspace(0.0, pmax, n + 1)
    du, dv = duv(p)
    sp = np.hypot(du, dv)
    # cumulative Simpson over pairs of intervals, the odd nodes by a midpoint-corrected trapezoid
    s = np.zeros(n + 1)
    h = pmax / n
    s[2::2] = np.cumsum(h / 3.0 * (sp[0:-2:2] + 4 * sp[1:-1:2] + sp[2::2]))
    s[1::2] = s[0:-1:2] + h / 12.0 * (5 * sp[0:-1:2] + 8 * sp[1::2] - sp[2::2])
    return p, s, uv, duv


def reference_line(road: OdrRoad, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x, y (m) and heading (rad) of the reference line at s (array, clipped to [0, length])."""
    s = np.clip(np.atleast_1d(np.asarray(s, dtype=float)), 0.0, road.length)
    x, y, h = np.empty_like(s), np.empty_like(s), np.empty_like(s)
    starts = np.array([g.s for g in road.geometries])
    gi = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(starts) - 1)
    for i, g in enumerate(road.geometries):
        m = gi == i
        if not np.any(m):
            continue
        u = s[m] - g.s
        if g.kind == "line":
            lx, ly, lh = u, np.zeros_like(u), np.zeros_like(u)
        elif g.kind == "arc" or (g.kind == "spiral" and g.par["k1"] == g.par["k0"]):
            k = g.par["k"] if g.kind == "arc" else g.par["k0"]
            if k == 0.0:
                lx, ly, lh = u, np.zeros_like(u), np.zeros_like(u)
            else:
                lh = k * u
                lx, ly = np.sin(lh) / k, (1.0 - np.cos(lh)) / k
        elif g.kind == "spiral":
            lx, ly, lh = _spiral_local(u, g.par["k0"], (g.par["k1"] - g.par["k0"]) / g.length)
        else:
            tab = road._tables.get(i)
            if tab is None:
                tab = road._tables[i] = _param_table(g)
            pg, sg, uv, duv = tab
            p = np.interp(u, sg, pg)
            for _ in range(3):               # Newton on s(p) = u, s(p) from the table's node + Gauss-Legendre
                j = np.clip(np.searchsorted(pg, p, side="right") - 1, 0, len(pg) - 2)
                half = 0.5 * (p - pg[j])
                mid = pg[j] + half
                acc = np.zeros_like(p)
                for xg, wg in zip(*np.polynomial.legendre.leggauss(5)):
                    du, dv = duv(mid + half * xg)
                    acc += wg * np.hypot(du, dv)
                du, dv = duv(p)
                p = p - (sg[j] + half * acc - u) / np.maximum(np.hypot(du, dv), 1e-12)
            lx, ly = uv(p)
            du, dv = duv(p)
            lh = np.arctan2(dv, du)
        ch, sh = math.cos(g.hdg), math.sin(g.hdg)
        x[m] = g.x + ch * lx - sh * ly
        y[m] = g.y + sh * lx + ch * ly
        h[m] = g.hdg + lh
    return x, y, h


def surface_point(road: OdrRoad, s, t) -> np.ndarray:
    """Points (..., 3) of the road surface at reference-line position s and lateral position t (m,
    along the rolled cross section, left positive): P(s, t) of the module docstring."""
    s, t = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(t, dtype=float))
    x, y, h = reference_line(road, s.ravel())
    z = cubic_at(road.elevation, s.ravel())
    sup = cubic_at(road.superelevation, s.ravel())
    tt = t.ravel()
    c = np.cos(sup) * tt
    out = np.stack([x - np.sin(h) * c, y + np.cos(h) * c, z + np.sin(sup) * tt], axis=-1)
    return out.reshape(s.shape + (3,))


def lane_borders(road: OdrRoad, sec: LaneSection, s) -> dict:
    """Lane id -> (t_inner, t_outer) arrays at s (within the section): the standard's sums of widths from
    the lane offset outwards (inner: the border towards the centre lane). The centre lane: (offset, offset)."""
    s = np.asarray(s, dtype=float)
    off = cubic_at(road.lane_offset, s)
    out = {0: (off, off)}
    for side in (1, -1):
        t = off
        lid = side
        while lid in sec.lanes:
            w = cubic_at(sec.lanes[lid].widths, s, sec.s)
            t_out = t + side * w
            out[lid] = (t, t_out)
            t = t_out
            lid += side
    return out


def lane_centre_line(road: OdrRoad, lane_id: int, spacing: float = 0.5):
    """(x, y, z) of the centre line of a lane (m), every `spacing` m of s along the sections where the lane
    exists, in its direction of travel: right lanes along s, left lanes against it (RHT; LHT the
    opposite). Raises ConfigError if the road has no such lane."""
    if lane_id == 0:
        raise ConfigError(f"road {road.id}: lane 0 is the centre lane (no width); give a lane id != 0")
    pts = []
    for sec in road.sections:
        if lane_id not in sec.lanes or sec.end <= sec.s:
            continue
        n = max(2, int(math.ceil((sec.end - sec.s) / spacing)) + 1)
        s = np.linspace(sec.s, sec.end, n)
        a, b = lane_borders(road, sec, s)[lane_id]
        p = surface_point(road, s, 0.5 * (a + b))
        pts.append(p if not pts else p[1:])
    if not pts:
        raise ConfigError(f"road {road.id}: no lane {lane_id} (lanes: "
                          f"{sorted({i for q in road.sections for i in q.lanes if i})})")
    p = np.concatenate(pts)
    forward = (lane_id < 0) == (road.rule != "LHT")
    return p if forward else p[::-1]


def _s_grid(road: OdrRoad, a: float, b: float, ds_max: float, chord: float) -> np.ndarray:
    """Stations from a to b: every geometry and record start inside, and steps of at most ds_max, shorter
    where the reference line curves so that the chord's sagitta stays below `chord` (m) at the road's edge."""
    brk = {a, b}
    for recs in (road.elevation, road.superelevation, road.lane_offset):
        brk.update(r[0] for r in recs if a < r[0] < b)
    brk.update(g.s for g in road.geometries if a < g.s < b)
    brk = sorted(brk)
    out = [np.array([a])]
    for lo, hi in zip(brk[:-1], brk[1:]):
        if hi - lo < 1e-9:
            continue
        probe = np.linspace(lo, hi, 9)
        _, _, hd = reference_line(road, probe)
        kmax = float(np.max(np.abs(np.diff(hd)) / np.maximum(np.diff(probe), 1e-12))) if len(probe) > 1 else 0.0
        step = ds_max if kmax < 1e-9 else min(ds_max, math.sqrt(8.0 * chord / kmax))
        n = max(1, int(math.ceil((hi - lo) / step)))
        out.append(np.linspace(lo, hi, n + 1)[1:])
    return np.concatenate(out)


@dataclass
class RoadMesh:
    """The drivable surface: vertices (nv, 3), triangles (nt, 3), per-triangle friction scale and
    rolling resistance, and per triangle the road id index and lane id it belongs to."""
    vertices: np.ndarray
    triangles: np.ndarray
    tri_mu: np.ndarray
    tri_rr: np.ndarray
    tri_lane: np.ndarray


def mesh_opendrive(odr: OpenDrive, mu: float = 1.0, rolling_resistance: float = 0.0, ds_max: float = 1.0,
                   dt_max: float = 1.0, chord: float = 0.002) -> RoadMesh:
    """Mesh every road's lanes: per lane section a grid of stations in s (`_s_grid`) by columns at every
    lane border plus inner columns at most dt_max apart, each quad split in two triangles. Triangles of
    zero width (a lane that starts or ends) are dropped. Friction per triangle: its lane's material at the
    quad's middle station, else `mu`. Raises ConfigError where the cross section folds over in plan view
    (a lane border inside the centre of curvature)."""
    verts, tris, mus, lanes = [], [], [], []
    nv = 0
    for road in odr.roads:
        for sec in road.sections:
            if sec.end - sec.s < 1e-6:
                continue
            ids = sorted(i for i in sec.lanes if i != 0)
            if not ids:
                continue
            s = _s_grid(road, sec.s, sec.end, ds_max, chord)
            bor = lane_borders(road, sec, s)
            # columns from the rightmost border to the leftmost: (t (ns,), lane id of the strip to its left)
            cols, strip_lane = [], []
            right = sorted((i for i in ids if i < 0))          # -n .. -1
            left = sorted(i for i in ids if i > 0)             # 1 .. n
            order = right + left
            first = bor[order[0]][1] if order[0] < 0 else bor[order[0]][0]
            cols.append(first)
            for lid in order:
                a, b = bor[lid]
                lo, hi = (b, a) if lid < 0 else (a, b)         # right lanes: outer border is the lower t
                k = max(1, int(math.ceil(float(np.max(hi - lo)) / dt_max)))
                for j in range(1, k + 1):
                    cols.append(lo + (hi - lo) * (j / k))
                    strip_lane.append(lid)
            T = np.stack(cols, axis=1)                          # (ns, nc)
            ns, nc = T.shape
            P = surface_point(road, np.repeat(s, nc).reshape(ns, nc), T)
            verts.append(P.reshape(-1, 3))
            idx = np.arange(ns * nc).reshape(ns, nc) + nv
            nv += ns * nc
            a00, a01 = idx[:-1, :-1], idx[:-1, 1:]
            a10, a11 = idx[1:, :-1], idx[1:, 1:]
            t1 = np.stack([a00, a10, a11], axis=-1).reshape(-1, 3)
            t2 = np.stack([a00, a11, a01], axis=-1).reshape(-1, 3)
            lane_of = np.broadcast_to(np.array(strip_lane), (ns - 1, nc - 1)).reshape(-1)
            smid = 0.5 * (s[:-1] + s[1:])
            fr = np.empty((ns - 1, nc - 1))
            for j, lid in enumerate(strip_lane):
                recs = sec.lanes[lid].friction
                if not recs:
                    fr[:, j] = mu
                else:
                    offs = np.array([r[0] for r in recs])
                    vals = np.array([r[1] for r in recs])
                    fr[:, j] = vals[np.clip(np.searchsorted(offs, smid - sec.s + 1e-9, side="right") - 1, 0,
                                            len(vals) - 1)]
            tris += [t1, t2]
            mus += [fr.reshape(-1), fr.reshape(-1)]
            lanes += [lane_of, lane_of]
    if not tris:
        raise ConfigError(f"{odr.path}: no lane with a width to mesh")
    V = np.concatenate(verts)
    F = np.concatenate(tris)
    MU = np.concatenate(mus)
    LN = np.concatenate(lanes)
    p = V[:, :2][F]
    area2 = ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
             - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    scale = np.max(np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2), axis=1)
    keep = np.abs(area2) > 1e-9 * scale * scale + 1e-12
    if np.any(area2[keep] < 0.0):
        bad = int(np.argmax(keep & (area2 < 0.0)))
        c = V[F[bad]].mean(axis=0)
        raise ConfigError(f"{odr.path}: the road surface folds over near x = {c[0]:.1f}, y = {c[1]:.1f} m "
                          "(a lane border beyond the centre of curvature)")
    F, MU, LN = F[keep], MU[keep], LN[keep]
    return RoadMesh(V, F.astype(np.int32), MU, np.full(len(F), float(rolling_resistance)), LN.astype(np.int32))


# ---------------------------------------------------------------------------------------------------
# Road markings (drawing)

def _ribbon(P: np.ndarray, width: float):
    """Left and right edges (n, 3) of a strip of `width` m centred on the polyline P (n, 3), lifted by
    MARK_LIFT."""
    d = np.gradient(P[:, :2], axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    nrm = np.stack([-d[:, 1], d[:, 0], np.zeros(len(d))], axis=1)
    lift = np.array([0.0, 0.0, MARK_LIFT])
    return P + 0.5 * width * nrm + lift, P - 0.5 * width * nrm + lift


def road_markings(odr: OpenDrive, spacing: float = 0.5) -> dict:
    """The road marks as triangles to draw: {"vertices": (nv, 3), "triangles": (nt, 3), "colour": [per
    triangle '#rrggbb']}. Each lane's marks on its outer border (the centre lane's on the offset line),
    `solid` continuous, `broken` in DASH / GAP dashes, the doubled types (`solid solid`, `solid broken`,
    `broken solid`, `broken broken`) as two lines one width apart; `none` not drawn; any other type drawn
    solid."""
    V, F, C = [], [], []
    nv = 0

    def add(P, width, colour):
        nonlocal nv
        if len(P) < 2:
            return
        a, b = _ribbon(P, width)
        n = len(P)
        V.append(np.concatenate([a, b]))
        i = np.arange(n - 1) + nv
        F.append(np.concatenate([np.stack([i, i + n, i + 1], 1), np.stack([i + 1, i + n, i + n + 1], 1)]))
        C.extend([colour] * (2 * (n - 1)))
        nv += 2 * n

    for road in odr.roads:
        for sec in road.sections:
            for lid, lane in sec.lanes.items():
                for k, (off, typ, width, colour) in enumerate(lane.marks):
                    a = sec.s + off
                    b = sec.s + lane.marks[k + 1][0] if k + 1 < len(lane.marks) else sec.end
                    b = min(b, sec.end)
                    if typ == "none" or b - a < 1e-6:
                        continue
                    col = MARK_COLOURS.get(colour, MARK_WHITE)
                    parts = typ.split() if typ in ("solid solid", "solid broken", "broken solid",
                                                   "broken broken") else [typ]
                    for j, part in enumerate(parts):
                        shift = 0.0 if len(parts) == 1 else (j - 0.5) * 2.0 * width
                        if part == "broken":
                            starts = np.arange(a, b, DASH + GAP)
                            spans = [(q, min(q + DASH, b)) for q in starts]
                        else:
                            spans = [(a, b)]
                        for lo, hi in spans:
                            n = max(2, int(math.ceil((hi - lo) / spacing)) + 1)
                            s = np.linspace(lo, hi, n)
                            t = lane_borders(road, sec, s)[lid][1] + shift
                            add(surface_point(road, s, t), width, col)
    if not V:
        return {"vertices": np.zeros((0, 3)), "triangles": np.zeros((0, 3), dtype=np.int32), "colour": []}
    return {"vertices": np.concatenate(V), "triangles": np.concatenate(F).astype(np.int32), "colour": C}
