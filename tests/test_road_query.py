"""Road queries (rtsim.road.query.road_query) against analytic surfaces and a brute-force search."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import Delaunay

from rtsim.road.model import make_grade, make_mesh, make_plane
from rtsim.road.query import NQUERY, Q_MU, Q_NX, Q_NZ, Q_RR, Q_Z, query_points, road_query


def query_many(road, xy):
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    out = np.zeros((xy.shape[0], NQUERY))
    face = np.zeros(xy.shape[0], dtype=np.int64)
    query_points(road, xy, out, face)
    return face, out


def grid_mesh(f, x0, x1, y0, y1, h, mu=1.0, rr=0.01):
    """Mesh of z = f(x, y) sampled on a regular grid of spacing h (Delaunay of the nodes)."""
    gx, gy = np.meshgrid(np.arange(x0, x1 + 1e-9, h), np.arange(y0, y1 + 1e-9, h))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    tri = Delaunay(xy).simplices
    return make_mesh(np.column_stack([xy, f(xy[:, 0], xy[:, 1])]), tri, mu, rr, cell_size=h)


def test_flat_plane_height_normal_and_surface_values():
    road = make_plane(0.3, mu=0.8, rolling_resistance=0.012)
    rng = np.random.default_rng(0)
    xy = rng.uniform(-1e3, 1e3, (200, 2))
    face, out = query_many(road, xy)
    assert np.all(face == 0)
    np.testing.assert_array_equal(out[:, Q_Z], 0.3)
    np.testing.assert_array_equal(out[:, Q_NX:Q_NZ + 1], np.tile([0.0, 0.0, 1.0], (200, 1)))
    np.testing.assert_array_equal(out[:, Q_MU], 0.8)
    np.testing.assert_array_equal(out[:, Q_RR], 0.012)


@pytest.mark.parametrize("grade, heading_deg", [(0.05, 0.0), (0.12, 30.0), (-0.08, -90.0), (0.2, 180.0)])
def test_grade_height_and_normal_are_analytic(grade, heading_deg):
    psi = math.radians(heading_deg)
    origin = (3.0, -2.0, 1.5)
    road = make_grade(grade, psi, origin, mu=0.9, rolling_resistance=0.015)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-100, 100, (500, 2))
    face, out = query_many(road, xy)
    along = (xy[:, 0] - origin[0]) * math.cos(psi) + (xy[:, 1] - origin[1]) * math.sin(psi)
    np.testing.assert_allclose(out[:, Q_Z], origin[2] + grade * along, rtol=0, atol=1e-12)
    k = 1.0 / math.sqrt(1.0 + grade * grade)
    normal = np.array([-grade * math.cos(psi) * k, -grade * math.sin(psi) * k, k])
    np.testing.assert_allclose(out[:, Q_NX:Q_NZ + 1], np.tile(normal, (500, 1)), rtol=0, atol=1e-15)
    assert np.all(face == 0) and np.all(out[:, Q_MU] == 0.9) and np.all(out[:, Q_RR] == 0.015)
    # positive grade = uphill when travelling along the heading: 1 m of travel rises by `grade`
    out1 = np.zeros(NQUERY)
    road_query(road, origin[0] + math.cos(psi), origin[1] + math.sin(psi), out1)
    assert out1[Q_Z] - origin[2] == pytest.approx(grade, abs=1e-12)


def test_mesh_of_smooth_function_within_interpolation_bound():
    """z = 0.01 x + 0.02 sin(y) on a 0.5 m grid. Linear interpolation on a right triangle (which
    contains its circumcentre) errs by at most M R^2 / 2 with R = h / sqrt(2) its circumradius and
    M = max |Hessian| = 0.02; its gradient errs by at most 2 M h (mean-value theorem on the legs)."""
    h, m = 0.5, 0.02
    f = lambda x, y: 0.01 * x + 0.02 * np.sin(y)  # noqa: E731
    road = grid_mesh(f, 0.0, 30.0, -4.0, 4.0, h)
    rng = np.random.default_rng(2)
    xy = np.column_stack([rng.uniform(0.0, 30.0, 5000), rng.uniform(-4.0, 4.0, 5000)])
    face, out = query_many(road, xy)
    assert np.all(face >= 0)
    err = np.abs(out[:, Q_Z] - f(xy[:, 0], xy[:, 1]))
    bound = m * h * h / 4.0
    assert err.max() <= bound + 1e-12
    assert err.max() > 0.05 * bound          # the bound is not vacuous for this surface
    grad = -out[:, [Q_NX, Q_NX + 1]] / out[:, [Q_NZ]]
    exact = np.column_stack([np.full(5000, 0.01), 0.02 * np.cos(xy[:, 1])])
    assert np.linalg.norm(grad - exact, axis=1).max() <= 2.0 * m * h
    np.testing.assert_allclose(np.linalg.norm(out[:, Q_NX:Q_NZ + 1], axis=1), 1.0, atol=1e-15)


def test_mesh_reproduces_a_linear_surface():
    f = lambda x, y: 2.5 - 0.013 * x + 0.021 * y  # noqa: E731
    road = grid_mesh(f, -10.0, 10.5, -3.0, 3.3, 0.7)     # nodes -10 .. 10.3 by 0.7, -3 .. 3.3
    rng = np.random.default_rng(3)
    xy = np.column_stack([rng.uniform(-10, 10.3, 2000), rng.uniform(-3, 3.3, 2000)])
    face, out = query_many(road, xy)
    assert np.all(face >= 0)
    np.testing.assert_allclose(out[:, Q_Z], f(xy[:, 0], xy[:, 1]), rtol=0, atol=1e-9)
    k = 1.0 / math.sqrt(1 + 0.013 ** 2 + 0.021 ** 2)
    np.testing.assert_allclose(out[:, Q_NX:Q_NZ + 1], np.tile([0.013 * k, -0.021 * k, k], (2000, 1)),
                               rtol=0, atol=1e-12)


def test_points_off_the_mesh_return_minus_one():
    road = grid_mesh(lambda x, y: 0.0 * x, 0.0, 10.0, 0.0, 5.0, 1.0)
    pts = [(-0.01, 2.0), (10.01, 2.0), (5.0, -1e-3), (5.0, 5.001), (1e9, 0.0), (-1e9, -1e9),
           (float("nan"), 1.0), (1.0, float("nan")), (float("inf"), 1.0)]
    out = np.zeros(NQUERY)
    for x, y in pts:
        assert road_query(road, x, y, out) == -1, (x, y)
        assert out[Q_Z] == -np.inf and out[Q_MU] == 0.0
    assert road_query(road, 10.0, 5.0, out) >= 0            # corner of the mesh is on it


def brute_force_containing(vert, tri, xy, tol=1e-9):
    """For each point, the set of triangles containing it (barycentric >= -tol), by direct
    computation over all triangles."""
    a, b, c = vert[tri[:, 0], :2], vert[tri[:, 1], :2], vert[tri[:, 2], :2]

    def cross(o, p, q):
        return (p[..., 0] - o[..., 0]) * (q[..., 1] - o[..., 1]) - (p[..., 1] - o[..., 1]) * (q[..., 0] - o[..., 0])

    area = cross(a, b, c)
    res = []
    for p in xy:
        p = p[None, :]
        l0 = cross(p, b, c) / area
        l1 = cross(a, p, c) / area
        l2 = cross(a, b, p) / area
        res.append(set(np.flatnonzero((l0 >= -tol) & (l1 >= -tol) & (l2 >= -tol)).tolist()))
    return res


def test_grid_hash_agrees_with_brute_force():
    """An irregular mesh (Delaunay of random points, some triangles removed to make holes): for 4000
    random points the hashed lookup finds a triangle that contains the point exactly when one exists,
    with the height of the plane through that triangle."""
    rng = np.random.default_rng(4)
    xy = rng.uniform(0.0, 20.0, (400, 2))
    z = 0.1 * np.sin(xy[:, 0]) + 0.05 * xy[:, 1] + rng.normal(0, 0.01, 400)
    simp = Delaunay(xy).simplices
    cen = xy[simp].mean(axis=1)
    holes = (np.hypot(cen[:, 0] - 6, cen[:, 1] - 6) < 2.5) | (np.hypot(cen[:, 0] - 14, cen[:, 1] - 13) < 3)
    simp = simp[~holes]
    vert = np.column_stack([xy, z])
    road = make_mesh(vert, simp, rng.uniform(0.3, 1.2, simp.shape[0]), 0.01)
    q = rng.uniform(-1.0, 21.0, (4000, 2))
    face, out = query_many(road, q)
    truth = brute_force_containing(vert, road.tri, q)
    assert sum(len(t) > 0 for t in truth) > 2500 and sum(len(t) == 0 for t in truth) > 300
    for i in range(q.shape[0]):
        if not truth[i]:
            assert face[i] == -1, i
            continue
        assert face[i] in truth[i], i
        t = face[i]
        p = vert[road.tri[t]]
        n = np.cross(p[1] - p[0], p[2] - p[0])
        z_plane = p[0, 2] - (n[0] * (q[i, 0] - p[0, 0]) + n[1] * (q[i, 1] - p[0, 1])) / n[2]
        assert out[i, Q_Z] == pytest.approx(z_plane, abs=1e-12)
        assert out[i, Q_MU] == road.tri_mu[t]
