"""Survey-to-mesh pipeline (rtsim.road.survey): Sibson interpolation against a Voronoi-clipping
reference, linear precision, an error bound for smooth surfaces, the alpha-shape outline, and the
errors on bad survey files."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.road.model import make_mesh
from rtsim.road.query import NQUERY, Q_MU, Q_RR, Q_Z, query_points
from rtsim.road.survey import (ALPHA_RADIUS_FACTOR, AlphaShape, NaturalNeighbour, Survey, check_points,
                               read_survey, survey_to_mesh)


def jittered_grid(x1, y1, spacing, sigma, seed, x0=0.0, y0=0.0):
    rng = np.random.default_rng(seed)
    g = np.stack(np.meshgrid(np.arange(x0, x1 + 1e-9, spacing), np.arange(y0, y1 + 1e-9, spacing)), -1)
    g = g.reshape(-1, 2)
    return g + rng.normal(0.0, sigma, g.shape)


def make_survey(xy, z, mu=None, rr=None, name="test.csv"):
    xyz = np.column_stack([xy, z])
    return Survey(xyz=xyz, mu=mu, rolling_resistance=rr, source=name, lines=np.arange(len(z)) + 2)


def query_many(road, xy):
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    out = np.zeros((xy.shape[0], NQUERY))
    face = np.zeros(xy.shape[0], dtype=np.int64)
    query_points(road, xy, out, face)
    return face, out


def mesh_road(m):
    return make_mesh(m.vertices, m.triangles, m.tri_mu, m.tri_rr, cell_size=m.grid_spacing)


# ---------------------------------------------------------------- Sibson natural neighbours

def _clip(poly, a, b):
    """Part of the convex polygon closer to site a than to site b."""
    mid, nrm, out = 0.5 * (a + b), b - a, []
    for i in range(len(poly)):
        p, q = poly[i], poly[(i + 1) % len(poly)]
        dp, dq = (p - mid) @ nrm, (q - mid) @ nrm
        if dp <= 0:
            out.append(p)
        if (dp < 0) != (dq < 0) and dp != dq:
            out.append(p + (q - p) * dp / (dp - dq))
    return out


def _area(poly):
    if len(poly) < 3:
        return 0.0
    p = np.array(poly)
    return 0.5 * float(np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1]))


def sibson_reference(xy, q):
    """Sibson coordinates from their definition: the Voronoi cell of q among xy + {q} (a big box
    clipped by bisectors), and the part of it nearer each xy[i] than any other xy[j]."""
    cell = [q + np.array(c) for c in [(-1e3, -1e3), (1e3, -1e3), (1e3, 1e3), (-1e3, 1e3)]]
    for p in xy:
        cell = _clip(cell, q, p)
    total = _area(cell)
    w = np.zeros(len(xy))
    for i in range(len(xy)):
        part = cell
        for j in range(len(xy)):
            if j != i:
                part = _clip(part, xy[i], xy[j])
        w[i] = _area(part)
    return w / total


def test_sibson_weights_match_voronoi_definition():
    xy = jittered_grid(10.5, 6.0, 1.5, 0.25, seed=0)
    nn = NaturalNeighbour(xy, np.zeros(len(xy)))
    rng = np.random.default_rng(1)
    lo, hi = xy.min(axis=0) + 1.0, xy.max(axis=0) - 1.0
    for q in rng.uniform(lo, hi, (8, 2)):
        idx, w = nn.weights(q)
        full = np.zeros(len(xy))
        full[idx] = w
        np.testing.assert_allclose(full, sibson_reference(xy, q), rtol=0, atol=1e-10)


def test_sibson_linear_precision_and_data_points():
    xy = jittered_grid(30.0, 9.0, 1.5, 0.3, seed=2)
    f = lambda p: 12.0 + 0.011 * p[:, 0] - 0.7 * p[:, 1]  # noqa: E731
    nn = NaturalNeighbour(xy, f(xy))
    rng = np.random.default_rng(3)
    q = rng.uniform(xy.min(axis=0), xy.max(axis=0), (3000, 2))
    v = nn(q)
    inside = nn.tri.find_simplex(q) >= 0
    assert inside.sum() > 2500
    assert np.all(np.isnan(v[~inside]))                          # outside the convex hull
    np.testing.assert_allclose(v[inside], f(q[inside]), rtol=0, atol=1e-9)
    for qi in q[inside][:300]:                                   # coordinates: >= 0, sum 1, reproduce q
        idx, w = nn.weights(qi)
        assert w.min() >= -1e-14 and abs(w.sum() - 1.0) < 1e-12
        np.testing.assert_allclose(w @ xy[idx], qi, rtol=0, atol=1e-11)
    np.testing.assert_array_equal(nn(xy), f(xy))                 # data points exactly
    # on a hull edge the interpolant is linear along the edge
    hull = nn.tri.convex_hull[0]
    mid = 0.3 * xy[hull[0]] + 0.7 * xy[hull[1]]
    assert nn(mid[None, :])[0] == pytest.approx(0.3 * f(xy[[hull[0]]])[0] + 0.7 * f(xy[[hull[1]]])[0], abs=1e-9)


def test_smooth_surface_through_the_pipeline_within_derived_bound():
    """z = 0.2 sin(0.5 x) cos(0.7 y) + 0.01 x sampled at jittered survey points, meshed at h = 0.5 m.
    With Hessian norm <= M, the Sibson value at a node v errs by at most (M/2) sum_i w_i |x_i - v|^2
    (Taylor at v; the weights are >= 0, sum to 1 and reproduce v), and linear interpolation on a right
    grid triangle adds at most M h^2 / 4; so at any point of a triangle the error is bounded by the
    largest node bound of that triangle plus M h^2 / 4."""
    f = lambda x, y: 0.2 * np.sin(0.5 * x) * np.cos(0.7 * y) + 0.01 * x  # noqa: E731
    m = math.sqrt(0.05 ** 2 + 0.098 ** 2 + 2 * 0.07 ** 2)      # Frobenius bound of the Hessian
    xy = jittered_grid(24.0, 9.0, 1.5, 0.25, seed=4)
    h = 0.5
    mesh = survey_to_mesh(make_survey(xy, f(xy[:, 0], xy[:, 1])), h)
    nn = NaturalNeighbour(xy, f(xy[:, 0], xy[:, 1]))
    node_bound = np.empty(mesh.vertices.shape[0])
    for i, v in enumerate(mesh.vertices[:, :2]):
        idx, w = nn.weights(v)
        node_bound[i] = 0.5 * m * w @ ((xy[idx] - v) ** 2).sum(axis=1)
    node_err = np.abs(mesh.vertices[:, 2] - f(mesh.vertices[:, 0], mesh.vertices[:, 1]))
    assert np.all(node_err <= node_bound + 1e-12)
    road = mesh_road(mesh)
    rng = np.random.default_rng(5)
    q = rng.uniform(xy.min(axis=0), xy.max(axis=0), (4000, 2))
    face, out = query_many(road, q)
    on = face >= 0
    assert on.sum() > 3000
    bound = node_bound[road.tri[face[on]]].max(axis=1) + m * h * h / 4.0
    err = np.abs(out[on, Q_Z] - f(q[on, 0], q[on, 1]))
    assert np.all(err <= bound + 1e-12)
    assert err.max() > 0.1 * bound.max()


def test_linear_survey_gives_a_mesh_reproducing_it():
    xy = jittered_grid(40.0, 6.0, 1.5, 0.3, seed=6)
    f = lambda x, y: 5.0 + 0.015 * x - 0.008 * y  # noqa: E731
    road = mesh_road(survey_to_mesh(make_survey(xy, f(xy[:, 0], xy[:, 1])), 0.5))
    rng = np.random.default_rng(7)
    q = rng.uniform(xy.min(axis=0), xy.max(axis=0), (3000, 2))
    face, out = query_many(road, q)
    assert (face >= 0).sum() > 2000
    np.testing.assert_allclose(out[face >= 0, Q_Z], f(q[face >= 0, 0], q[face >= 0, 1]), rtol=0, atol=1e-9)


# ---------------------------------------------------------------- alpha shape

def l_shape_points(seed=8):
    """Jittered 1 m grid on the L [0, 20]^2 minus the notch (10, 20] x (10, 20]."""
    g = jittered_grid(20.0, 20.0, 1.0, 0.1, seed)
    return g[~((g[:, 0] > 10.3) & (g[:, 1] > 10.3))]


def test_alpha_shape_of_an_l_excludes_the_notch():
    xy = l_shape_points()
    alpha = AlphaShape(xy)
    nn = np.sort(np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)), axis=1)[:, 1]
    assert alpha.radius == pytest.approx(ALPHA_RADIUS_FACTOR * np.median(nn))
    assert len(alpha.loops) == 1
    notch = np.array([[15.0, 15.0], [12.0, 12.0], [11.5, 19.0], [19.0, 11.5], [13.0, 17.0]])
    assert not alpha.contains(notch).any()
    body = np.array([[5.0, 5.0], [15.0, 5.0], [5.0, 15.0], [9.0, 19.0], [19.0, 9.0], [1.0, 1.0]])
    assert alpha.contains(body).all()
    assert 280.0 < alpha.area < 305.0                  # the L is 300 m^2; the convex hull 400 m^2
    loop = xy[alpha.loops[0]]
    seg_area = 0.5 * np.sum(loop[:, 0] * np.roll(loop[:, 1], -1) - np.roll(loop[:, 0], -1) * loop[:, 1])
    assert seg_area == pytest.approx(alpha.area, rel=1e-9)      # counter-clockwise, encloses the shape
    perimeter = np.linalg.norm(loop - np.roll(loop, -1, axis=0), axis=1).sum()
    assert 75.0 < perimeter < 85.0                     # the L's is 80 m, its convex hull's 74 m
    # every contour edge belongs to a triangle of circumradius < r, so is shorter than 2 r
    assert np.linalg.norm(loop - np.roll(loop, -1, axis=0), axis=1).max() < 2.0 * alpha.radius
    # the mesh stays inside the outline: no triangle over the notch (beyond the chamfer an alpha
    # shape may cut across its inner corner, within a chord shorter than 2 r), none crossing the contour
    mesh = survey_to_mesh(make_survey(xy, np.zeros(len(xy))), 0.5)
    cen = mesh.vertices[mesh.triangles, :2].mean(axis=1)
    in_notch = (cen[:, 0] > 10.5) & (cen[:, 1] > 10.5)
    assert in_notch.sum() < 20
    assert np.hypot(cen[in_notch, 0] - 10.0, cen[in_notch, 1] - 10.0).max() < 2.0 * alpha.radius
    assert alpha.contains(cen).all()
    p = mesh.vertices[mesh.triangles, :2]
    for k in range(3):
        assert not alpha.crosses(p[:, k], p[:, (k + 1) % 3]).any()
    # and covers the body of the L away from the outline
    face, _ = query_many(mesh_road(mesh), body[:-1])
    assert np.all(face >= 0)


def test_alpha_radius_too_small_is_an_error():
    with pytest.raises(ConfigError, match="alpha-shape radius 0.1 m keeps no triangle"):
        AlphaShape(l_shape_points(), radius=0.1, source="s.csv")


# ---------------------------------------------------------------- per-triangle surface values

def test_per_triangle_friction_from_nearest_survey_point_or_defaults():
    xy = jittered_grid(20.0, 6.0, 1.5, 0.2, seed=9)
    z = np.zeros(len(xy))
    mu = np.where(xy[:, 0] < 10.0, 0.4, 1.1)
    rr = np.where(xy[:, 0] < 10.0, 0.02, 0.01)
    road = mesh_road(survey_to_mesh(make_survey(xy, z, mu, rr), 0.5))
    face, out = query_many(road, np.array([[3.0, 3.0], [17.0, 3.0]]))
    assert np.all(face >= 0)
    assert tuple(out[:, Q_MU]) == (0.4, 1.1) and tuple(out[:, Q_RR]) == (0.02, 0.01)
    plain = survey_to_mesh(make_survey(xy, z), 0.5, mu=0.7, rolling_resistance=0.013)
    assert np.all(plain.tri_mu == 0.7) and np.all(plain.tri_rr == 0.013)


# ---------------------------------------------------------------- bad survey files

def write(tmp_path, text, name="survey.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def grid_csv(n=16, extra_header="", extra=lambda i: ""):
    rows = [f"{i % 4 * 1.5},{i // 4 * 1.5},{0.01 * i}{extra(i)}" for i in range(n)]
    return "# test survey\nx,y,z" + extra_header + "\n" + "\n".join(rows) + "\n"


def test_reads_a_valid_survey_with_optional_columns(tmp_path):
    s = read_survey(write(tmp_path, grid_csv(extra_header=",mu,rolling_resistance",
                                             extra=lambda i: ",0.9,0.012")))
    assert s.xyz.shape == (16, 3) and s.mu.tolist() == [0.9] * 16 and s.lines[0] == 3
    s = read_survey(write(tmp_path, grid_csv()))
    assert s.mu is None and s.rolling_resistance is None


@pytest.mark.parametrize("text, expected", [
    (grid_csv(9), r"only 9 survey points; at least 10 are needed"),
    (grid_csv().replace("\n1.5,0.0,0.01\n", "\n1.5,0.0,nan\n"), r"line 4: column 'z' value 'nan' is not a finite number"),
    (grid_csv().replace("\n1.5,0.0,0.01\n", "\n1.5,0.0,abc\n"), r"line 4: column 'z' value 'abc' is not a number"),
    (grid_csv().replace("\n1.5,0.0,0.01\n", "\n0.0,0.0,0.01\n"), r"line 3 and line 4: duplicate survey points at x = 0, y = 0"),
    ("x,y,z\n" + "\n".join(f"{i},{2 * i + 1},0" for i in range(12)) + "\n", r"all 12 survey points lie on one line"),
    (grid_csv().replace("x,y,z", "x,y,height"), r"line 2: unknown column 'height'"),
    (grid_csv().replace("x,y,z", "x,y"), r"line 2: header lacks column 'z'"),
    (grid_csv().replace("\n1.5,0.0,0.01\n", "\n1.5,0.0\n"), r"line 4: 2 values, the header \(line 2\) names 3"),
    (grid_csv(extra_header=",mu", extra=lambda i: ",0.9" if i != 5 else ",2.5"), r"line 8: column 'mu' value 2.5 is out of range \(0, 2\]"),
    ("# only a comment\n", r"no header line"),
])
def test_bad_survey_files_raise_config_error(tmp_path, text, expected):
    p = write(tmp_path, text)
    with pytest.raises(ConfigError, match=expected) as exc:
        read_survey(p)
    msg = str(exc.value)
    assert msg.startswith(str(p) + ": ") and "\n" not in msg


def test_missing_survey_file(tmp_path):
    with pytest.raises(ConfigError, match="survey file not found"):
        read_survey(tmp_path / "nope.csv")


def test_check_points_rejects_nearly_collinear_points():
    t = np.linspace(0, 30, 20)
    xyz = np.column_stack([t, 0.5 * t + 1e-9 * np.sin(t), np.zeros(20)])
    with pytest.raises(ConfigError, match="lie on one line"):
        check_points(xyz, "pts")
