"""Tyre-road contact (rtsim.road.query.wheel_contact) against analytic disc-on-plane geometry.

The reference here is computed independently of the kernel's formula: the contact point is the point
of the line where the wheel plane cuts the road plane that is closest to the centre (found by solving
for a point on both planes), the penetration R0 minus its distance to the centre."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import Delaunay

from rtsim.road.model import make_grade, make_mesh, make_plane
from rtsim.road.config import load_road
from rtsim.road.query import (CT_D, CT_EX, CT_GAMMA, CT_MU, CT_NX, CT_PX, CT_RR, NCONTACT, NQUERY,
                              road_query, wheel_contact)

ROOT = __import__("pathlib").Path(__file__).resolve().parent.parent


def contact(road, c, a, r0):
    out = np.zeros(NCONTACT)
    face = wheel_contact(road, *map(float, c), *map(float, a), float(r0), out)
    return face, out


def reference(c, a, r0, n, q):
    """Disc (centre c, axis a, radius r0) on the plane through q with unit normal n."""
    c, a, n, q = (np.asarray(v, dtype=float) for v in (c, a, n, q))
    line = np.cross(a, n)
    line /= np.linalg.norm(line)
    # a point X on both planes: a.(X - c) = 0, n.(X - q) = 0, line.(X - c) = 0 (closest to c)
    m = np.array([a, n, line])
    x = np.linalg.solve(m, [a @ c, n @ q, line @ c])
    return x, r0 - np.linalg.norm(x - c), math.asin(a @ n), line


def axis(yaw, camber):
    """Spin axis of a wheel heading `yaw` (about z) and leaning `camber` (top to the right > 0)."""
    return np.array([-math.sin(yaw) * math.cos(camber), math.cos(yaw) * math.cos(camber), math.sin(camber)])


def test_upright_wheel_on_flat_road():
    road = make_plane(0.0, mu=0.9, rolling_resistance=0.011)
    face, out = contact(road, (1.0, 2.0, 0.30), (0.0, 1.0, 0.0), 0.31)
    assert face == 0
    np.testing.assert_allclose(out[CT_PX:CT_PX + 3], [1.0, 2.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(out[CT_NX:CT_NX + 3], [0.0, 0.0, 1.0], atol=0)
    np.testing.assert_allclose(out[CT_EX:CT_EX + 3], [1.0, 0.0, 0.0], atol=0)
    assert out[CT_D] == pytest.approx(0.01, abs=1e-15)
    assert out[CT_GAMMA] == 0.0 and out[CT_MU] == 0.9 and out[CT_RR] == 0.011
    # lifted off the road: no contact
    face, out = contact(road, (1.0, 2.0, 0.40), (0.0, 1.0, 0.0), 0.31)
    assert face == 0 and out[CT_D] == pytest.approx(-0.09, abs=1e-15)


@pytest.mark.parametrize("theta", [0.05, -0.1, 0.3])
def test_cambered_wheel_on_flat_road(theta):
    """Axis (0, cos t, sin t): the top leans right by t, the lowest disc point is at y + h tan t,
    and the distance from the centre to the road along the wheel plane is h / cos t."""
    h, r0 = 0.29, 0.3
    road = make_plane(0.0)
    face, out = contact(road, (0.0, 0.0, h), (0.0, math.cos(theta), math.sin(theta)), r0)
    np.testing.assert_allclose(out[CT_PX:CT_PX + 3], [0.0, h * math.tan(theta), 0.0], atol=1e-15)
    assert out[CT_D] == pytest.approx(r0 - h / math.cos(theta), abs=1e-15)
    assert out[CT_GAMMA] == pytest.approx(theta, abs=1e-15)
    np.testing.assert_allclose(out[CT_EX:CT_EX + 3], [1.0, 0.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("seed", range(6))
def test_any_wheel_on_a_tilted_plane_matches_reference(seed):
    rng = np.random.default_rng(seed)
    grade, psi = rng.uniform(-0.3, 0.3), rng.uniform(-math.pi, math.pi)
    road = make_grade(grade, psi, (1.0, -1.0, 0.5))
    a = axis(rng.uniform(-math.pi, math.pi), rng.uniform(-0.4, 0.4))
    r0 = 0.3
    out_q = np.zeros(NQUERY)
    cx, cy = rng.uniform(-50, 50, 2)
    road_query(road, cx, cy, out_q)
    c = np.array([cx, cy, out_q[0] + rng.uniform(0.2, 0.35)])
    face, out = contact(road, c, a, r0)
    n = out_q[1:4]
    p, d, gamma, line = reference(c, a, r0, n, (cx, cy, out_q[0]))
    np.testing.assert_allclose(out[CT_PX:CT_PX + 3], p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out[CT_NX:CT_NX + 3], n, rtol=0, atol=0)
    assert out[CT_D] == pytest.approx(d, abs=1e-12)
    assert out[CT_GAMMA] == pytest.approx(gamma, abs=1e-12)
    np.testing.assert_allclose(out[CT_EX:CT_EX + 3], line, atol=1e-12)
    # P is on the road, in the wheel plane, and the ground point of the disc is P
    road_query(road, p[0], p[1], out_q)
    assert out[CT_PX + 2] == pytest.approx(out_q[0], abs=1e-12)
    assert abs(a @ (out[CT_PX:CT_PX + 3] - c)) < 1e-12


def test_upright_wheel_on_the_5pct_grade_config():
    """On z = 0.05 x (grade_5pct.toml) an upright wheel (axis +y, camber 0 relative to the road)
    touches at the foot of the perpendicular from its centre: P = C - h n, d = R0 - h."""
    road = load_road(ROOT / "configs" / "roads" / "grade_5pct.toml")
    g, r0 = 0.05, 0.3
    c = np.array([10.0, 0.7, 0.5 + 0.28])
    face, out = contact(road, c, (0.0, 1.0, 0.0), r0)
    k = 1.0 / math.sqrt(1 + g * g)
    n = np.array([-g * k, 0.0, k])
    h = (c[2] - g * c[0]) * k
    np.testing.assert_allclose(out[CT_PX:CT_PX + 3], c - h * n, atol=1e-15)
    np.testing.assert_allclose(out[CT_NX:CT_NX + 3], n, atol=1e-16)
    np.testing.assert_allclose(out[CT_EX:CT_EX + 3], [k, 0.0, g * k], atol=1e-16)
    assert out[CT_D] == pytest.approx(r0 - h, abs=1e-15)
    assert out[CT_GAMMA] == 0.0


def test_mesh_of_a_plane_gives_the_plane_contact():
    """A tilted plane as a mesh: wherever the wheel stands (the contact point often lies in another
    triangle than the centre's projection), the contact is the analytic one."""
    gx, gy, z0 = 0.04, -0.03, 2.0
    xs, ys = np.meshgrid(np.linspace(0, 10, 21), np.linspace(-3, 3, 13))
    xy = np.column_stack([xs.ravel(), ys.ravel()])
    mesh = make_mesh(np.column_stack([xy, z0 + gx * xy[:, 0] + gy * xy[:, 1]]),
                     Delaunay(xy).simplices, 1.0, 0.01)
    plane = make_grade(math.hypot(gx, gy), math.atan2(gy, gx), (0.0, 0.0, z0))
    rng = np.random.default_rng(7)
    for _ in range(200):
        c = np.array([rng.uniform(1, 9), rng.uniform(-2, 2), 0.0])
        c[2] = z0 + gx * c[0] + gy * c[1] + rng.uniform(0.25, 0.32)
        a = axis(rng.uniform(-1, 1), rng.uniform(-0.3, 0.3))
        face_m, out_m = contact(mesh, c, a, 0.3)
        face_p, out_p = contact(plane, c, a, 0.3)
        assert face_m >= 0
        np.testing.assert_allclose(out_m[:CT_MU], out_p[:CT_MU], rtol=0, atol=1e-9)


def test_contact_moves_to_the_triangle_under_the_contact_point():
    """Valley: z = 0 for y < 0, z = g y for y > 0 (mesh edge along y = 0). A cambered wheel whose
    centre is over the flat side but whose lowest point, on the flat plane, lies beyond y = 0 ends
    on the sloped plane, and the result is that plane's analytic contact."""
    g, r0, theta = 0.2, 0.3, 0.2
    xs, ys = np.meshgrid(np.linspace(-2, 2, 9), np.linspace(-2, 2, 9))
    xy = np.column_stack([xs.ravel(), ys.ravel()])
    z = np.where(xy[:, 1] > 0, g * xy[:, 1], 0.0)
    cells = []
    for j in range(8):
        for i in range(8):
            v = j * 9 + i
            cells += [(v, v + 1, v + 10), (v, v + 10, v + 9)]
    road = make_mesh(np.column_stack([xy, z]), cells, np.where(np.arange(128) < 64, 0.5, 1.0), 0.01)
    a = np.array([0.0, math.cos(theta), math.sin(theta)])
    c = np.array([0.1, -0.02, 0.28])
    # on the flat plane alone the contact point would be at y = -0.02 + 0.28 tan(theta) > 0
    assert -0.02 + 0.28 * math.tan(theta) > 0
    face, out = contact(road, c, a, r0)
    k = 1 / math.sqrt(1 + g * g)
    n = np.array([0.0, -g * k, k])
    p, d, gamma, _ = reference(c, a, r0, n, (0.0, 0.0, 0.0))
    assert p[1] > 0
    assert road.tri_geom[face, 10] < 0                    # a triangle of the sloped side
    np.testing.assert_allclose(out[CT_PX:CT_PX + 3], p, atol=1e-12)
    np.testing.assert_allclose(out[CT_NX:CT_NX + 3], n, atol=1e-15)
    assert out[CT_D] == pytest.approx(d, abs=1e-12)
    assert out[CT_GAMMA] == pytest.approx(gamma, abs=1e-12)
    assert out[CT_MU] == 1.0


def test_off_the_mesh_and_degenerate_wheels_report_no_contact():
    xs, ys = np.meshgrid(np.linspace(0, 4, 5), np.linspace(0, 4, 5))
    xy = np.column_stack([xs.ravel(), ys.ravel()])
    road = make_mesh(np.column_stack([xy, np.zeros(25)]), Delaunay(xy).simplices, 1.0, 0.01)
    face, out = contact(road, (5.0, 1.0, 0.2), (0.0, 1.0, 0.0), 0.3)
    assert face == -1 and out[CT_D] == -np.inf
    np.testing.assert_array_equal(out[CT_PX:CT_PX + 3], [5.0, 1.0, 0.2])
    # a wheel lying flat on the road has no lowest point: reported as no contact
    face, out = contact(road, (2.0, 2.0, 0.01), (0.0, 0.0, 1.0), 0.3)
    assert face >= 0 and out[CT_D] == -np.inf
