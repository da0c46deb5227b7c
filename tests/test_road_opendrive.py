"""OpenDRIVE roads (rtsim.road.opendrive): the reader's geometry against analytic results (an arc's radius,
a clothoid's curvature rate and position, a superelevated curve's cross slope, polynomials), the meshed
surface against the analytic surface, per-lane friction in the contact query, the lane centre lines and
the road marks, and one-line errors for bad files. The test files are written here (tests/xodr_writer.py).
The car on such a road: tests/test_road_opendrive_car.py."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

import xodr_writer as W
from rtsim.errors import ConfigError
from rtsim.road.config import load_road, read_opendrive_of
from rtsim.road.opendrive import (lane_borders, lane_centre_line, mesh_opendrive, read_opendrive,
                                  reference_line, road_markings, surface_point)
from rtsim.road.query import NQUERY, Q_MU, Q_NZ, Q_Z, road_query


def _one(tmp_path, geometry: str, length: float, lateral: str = "", elevation: str = ""):
    p = W.write(tmp_path / "one.xodr", W.document(W.road_xml(geometry, length, W.lanes_xml(), elevation, lateral)))
    return read_opendrive(p).road()


def _heading_integral(x0, y0, h0, heading, u, n=400_000):
    """Position along a curve of heading h0 + heading(v) at arc lengths u: a fine midpoint rule, independent
    of the reader's closed forms."""
    du = u.max() / n
    v = (np.arange(n) + 0.5) * du
    th = h0 + heading(v)
    cx = np.concatenate(([0.0], np.cumsum(np.cos(th)) * du))
    cy = np.concatenate(([0.0], np.cumsum(np.sin(th)) * du))
    grid = np.arange(n + 1) * du
    return x0 + np.interp(u, grid, cx), y0 + np.interp(u, grid, cy)


def test_an_arc_has_its_radius_and_turns_at_its_curvature(tmp_path):
    k, x0, y0, h0, L = -1.0 / 35.0, 12.0, -4.0, 0.7, 80.0     # turning right
    road = _one(tmp_path, f'<geometry s="0" x="{x0}" y="{y0}" hdg="{h0}" length="{L}"><arc curvature="{k}"/></geometry>', L)
    s = np.linspace(0.0, L, 41)
    x, y, h = reference_line(road, s)
    cx, cy = x0 - math.sin(h0) / k, y0 + math.cos(h0) / k      # the centre, on the left normal at 1/k
    assert np.max(np.abs(np.hypot(x - cx, y - cy) - 35.0)) < 1e-9
    assert np.max(np.abs(h - (h0 + k * s))) < 1e-12


@pytest.mark.parametrize("k0,k1", [(0.0, 0.02), (0.01, 0.03), (0.02, -0.015), (-0.004, -0.03), (0.01, 0.01 + 1e-10)])
def test_a_clothoid_changes_its_curvature_at_its_rate(tmp_path, k0, k1):
    L, x0, y0, h0 = 60.0, 5.0, 3.0, -0.4
    road = _one(tmp_path, f'<geometry s="0" x="{x0}" y="{y0}" hdg="{h0}" length="{L}">'
                          f'<spiral curvStart="{k0}" curvEnd="{k1}"/></geometry>', L)
    c = (k1 - k0) / L
    s = np.linspace(0.0, L, 601)
    x, y, h = reference_line(road, s)
    xr, yr = _heading_integral(x0, y0, h0, lambda v: k0 * v + 0.5 * c * v * v, s)
    assert np.max(np.hypot(x - xr, y - yr)) < 1e-6
    assert np.max(np.abs(h - (h0 + k0 * s + 0.5 * c * s * s))) < 1e-12
    # curvature from the points themselves (circle through three neighbours) rises at the rate c
    a, b, q = np.stack([x[:-2], y[:-2]], 1), np.stack([x[1:-1], y[1:-1]], 1), np.stack([x[2:], y[2:]], 1)
    cross = (b - a)[:, 0] * (q - a)[:, 1] - (b - a)[:, 1] * (q - a)[:, 0]
    kappa = 2.0 * cross / (np.linalg.norm(b - a, axis=1) * np.linalg.norm(q - b, axis=1) * np.linalg.norm(q - a, axis=1))
    rate = np.polyfit(s[1:-1], kappa, 1)[0]
    assert rate == pytest.approx(c, rel=1e-4, abs=1e-9)


def test_polynomial_geometries_follow_their_curves_by_arc_length(tmp_path):
    # poly3 v = 0.002 u^2 + 1e-5 u^3 from (1, 2) heading 0.3; paramPoly3 a half-parabola over p in [0, 1]
    L = 50.0
    poly = f'<geometry s="0" x="1" y="2" hdg="0.3" length="{L}"><poly3 a="0" b="0" c="0.002" d="1e-5"/></geometry>'
    road = _one(tmp_path, poly, L)
    s = np.linspace(0.0, L, 51)
    x, y, h = reference_line(road, s)
    seg = np.hypot(np.diff(x), np.diff(y))
    uu = np.linspace(0.0, 60.0, 600_001)                     # arc length of the curve by fine chords
    vv = 0.002 * uu ** 2 + 1e-5 * uu ** 3
    arc = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(uu), np.diff(vv)))))
    u_at = np.interp(s, arc, uu)
    v_at = 0.002 * u_at ** 2 + 1e-5 * u_at ** 3
    xr = 1 + math.cos(0.3) * u_at - math.sin(0.3) * v_at
    yr = 2 + math.sin(0.3) * u_at + math.cos(0.3) * v_at
    assert np.max(np.hypot(x - xr, y - yr)) < 1e-6
    assert np.all(seg <= 1.0 + 1e-9) and np.sum(seg) == pytest.approx(L, abs=1e-4)
    assert np.max(np.abs(h - (0.3 + np.arctan(0.004 * u_at + 3e-5 * u_at ** 2)))) < 1e-6
    # paramPoly3, normalized: u = 40 p, v = 10 p^2 (a parabola v = u^2 / 160)
    pp = ('<geometry s="0" x="0" y="0" hdg="0" length="{L}"><paramPoly3 aU="0" bU="40" cU="0" dU="0" '
          'aV="0" bV="0" cV="10" dV="0" pRange="normalized"/></geometry>')
    uu = np.linspace(0.0, 40.0, 400_001)
    vv = uu ** 2 / 160.0
    arc = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(uu), np.diff(vv)))))
    road = _one(tmp_path, pp.format(L=float(arc[-1])), float(arc[-1]))
    s = np.linspace(0.0, arc[-1], 33)
    x, y, _ = reference_line(road, s)
    u_at = np.interp(s, arc, uu)
    assert np.max(np.hypot(x - u_at, y - u_at ** 2 / 160.0)) < 1e-6


def test_the_superelevated_curve_has_its_cross_slope(tmp_path):
    road = read_opendrive(W.write(tmp_path / "bar.xodr", W.bar_road())).road()
    for s, slope in ((30.0, 0.0), (W.LINE + W.SPIRAL + 20.0, -W.CROSS_SLOPE), (W.LINE + W.SPIRAL + 150.0, -W.CROSS_SLOPE),
                     (W.LINE + 0.5 * W.SPIRAL, -math.tan(0.5 * math.atan(W.CROSS_SLOPE)))):
        t = np.array([-7.0, 0.0, 7.0])
        p = surface_point(road, np.full(3, s), t)
        horiz = np.hypot(*(p[2, :2] - p[0, :2]))
        assert (p[2, 2] - p[0, 2]) / horiz == pytest.approx(slope, abs=1e-12)
        # the cross section is perpendicular to the reference line, the lane width measured along it
        assert np.linalg.norm(p[2] - p[0]) == pytest.approx(14.0, abs=1e-12)
        assert p[1, 2] == pytest.approx(W.GRADE * s, abs=1e-12)
    # the arc's lane borders are concentric circles: radius R - t cos(roll)
    s = np.linspace(W.LINE + W.SPIRAL, W.LINE + W.SPIRAL + W.ARC, 50)
    x, y, h = reference_line(road, s)
    cx, cy = x[0] - math.sin(h[0]) * W.RADIUS, y[0] + math.cos(h[0]) * W.RADIUS
    for t in (-7.0, -3.5, 3.5, 7.0):
        p = surface_point(road, s, np.full_like(s, t))
        r = np.hypot(p[:, 0] - cx, p[:, 1] - cy)
        assert np.max(np.abs(r - (W.RADIUS - t * math.cos(math.atan(W.CROSS_SLOPE))))) < 1e-9


def _query(road, x, y):
    out = np.zeros(NQUERY)
    res = np.zeros((len(x), NQUERY))
    for i in range(len(x)):
        road_query(road, float(x[i]), float(y[i]), out)
        res[i] = out
    return res


def test_the_mesh_is_within_5_mm_of_the_analytic_surface(tmp_path):
    """The bar: random points of the road (all lanes, the whole length, including the superelevation ramp),
    the mesh's height under each against the analytic surface's: at most 5 mm."""
    xodr = W.write(tmp_path / "bar.xodr", W.bar_road())
    road = load_road(W.road_toml(tmp_path / "bar.toml", xodr))
    odr = read_opendrive(xodr)
    rng = np.random.default_rng(7)
    s = rng.uniform(0.0, odr.road().length, 4000)
    t = rng.uniform(-6.99, 6.99, 4000)
    p = surface_point(odr.road(), s, t)
    q = _query(road, p[:, 0], p[:, 1])
    err = np.abs(q[:, Q_Z] - p[:, 2])
    print(f"mesh height error: max {1000 * err.max():.3f} mm, mean {1000 * err.mean():.3f} mm")
    assert err.max() <= 0.005
    # the surface normal of the banked arc: tilted by the 4 % cross slope (nz = 1 / sqrt(1 + g^2 + 0.04^2))
    arc = s > W.LINE + W.SPIRAL + 1.0
    assert np.allclose(q[arc, Q_NZ], 1.0 / math.sqrt(1.0 + W.GRADE ** 2 + W.CROSS_SLOPE ** 2), atol=2e-4)


def test_each_lane_has_its_friction_in_the_contact_query(tmp_path):
    xodr = W.write(tmp_path / "bar.xodr", W.bar_road({-1: 0.35, -2: 1.2, 1: 0.8}))
    road = load_road(W.road_toml(tmp_path / "bar.toml", xodr, mu=0.95))
    odr = read_opendrive(xodr).road()
    s = np.linspace(1.0, odr.length - 1.0, 200)
    for lane, mu in ((-1, 0.35), (-2, 1.2), (1, 0.8), (2, 0.95)):
        a, b = lane_borders(odr, odr.sections[0], s)[lane]
        for frac in (0.1, 0.5, 0.9):
            p = surface_point(odr, s, a + frac * (b - a))
            assert np.all(_query(road, p[:, 0], p[:, 1])[:, Q_MU] == mu)
    # beyond the outer border, the ground takes the off-road friction (the config's default 0.6) within 1 m
    p = surface_point(odr, s, np.full_like(s, -9.5))
    assert np.allclose(_query(road, p[:, 0], p[:, 1])[:, Q_MU], 0.6)


def test_lane_centre_lines_run_in_the_direction_of_travel(tmp_path):
    odr = read_opendrive(W.write(tmp_path / "bar.xodr", W.bar_road())).road()
    right = lane_centre_line(odr, -1, 0.5)
    left = lane_centre_line(odr, 1, 0.5)
    assert right[0, :2] == pytest.approx((0.0, -1.75)) and left[-1, :2] == pytest.approx((0.0, 1.75))
    assert right[1, 0] > right[0, 0] and left[-2, 0] > left[-1, 0]
    # on the arc, the right lane's centre is at R + 1.75 cos(roll) from the centre of the circle
    s = np.linspace(W.LINE + W.SPIRAL, odr.length, 20)
    x, y, h = reference_line(odr, s)
    cx, cy = x[0] - math.sin(h[0]) * W.RADIUS, y[0] + math.cos(h[0]) * W.RADIUS
    tail = right[right[:, 1] > y[1]]
    r = np.hypot(tail[:, 0] - cx, tail[:, 1] - cy)
    assert np.max(np.abs(r - (W.RADIUS + 1.75 * math.cos(math.atan(W.CROSS_SLOPE))))) < 1e-9
    with pytest.raises(ConfigError, match="no lane -3"):
        lane_centre_line(odr, -3)


def test_road_marks_lie_on_the_lane_borders(tmp_path):
    odr = read_opendrive(W.write(tmp_path / "bar.xodr", W.bar_road()))
    marks = road_markings(odr)
    v, f = marks["vertices"], marks["triangles"]
    assert len(f) == len(marks["colour"]) > 0 and f.max() < len(v)
    road = odr.road()
    mesh = mesh_opendrive(odr)
    assert np.isin(np.unique(mesh.tri_lane), [-2, -1, 1, 2]).all()
    # every mark vertex is 6 cm (half its width) from one of the five borders t = 0, +-3.5, +-7 (1 cm spacing)
    s = np.arange(0.0, road.length, 0.01)
    pts = {t: surface_point(road, s, np.full_like(s, t)) for t in (-7.0, -3.5, 0.0, 3.5, 7.0)}
    trees = {t: cKDTree(p[:, :2]) for t, p in pts.items()}
    found = [tree.query(v[:, :2]) for tree in trees.values()]
    d = np.array([q[0] for q in found])
    near = np.argmin(d, axis=0)
    assert np.max(np.abs(d.min(axis=0) - 0.06)) < 0.002
    # 1 cm above the border's point beside it (the drawing's lift)
    z_border = np.array([list(pts.values())[k][found[k][1][i], 2] for i, k in enumerate(near)])
    assert np.max(np.abs(v[:, 2] - z_border - 0.01)) < 1e-3
    # broken lines: the inner lane borders carry 3 m dashes every 9 m, the edges and the centre line are solid
    s_probe = np.arange(0.5, road.length - 0.5, 0.25)

    def covered(t):
        mark = cKDTree(v[trees[t].query(v[:, :2])[0] < 0.07, :2])
        # a probe within 0.3 m of a mark's vertex (0.5 m apart along the mark) is on the mark
        return np.mean(mark.query(surface_point(road, s_probe, np.full_like(s_probe, t))[:, :2])[0] < 0.3)
    assert min(covered(0.0), covered(7.0), covered(-7.0)) > 0.99
    dash = (3.0 + 2 * 0.3) / 9.0                # a dash and the probes' reach at its ends, every 9 m
    assert covered(-3.5) == pytest.approx(dash, abs=0.03) and covered(3.5) == pytest.approx(dash, abs=0.03)


@pytest.mark.parametrize("text,match", [
    ('<OpenDRIVE><road id="1" length="10"><planView><geometry s="0" x="0" y="0" hdg="0" length="10"><clothoid/>'
     '</geometry></planView><lanes/></road></OpenDRIVE>', "unknown geometry <clothoid>"),
    ('<OpenDRIVE><road id="1" length="10"><planView><geometry s="0" x="0" y="zero" hdg="0" length="10"><line/>'
     '</geometry></planView><lanes/></road></OpenDRIVE>', "not a number"),
    ('<OpenDRIVE><road id="1" length="10"></road></OpenDRIVE>', "no <planView><geometry>"),
    ('<OpenDRIVE>', "not XML"),
    ('<Other/>', "expected <OpenDRIVE>"),
])
def test_a_bad_file_gets_one_line_naming_it(tmp_path, text, match):
    p = W.write(tmp_path / "bad.xodr", text)
    with pytest.raises(ConfigError, match=match) as err:
        read_opendrive(p)
    assert str(p) in str(err.value) and "\n" not in str(err.value)


def test_a_road_config_names_a_missing_file_and_a_folding_curve(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_road(W.road_toml(tmp_path / "r.toml", tmp_path / "absent.xodr"))
    tight = W.document(W.road_xml('<geometry s="0" x="0" y="0" hdg="0" length="20"><arc curvature="0.2"/></geometry>',
                                  20.0, W.lanes_xml()))
    with pytest.raises(ConfigError, match="folds over"):
        load_road(W.road_toml(tmp_path / "t.toml", W.write(tmp_path / "t.xodr", tight)))
    with pytest.raises(ConfigError, match="an OpenDRIVE road is needed"):
        read_opendrive_of(W.write(tmp_path / "flat.toml", 'type = "flat"\n'))
