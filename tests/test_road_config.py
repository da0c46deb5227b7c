"""Road configuration files (configs/roads/*.toml, rtsim.road.config.load_road): the shipped roads
and the errors on bad files."""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.road import ROAD_MESH, ROAD_PLANE, load_road
from rtsim.road.model import TG_NZ
from rtsim.road.query import NQUERY, Q_MU, Q_NX, Q_NZ, Q_RR, Q_Z, query_points
from rtsim.road.survey import read_survey

ROOT = Path(__file__).resolve().parent.parent
ROADS = ROOT / "configs" / "roads"


def query_many(road, xy):
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    out = np.zeros((xy.shape[0], NQUERY))
    face = np.zeros(xy.shape[0], dtype=np.int64)
    query_points(road, xy, out, face)
    return face, out


@pytest.fixture(scope="module")
def campus():
    return load_road(ROADS / "campus.toml")


def test_flat_and_grade_configs():
    xy = np.array([[0.0, 0.0], [12.0, -3.0], [-40.0, 7.0]])
    face, out = query_many(load_road(ROADS / "flat.toml"), xy)
    assert np.all(face == 0) and np.all(out[:, Q_Z] == 0.0) and np.all(out[:, Q_NZ] == 1.0)
    assert np.all(out[:, Q_MU] == 1.0) and np.all(out[:, Q_RR] == 0.0)
    road = load_road(ROADS / "grade_5pct.toml")
    assert road.ipar[0] == ROAD_PLANE
    face, out = query_many(road, xy)
    np.testing.assert_allclose(out[:, Q_Z], 0.05 * xy[:, 0], atol=1e-15)
    np.testing.assert_allclose(out[:, Q_NX], -0.05 / math.sqrt(1.0025), atol=1e-16)


def test_campus_survey_is_the_documented_synthetic_one(tmp_path):
    path = ROADS / "campus_survey.csv"
    assert path.read_text().startswith("# SYNTHETIC survey")
    s = read_survey(path)
    assert 280 <= s.xyz.shape[0] <= 320
    nn = np.sort(np.hypot(*(s.xyz[:, None, :2] - s.xyz[None, :, :2]).transpose(2, 0, 1)), axis=1)[:, 1]
    assert 1.2 < np.median(nn) < 1.6                      # points about 1.5 m apart
    assert np.ptp(s.xyz[:, 0]) > 80.0 and 5.0 < np.ptp(s.xyz[s.xyz[:, 1] < 3.5, 1]) < 6.5
    # the shipped file is exactly what the committed generator writes (fixed seed)
    spec = importlib.util.spec_from_file_location("make_campus_survey", ROOT / "tools" / "make_campus_survey.py")
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    out = tmp_path / "campus.csv"
    gen.main(["make_campus_survey.py", str(out)])
    assert out.read_text() == path.read_text()


def test_campus_mesh_covers_the_straight_line_path_with_gentle_slopes(campus):
    assert campus.ipar[0] == ROAD_MESH
    # the straight-line run, x 5..70, y -1.5..1.5, and beyond: from x = -3 (a car at the road-frame
    # origin, configs/scenarios/straight_line.toml, with its rear overhang) to x = 74
    xs, ys = np.meshgrid(np.linspace(-3.0, 74.0, 1541), np.linspace(-1.5, 1.5, 61))
    face, out = query_many(campus, np.column_stack([xs.ravel(), ys.ravel()]))
    assert np.all(face >= 0)
    slope = np.sqrt(1.0 / campus.tri_geom[:, TG_NZ] ** 2 - 1.0)
    assert slope.max() < 0.02                              # every triangle, not only on the path
    assert np.all(out[:, Q_MU] == 1.0) and np.all(out[:, Q_RR] == 0.0)   # the TOML defaults
    # the mesh passes close to the survey points it covers (exact at grid nodes + linear in between)
    s = read_survey(ROADS / "campus_survey.csv")
    face, out = query_many(campus, s.xyz[:, :2])
    on = face >= 0
    assert on.sum() > 150
    assert np.abs(out[on, Q_Z] - s.xyz[on, 2]).max() < 0.005
    # and is off the road away from the survey
    face, _ = query_many(campus, np.array([[-8.0, 0.0], [40.0, 5.0], [80.0, 0.0], [40.0, -6.0]]))
    assert np.all(face == -1)


def write(tmp_path, text, name="road.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, expected", [
    ('type = "grade"\ngrade = 0.8\n', r"grade = 0.8: out of range \(allowed -0.5 <= grade <= 0.5; rise over run"),
    ('type = "grade"\n', r"grade: missing \(required; rise over run"),
    ('type = "flat"\nmu = 0.0\n', r"mu = 0.0: out of range \(allowed 0 < mu <= 2"),
    ('type = "flat"\nrolling_resistance = -0.1\n', r"rolling_resistance = -0.1: out of range \(allowed 0 <= rolling_resistance <= 0.1"),
    ('type = "flat"\nheigth = 1.0\n', r"heigth = 1.0: unknown key \(allowed: type, height, mu, rolling_resistance\)"),
    ('type = "hill"\n', r"type = 'hill': not one of 'flat', 'grade', 'mesh'"),
    ('height = 1.0\n', r"type: missing"),
    ('type = "mesh"\nsurvey = "campus_survey.csv"\ngrid_spacing = "fine"\n', r"grid_spacing = 'fine': must be a number"),
    ('type = "mesh"\nsurvey = "campus_survey.csv"\ngrid_spacing = 0.01\n', r"grid_spacing = 0.01: out of range \(allowed 0.05 <= grid_spacing <= 10"),
    ('type = "mesh"\nsurvey = "nowhere.csv"\ngrid_spacing = 0.5\n', r"survey = 'nowhere.csv': file not found"),
    ('type = "grade"\ngrade = 0.1\norigin = [0.0, 1.0]\n', r"origin\[2\]: missing"),
    ('type = "flat"\nheight = \n', r"not valid TOML: .*line 2"),
])
def test_bad_road_files_raise_config_error(tmp_path, text, expected):
    p = write(tmp_path, text)
    with pytest.raises(ConfigError, match=expected) as exc:
        load_road(p)
    msg = str(exc.value)
    assert msg.startswith(str(p) + ": ") and "\n" not in msg


def test_survey_errors_name_the_survey_file(tmp_path):
    write(tmp_path, "x,y,z\n0,0,0\n1,0,0\n0,1,0\n", name="tiny.csv")
    p = write(tmp_path, 'type = "mesh"\nsurvey = "tiny.csv"\ngrid_spacing = 0.5\n')
    with pytest.raises(ConfigError, match=r"tiny.csv: only 3 survey points; at least 10 are needed"):
        load_road(p)


def test_missing_road_file(tmp_path):
    with pytest.raises(ConfigError, match="none.toml: cannot read: no such file"):
        load_road(tmp_path / "none.toml")
