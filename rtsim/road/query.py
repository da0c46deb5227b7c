"""Compiled road queries: surface height, normal, friction and rolling resistance under a point, and
the tyre-road contact of a wheel disc. One function serves every road kind (see rtsim.road.model).

The kernels never allocate: results go to caller-owned arrays, and the return value is the face
index (the triangle of a mesh, 0 for an analytic plane) or -1 when the point is off the road.

Tyre-road contact (`wheel_contact`), disc on a locally planar road
------------------------------------------------------------------
The wheel is a rigid disc of unloaded radius R0, centre C, unit spin axis a (pointing to the wheel's
left when it rolls forward, so forward rolling is a positive rotation about a). The road near the
wheel is replaced by the plane of one triangle: point Q on the surface, unit normal n (up).

- sin(gamma) = a.n: gamma is the inclination of the wheel plane from the road normal (camber relative
  to the surface); gamma > 0 when the top of the wheel leans to its right (a positive rotation about
  the wheel's forward direction), the ISO 8855 inclination sign. cos(gamma) = |n - (a.n) a|.
- u = -(n - (a.n) a) / cos(gamma) is the unit direction in the wheel plane closest to -n: the disc
  point C + R0 u is the lowest point of the disc relative to the road plane.
- h = n.(C - Q) is the height of the centre above the plane, and s = h / cos(gamma) the distance from
  C along u to the plane. The contact point is P = C + s u: the point of the line where the wheel
  plane cuts the road plane that is nearest to C.
- The penetration (radial tyre deflection, in the wheel plane) is d = R0 - s; d <= 0 means no contact.
  Measured along n it is d cos(gamma).
- The longitudinal direction e_x = (a x n) / cos(gamma) is tangent to the road, in the wheel plane,
  forward; the lateral direction is n x e_x.

The plane is that of the triangle under the centre's vertical projection (Cx, Cy). If P falls in
another triangle, its plane is used instead, at most twice more (three planes in all); where the
contact alternates between two triangles (a crest), the last plane is kept, an approximation whose
error is bounded by the angle between the two planes times the distance from C to the edge.
"""
from __future__ import annotations

import math

from rtsim.jit import inline_kernel, kernel
from rtsim.road.model import (
    FP_GRID_X0, FP_GRID_X1, FP_GRID_Y0, FP_GRID_Y1, FP_GX, FP_GY, FP_INV_H, FP_MU, FP_NX, FP_NY,
    FP_NZ, FP_OFF_MU, FP_OFF_RR, FP_RR, FP_X0, FP_Y0, FP_Z0, INSIDE_TOL, IP_GROUND, IP_KIND, IP_NCX,
    IP_NCY, IP_SMOOTH, OFF_SURVEY_BAND, OFF_SURVEY_BLEND, ROAD_PLANE, TG_B11, TG_B12,
    TG_B21, TG_B22, TG_GX, TG_GY, TG_NX, TG_NY, TG_NZ, TG_X0, TG_Y0, TG_Z0,
)

# road_query output slots
Q_Z = 0
Q_NX = 1
Q_NY = 2
Q_NZ = 3
Q_MU = 4
Q_RR = 5
NQUERY = 6

# wheel_contact output slots
CT_PX = 0      # contact point P (3)
CT_NX = 3      # road normal n at P (3)
CT_EX = 6      # longitudinal unit direction e_x (3)
CT_D = 9       # penetration d = R0 - |P - C| (m), <= 0: no contact
CT_GAMMA = 10  # inclination relative to the road, rad
CT_MU = 11     # friction scale of the triangle used
CT_RR = 12     # rolling-resistance coefficient of the triangle used
NCONTACT = 13

#: Planes tried at most by wheel_contact (the first one plus two moves).
MAX_CONTACT_PLANES = 3


@inline_kernel
def _edge_point(road, j, x, y):
    """(squared horizontal distance, parameter s in [0, 1]) of the point of boundary edge j nearest (x, y)."""
    v = road.vert
    a = road.bnd_vert[j, 0]
    b = road.bnd_vert[j, 1]
    ex = v[b, 0] - v[a, 0]
    ey = v[b, 1] - v[a, 1]
    dx = x - v[a, 0]
    dy = y - v[a, 1]
    ee = ex * ex + ey * ey
    s = (dx * ex + dy * ey) / ee if ee > 0.0 else 0.0
    s = min(max(s, 0.0), 1.0)
    rx = dx - s * ex
    ry = dy - s * ey
    return rx * rx + ry * ry, s


@inline_kernel
def off_survey(road, x, y):
    """(face, z, nx, ny, nz, mu, rr) of the ground beyond a mesh's survey at (x, y), the rule of
    "Off the survey" in rtsim.road.model: face -1; z = -inf (no ground) when the mesh declares none,
    has no boundary or (x, y) is not finite."""
    nb = road.bnd_vert.shape[0]
    if road.ipar[IP_GROUND] == 0 or nb == 0 or not (math.isfinite(x) and math.isfinite(y)):
        return -1, -math.inf, 0.0, 0.0, 1.0, 0.0, 0.0
    best = math.inf
    for j in range(nb):
        r2, s = _edge_point(road, j, x, y)
        best = min(best, r2)
    rmin = math.sqrt(best)
    band = OFF_SURVEY_BAND * rmin
    v = road.vert
    smooth = road.ipar[IP_SMOOTH] != 0
    wsum = 0.0
    z = 0.0
    bx = 0.0
    by = 0.0
    bz = 0.0
    mub = 0.0
    rrb = 0.0
    for j in range(nb):
        r2, s = _edge_point(road, j, x, y)
        if r2 > best:
            if not band > 0.0:
                continue
            u = (math.sqrt(r2) - rmin) / band
            if u >= 1.0:
                continue
            wj = (1.0 - u) * (1.0 - u)
        else:
            wj = 1.0
        a = road.bnd_vert[j, 0]
        b = road.bnd_vert[j, 1]
        t = road.bnd_tri[j]
        wsum += wj
        z += wj * ((1.0 - s) * v[a, 2] + s * v[b, 2])
        if smooth:
            vn = road.vert_n
            bx += wj * ((1.0 - s) * vn[a, 0] + s * vn[b, 0])
            by += wj * ((1.0 - s) * vn[a, 1] + s * vn[b, 1])
            bz += wj * ((1.0 - s) * vn[a, 2] + s * vn[b, 2])
        else:
            g = road.tri_geom
            bx += wj * g[t, TG_NX]
            by += wj * g[t, TG_NY]
            bz += wj * g[t, TG_NZ]
        mub += wj * road.tri_mu[t]
        rrb += wj * road.tri_rr[t]
    z /= wsum
    r = min(rmin / OFF_SURVEY_BLEND, 1.0)
    w = r * r * (3.0 - 2.0 * r)
    nx = (1.0 - w) * bx / wsum
    ny = (1.0 - w) * by / wsum
    nz = (1.0 - w) * bz / wsum + w
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    fp = road.fpar
    mu = (1.0 - w) * mub / wsum + w * fp[FP_OFF_MU]
    rr = (1.0 - w) * rrb / wsum + w * fp[FP_OFF_RR]
    return -1, z, nx * inv, ny * inv, nz * inv, mu, rr


@inline_kernel
def locate(road, x, y):
    """(face, z, nx, ny, nz, mu, rr) of the road under (x, y); face -1 off the survey of a mesh, where
    z is the continued ground (off_survey) or -inf without one."""
    fp = road.fpar
    if road.ipar[IP_KIND] == ROAD_PLANE:
        z = fp[FP_Z0] + fp[FP_GX] * (x - fp[FP_X0]) + fp[FP_GY] * (y - fp[FP_Y0])
        return 0, z, fp[FP_NX], fp[FP_NY], fp[FP_NZ], fp[FP_MU], fp[FP_RR]
    # mesh: grid-hash cell, then the inside test on the few triangles listed there
    if x >= fp[FP_GRID_X0] and x < fp[FP_GRID_X1] and y >= fp[FP_GRID_Y0] and y < fp[FP_GRID_Y1]:
        ncx = road.ipar[IP_NCX]
        inv_h = fp[FP_INV_H]
        ix = min(int((x - fp[FP_GRID_X0]) * inv_h), ncx - 1)
        iy = min(int((y - fp[FP_GRID_Y0]) * inv_h), road.ipar[IP_NCY] - 1)
        c = iy * ncx + ix
        g = road.tri_geom
        for k in range(road.cell_start[c], road.cell_start[c + 1]):
            t = road.cell_tri[k]
            dx = x - g[t, TG_X0]
            dy = y - g[t, TG_Y0]
            l1 = g[t, TG_B11] * dx + g[t, TG_B12] * dy
            if l1 < -INSIDE_TOL:
                continue
            l2 = g[t, TG_B21] * dx + g[t, TG_B22] * dy
            if l2 < -INSIDE_TOL or l1 + l2 > 1.0 + INSIDE_TOL:
                continue
            z = g[t, TG_Z0] + g[t, TG_GX] * dx + g[t, TG_GY] * dy
            if road.ipar[IP_SMOOTH] == 0:
                return t, z, g[t, TG_NX], g[t, TG_NY], g[t, TG_NZ], road.tri_mu[t], road.tri_rr[t]
            # smooth: the normal interpolated from the vertex normals (continuous across edges)
            l0 = 1.0 - l1 - l2
            vn = road.vert_n
            a, b, c3 = road.tri[t, 0], road.tri[t, 1], road.tri[t, 2]
            nx = l0 * vn[a, 0] + l1 * vn[b, 0] + l2 * vn[c3, 0]
            ny = l0 * vn[a, 1] + l1 * vn[b, 1] + l2 * vn[c3, 1]
            nz = l0 * vn[a, 2] + l1 * vn[b, 2] + l2 * vn[c3, 2]
            inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
            return t, z, nx * inv, ny * inv, nz * inv, road.tri_mu[t], road.tri_rr[t]
    return off_survey(road, x, y)


@kernel
def road_query(road, x, y, out):
    """Surface under (x, y): out[Q_Z] height, out[Q_NX:Q_NZ+1] unit normal (up), out[Q_MU] friction
    scale, out[Q_RR] rolling-resistance coefficient. Returns the triangle index (0 for a plane), or -1
    off a mesh's survey: then out is the ground continued beyond it (rtsim.road.model, "Off the
    survey"), or -inf, (0, 0, 1), 0, 0 for a mesh without one."""
    t, z, nx, ny, nz, mu, rr = locate(road, x, y)
    out[Q_Z] = z
    out[Q_NX] = nx
    out[Q_NY] = ny
    out[Q_NZ] = nz
    out[Q_MU] = mu
    out[Q_RR] = rr
    return t


@kernel
def wheel_contact(road, cx, cy, cz, ax, ay, az, r0, out):
    """Contact of a wheel disc (centre (cx, cy, cz), unit spin axis (ax, ay, az), unloaded radius r0)
    with the road; see the module docstring for the geometry. Fills out[0:NCONTACT] (CT_* slots) and
    returns the index of the triangle whose plane was used (0 for a plane road), -1 for the tangent
    plane of the ground beyond a mesh's survey; if there is no ground under the centre (a mesh without
    off-survey ground) d = -inf, P = C, n = e_z, e_x = e_x of the world. A wheel lying flat on the
    road (cos(gamma) < 1e-9) also reports d = -inf."""
    t, z, nx, ny, nz, mu, rr = locate(road, cx, cy)
    if z == -math.inf:
        out[CT_PX] = cx
        out[CT_PX + 1] = cy
        out[CT_PX + 2] = cz
        out[CT_NX] = 0.0
        out[CT_NX + 1] = 0.0
        out[CT_NX + 2] = 1.0
        out[CT_EX] = 1.0
        out[CT_EX + 1] = 0.0
        out[CT_EX + 2] = 0.0
        out[CT_D] = -math.inf
        out[CT_GAMMA] = 0.0
        out[CT_MU] = 0.0
        out[CT_RR] = 0.0
        return -1
    qx = cx
    qy = cy
    qz = z
    px = cx
    py = cy
    pz = z
    s = 0.0
    sa = 0.0
    cg = 1.0
    for it in range(MAX_CONTACT_PLANES):
        sa = ax * nx + ay * ny + az * nz
        cg = math.sqrt(max(1.0 - sa * sa, 0.0))
        h = nx * (cx - qx) + ny * (cy - qy) + nz * (cz - qz)
        if cg < 1e-9:
            s = math.inf
            px = cx - h * nx
            py = cy - h * ny
            pz = cz - h * nz
            break
        inv = 1.0 / cg
        ux = -(nx - sa * ax) * inv
        uy = -(ny - sa * ay) * inv
        uz = -(nz - sa * az) * inv
        s = h * inv
        px = cx + s * ux
        py = cy + s * uy
        pz = cz + s * uz
        if it == MAX_CONTACT_PLANES - 1:
            break
        t2, z2, nx2, ny2, nz2, mu2, rr2 = locate(road, px, py)
        if z2 == -math.inf or t2 == t:
            break
        t = t2
        qx = px
        qy = py
        qz = z2
        nx = nx2
        ny = ny2
        nz = nz2
        mu = mu2
        rr = rr2
    out[CT_PX] = px
    out[CT_PX + 1] = py
    out[CT_PX + 2] = pz
    out[CT_NX] = nx
    out[CT_NX + 1] = ny
    out[CT_NX + 2] = nz
    if cg >= 1e-9:
        inv = 1.0 / cg
        out[CT_EX] = (ay * nz - az * ny) * inv
        out[CT_EX + 1] = (az * nx - ax * nz) * inv
        out[CT_EX + 2] = (ax * ny - ay * nx) * inv
    else:
        out[CT_EX] = 1.0
        out[CT_EX + 1] = 0.0
        out[CT_EX + 2] = 0.0
    out[CT_D] = r0 - s
    out[CT_GAMMA] = math.asin(min(max(sa, -1.0), 1.0))
    out[CT_MU] = mu
    out[CT_RR] = rr
    return t


@kernel
def query_points(road, xy, out, face):
    """road_query for each row of xy (n, 2): out (n, NQUERY), face (n,) int."""
    for i in range(xy.shape[0]):
        face[i] = road_query(road, xy[i, 0], xy[i, 1], out[i])


@kernel
def contact_points(road, centre, axis, r0, out, face):
    """wheel_contact for each row of centre (n, 3) and axis (n, 3): out (n, NCONTACT), face (n,)."""
    for i in range(centre.shape[0]):
        face[i] = wheel_contact(road, centre[i, 0], centre[i, 1], centre[i, 2],
                                axis[i, 0], axis[i, 1], axis[i, 2], r0, out[i])
