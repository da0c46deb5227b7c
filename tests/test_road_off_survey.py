"""The ground beyond a mesh road's survey (rtsim.road.model, "Off the survey"): the world does not end
where the survey does. Checked against the rule itself: the height of the nearest outline point, the
mesh's normal and surface values at the outline blending to level and the declared off-survey values
within OFF_SURVEY_BLEND, continuity across the outline (no jump in height or tyre load), and the
old rule (no ground, height -inf) for a mesh that declares none."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import Delaunay

from rtsim.errors import ConfigError
from rtsim.road import load_road
from rtsim.road.model import OFF_SURVEY_BAND, OFF_SURVEY_BLEND, make_mesh
from rtsim.road.query import CT_D, CT_MU, CT_NX, NCONTACT, NQUERY, Q_MU, Q_NX, Q_NZ, Q_RR, Q_Z, \
    road_query, wheel_contact

ROOT = Path(__file__).resolve().parent.parent
ROADS = ROOT / "configs" / "roads"
SLOPE = 0.02            # grade of the test mesh along x (rise over run)


def sloped_mesh(smooth: bool, ground: bool = True):
    """z = SLOPE x on x 0..10, y 0..5 (1 m grid), mu 0.9, rr 0.01; off-survey ground mu 0.5, rr 0.03."""
    gx, gy = np.meshgrid(np.arange(0.0, 10.0 + 1e-9, 1.0), np.arange(0.0, 5.0 + 1e-9, 1.0))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    tri = Delaunay(xy).simplices
    return make_mesh(np.column_stack([xy, SLOPE * xy[:, 0]]), tri, 0.9, 0.01, cell_size=1.0,
                     smooth_normals=smooth, off_survey_mu=0.5 if ground else None, off_survey_rr=0.03)


def q(road, x, y):
    out = np.zeros(NQUERY)
    face = road_query(road, float(x), float(y), out)
    return face, out


@pytest.mark.parametrize("smooth", [False, True])
def test_ground_beyond_the_outline_follows_the_rule(smooth):
    road = sloped_mesh(smooth)
    # beyond the side y = 5: the height of the outline points within the band, whose horizontal
    # distance from the foot (x, 5) is at most r sqrt((1 + band)^2 - 1), so within SLOPE times that of
    # the foot's height SLOPE x; level and off-survey values once farther than the blend distance
    spread = math.sqrt((1.0 + OFF_SURVEY_BAND) ** 2 - 1.0)
    for x in (0.5, 3.3, 9.9):
        for r in (1e-6, 0.3, OFF_SURVEY_BLEND, 50.0):
            face, out = q(road, x, 5.0 + r)
            assert face == -1
            assert abs(out[Q_Z] - SLOPE * x) <= SLOPE * r * spread + 1e-12
            w = min(r / OFF_SURVEY_BLEND, 1.0) ** 2 * (3.0 - 2.0 * min(r / OFF_SURVEY_BLEND, 1.0))
            assert out[Q_MU] == pytest.approx(0.9 * (1 - w) + 0.5 * w, abs=1e-12)
            assert out[Q_RR] == pytest.approx(0.01 * (1 - w) + 0.03 * w, abs=1e-12)
            assert np.linalg.norm(out[Q_NX:Q_NZ + 1]) == pytest.approx(1.0, abs=1e-12)
            if r >= OFF_SURVEY_BLEND:
                np.testing.assert_allclose(out[Q_NX:Q_NZ + 1], [0.0, 0.0, 1.0], atol=1e-15)
    # beyond the end x = 10, where the outline is level across: the end's height
    assert q(road, 10.5, 2.5)[1][Q_Z] == pytest.approx(SLOPE * 10.0, abs=1e-12)
    # anywhere: within the outline's range of heights
    for x, y in ((25.0, 2.0), (-7.0, -3.0), (1e7, 1e7), (-1e7, 3.0)):
        assert -1e-12 <= q(road, x, y)[1][Q_Z] <= SLOPE * 10.0 + 1e-12


@pytest.mark.parametrize("smooth", [False, True])
def test_no_jump_across_the_outline(smooth):
    """Height, normal, friction and rolling resistance just inside and just outside the outline agree
    to first order in the step (a C0 surface with C0 normals)."""
    road = sloped_mesh(smooth)
    eps = 1e-7
    for x, y, dx, dy in ((10.0, 2.4, 1, 0), (4.6, 5.0, 0, 1), (0.0, 1.7, -1, 0), (7.2, 0.0, 0, -1)):
        fi, inside = q(road, x - dx * eps, y - dy * eps)
        fo, outside = q(road, x + dx * eps, y + dy * eps)
        assert fi >= 0 and fo == -1
        np.testing.assert_allclose(outside, inside, atol=1e-6)


def test_wheel_rolling_off_the_end_keeps_its_load():
    """A wheel at constant height rolled over the end of a level mesh: its deflection, normal and
    friction change continuously; past the blend it stands on level ground at the off-survey mu."""
    gx, gy = np.meshgrid(np.arange(0.0, 10.0 + 1e-9, 0.5), np.arange(-2.0, 2.0 + 1e-9, 0.5))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    road = make_mesh(np.column_stack([xy, np.full(len(xy), 1.5)]), Delaunay(xy).simplices, 1.0, 0.0,
                     cell_size=0.5, smooth_normals=True, off_survey_mu=0.6)
    r0, zc = 0.3, 1.5 + 0.28
    ct = np.zeros(NCONTACT)
    d, mu = [], []
    for x in np.linspace(8.0, 13.0, 501):
        wheel_contact(road, float(x), 0.0, zc, 0.0, 1.0, 0.0, r0, ct)
        d.append(ct[CT_D])
        mu.append(ct[CT_MU])
        np.testing.assert_allclose(ct[CT_NX:CT_NX + 3], [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(d, 0.02, atol=1e-12)
    mu = np.array(mu)
    assert mu[0] == 1.0 and mu[-1] == pytest.approx(0.6, abs=1e-12)
    assert np.abs(np.diff(mu)).max() < 0.4 * 1.5 * 0.01 / OFF_SURVEY_BLEND + 1e-12   # smoothstep slope


def test_mesh_without_ground_is_off_the_road_beyond_it():
    road = sloped_mesh(True, ground=False)
    face, out = q(road, 12.0, 2.0)
    assert face == -1 and out[Q_Z] == -math.inf and out[Q_MU] == 0.0
    ct = np.zeros(NCONTACT)
    assert wheel_contact(road, 12.0, 2.0, 0.2, 0.0, 1.0, 0.0, 0.3, ct) == -1 and ct[CT_D] == -math.inf


def test_non_finite_points_have_no_ground():
    road = sloped_mesh(True)
    for x, y in ((math.nan, 1.0), (1.0, math.nan), (math.inf, 1.0)):
        face, out = q(road, x, y)
        assert face == -1 and out[Q_Z] == -math.inf


def test_campus_ground_has_no_step_anywhere_beyond_the_survey():
    """Lines 1.25 cm apart across the whole campus and 8 m around it: between neighbouring points the
    height changes by no more than the surface's slopes allow (below 5 % here), also where the nearest
    outline edge changes (a concave outline; the nearest edge alone gave steps up to 11 cm)."""
    road = load_road(ROADS / "campus.toml")
    h = 30.0 / 2400
    worst = 0.0
    for x0 in np.arange(-14.0, 86.0, 0.5):
        xy = np.column_stack([np.full(2401, x0), np.linspace(-15.0, 15.0, 2401)])
        out = np.zeros((len(xy), NQUERY))
        face = np.zeros(len(xy), dtype=np.int64)
        from rtsim.road.query import query_points
        query_points(road, xy, out, face)
        assert np.all(np.isfinite(out)), x0
        worst = max(worst, float(np.abs(np.diff(out[:, Q_Z])).max()))
    assert worst < 0.05 * h, worst


def test_campus_ground_continues_past_the_end_of_the_lane():
    """The campus lane ends near x = 78 m: beyond it the ground is at the height of the lane's end,
    level, with the declared off-survey friction (configs/roads/campus.toml)."""
    road = load_road(ROADS / "campus.toml")
    f_in, inside = q(road, 77.0, 0.0)
    f_out, far = q(road, 90.0, 0.0)
    assert f_in >= 0 and f_out == -1
    assert abs(far[Q_Z] - inside[Q_Z]) < 0.02 * 2.0        # the lane's slopes are below 2 %
    np.testing.assert_allclose(far[Q_NX:Q_NZ + 1], [0.0, 0.0, 1.0], atol=1e-15)
    assert far[Q_MU] == 0.6 and far[Q_RR] == 0.02


@pytest.mark.parametrize("key, value, expected", [
    ("off_survey_friction", "0.0", r"off_survey_friction = 0.0: out of range \(allowed 0 < off_survey_friction <= 2"),
    ("off_survey_friction", "2.5", r"off_survey_friction = 2.5: out of range"),
    ("off_survey_rolling_resistance", "0.2", r"off_survey_rolling_resistance = 0.2: out of range \(allowed 0 <= "),
])
def test_off_survey_keys_are_validated(tmp_path, key, value, expected):
    p = tmp_path / "road.toml"
    survey = (ROADS / "campus_survey.csv").resolve()
    p.write_text(f'type = "mesh"\nsurvey = "{survey}"\ngrid_spacing = 0.5\n{key} = {value}\n')
    with pytest.raises(ConfigError, match=expected):
        load_road(p)
