"""The X-by-wire car on an OpenDRIVE road (rtsim.road.opendrive): the path follower keeps it on a lane's centre
line through the straight, the clothoid and the superelevated arc at 60 km/h, and a friction change between
lanes shows in its tyre forces (split-mu braking). Test files written by tests/xodr_writer.py."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import xodr_writer as W
from drivers.scenario import load_scenario
from rtsim.errors import ConfigError
from rtsim.road.config import read_opendrive_of
from rtsim.road.opendrive import lane_centre_line, reference_line
from rtsim.vehicle.offline import prepare, run

ROOT = Path(__file__).resolve().parent.parent
XBW = ROOT / "configs" / "vehicles" / "xbw.toml"
V60 = 60.0 / 3.6


def _scenario(tmp_path, road: Path, body: str, duration: float, y0: float) -> Path:
    p = tmp_path / "sc.toml"
    p.write_text(f'name = "sc"\ndescription = "test"\nvehicle = "{XBW}"\nroad = "{road}"\nduration = {duration}\n'
                 f'[initial]\nspeed = {V60}\nx = 0.0\ny = {y0}\n{body}')
    return p


def _distance_to(polyline: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Horizontal distance (m) of each point (x, y) to the polyline (n, 2)."""
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    out = np.empty(len(x))
    for i in range(len(x)):
        u = np.clip(((x[i] - a[:, 0]) * ab[:, 0] + (y[i] - a[:, 1]) * ab[:, 1]) / np.sum(ab * ab, axis=1), 0.0, 1.0)
        out[i] = np.min(np.hypot(a[:, 0] + u * ab[:, 0] - x[i], a[:, 1] + u * ab[:, 1] - y[i]))
    return out


def test_the_car_follows_a_lanes_centre_line_at_60_kmh_within_0_2_m(tmp_path):
    """The bar: lane -1's centre line through line, clothoid and the 4 % banked arc of radius 100 m; the car's
    centre of mass stays within 0.2 m of it (measured from the recorded positions, against the analytic
    centre line sampled every 5 cm)."""
    xodr = W.write(tmp_path / "bar.xodr", W.bar_road())
    road = W.road_toml(tmp_path / "bar.toml", xodr)
    body = (f'[inputs.speed_follower]\ntime = [0.0]\nspeed = [{V60}]\n'
            '[inputs.path_follower]\nlane = -1\nmethod = "pure_pursuit"\n')
    sc = load_scenario(_scenario(tmp_path, road, body, 14.0, -1.75))
    sim, sc = prepare(None, sc)
    res = run(sim, sc)
    assert res.fault is None
    x, y, v = res.column("pos_x"), res.column("pos_y"), res.column("speed")
    centre = lane_centre_line(read_opendrive_of(road).road(), -1, 0.05)[:, :2]
    err = _distance_to(centre, x, y)
    odr = read_opendrive_of(road).road()
    xa, ya, ha = (float(q[0]) for q in reference_line(odr, W.LINE + W.SPIRAL + 10.0))   # 10 m into the arc
    on_arc = (x - xa) * math.cos(ha) + (y - ya) * math.sin(ha) > 0.0                  # beyond it
    print(f"lane centre line: max distance {err.max():.3f} m, speed {v.min() * 3.6:.1f}..{v.max() * 3.6:.1f} km/h")
    assert err.max() <= 0.2
    assert np.all(np.abs(v - V60) < 0.05 * V60)                      # at 60 km/h throughout
    assert np.count_nonzero(on_arc) > 200 and y[-1] > 60.0           # and it drove into the arc
    # in the arc, its path's radius (speed over yaw rate) is the lane centre's
    r = v[on_arc] / np.abs(res.column("yaw_rate")[on_arc])
    assert np.median(r) == pytest.approx(W.RADIUS + 1.75, rel=0.03)


def test_a_friction_change_between_lanes_shows_in_the_tyre_forces(tmp_path):
    """Split mu: the car straddles the border of lane -1 (friction 1.0) and lane -2 (friction 0.3) and brakes
    hard on the straight: the right tyres (on lane -2) carry at most 0.3 of their load as braking force, the
    left ones much more."""
    xodr = W.write(tmp_path / "split.xodr", W.bar_road({-1: 1.0, -2: 0.3}))
    road = W.road_toml(tmp_path / "split.toml", xodr)
    body = '[inputs.brake_pressure_cmd]\ntype = "step"\nt0 = 0.2\nafter = 12000.0\nramp = 0.1\n'
    sc = load_scenario(_scenario(tmp_path, road, body, 1.0, -3.5))
    sim, sc = prepare(None, sc)
    res = run(sim, sc)
    assert res.fault is None
    t = res.column("time")
    hard = (t > 0.5) & (res.column("speed") > 3.0)
    assert np.count_nonzero(hard) > 20
    ratio = {w: np.abs(res.column(f"tyre_fx_{w}")[hard]) / res.column(f"tyre_fz_{w}")[hard] for w in ("fl", "fr", "rl", "rr")}
    print({w: round(float(np.max(r)), 3) for w, r in ratio.items()})
    for w in ("fr", "rr"):                              # on lane -2: the 0.3 friction bounds the force
        assert np.max(ratio[w]) <= 0.3 * 1.15
    for w in ("fl", "rl"):                              # on lane -1
        assert np.max(ratio[w]) > 2.0 * np.max(ratio["fr"])


def test_a_lane_path_needs_an_opendrive_road(tmp_path):
    flat = tmp_path / "flat.toml"
    flat.write_text('type = "flat"\n')
    body = '[inputs.path_follower]\nlane = -1\n'
    with pytest.raises(ConfigError, match="inputs.path_follower.lane .*an OpenDRIVE road is needed"):
        load_scenario(_scenario(tmp_path, flat, body, 1.0, 0.0))
    xodr = W.write(tmp_path / "bar.xodr", W.bar_road())
    with pytest.raises(ConfigError, match="no lane -5"):
        load_scenario(_scenario(tmp_path, W.road_toml(tmp_path / "bar.toml", xodr), '[inputs.path_follower]\nlane = -5\n',
                                1.0, 0.0))
