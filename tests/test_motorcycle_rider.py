"""The rider (drivers.rider) on the sport motorcycle, closed loop in the time domain: the double lane change
at 22 m/s and the figure-eight of Moreno Giner et al. (2008), section 5. Bars: path kept within 0.3 m RMS
lateral error, no fall; in the steady turns the roll approaches the equilibrium lean within 10 %.

The equilibrium lean: atan(u^2 kappa / g) is the lean of the line from the contact patch to the mass
centre. With tyres of crown radius rho the contact moves round the crown into the turn, so the frame
leans further, by asin(k sin phi_0), k = rho / (h - rho) (Cossalter, Motorcycle Dynamics, ch. 2): the
motorcycle on its tyres is held to that value, and the same motorcycle on knife-edge wheels to
atan(u^2 kappa / g) itself."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.road.paths import double_lane_change, figure_eight
from drivers.rider import rider
from rtsim.configfile import load_toml, validate
from rtsim.vehicle.motorcycle.build import build_motorcycle
from rtsim.vehicle.motorcycle.config import MotorcycleConfig, load_motorcycle
from rtsim.vehicle.motorcycle.ride import Ride, tyre_lean_ratio
from rtsim.vehicle.motorcycle.sim import TwoWheelerSim, static_pose

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = ROOT / "configs" / "vehicles" / "motorcycle.toml"
G = 9.81
RADIUS = 20.0


@pytest.fixture(scope="module")
def bike():
    cfg, base = load_motorcycle(VEHICLE)
    return build_motorcycle(cfg, base)


def _ride(mm, px, py, speed, seconds, closed=False):
    q, _ = static_pose(mm)
    r = rider(px, py, closed=closed, speed=speed, tyre_lean=tyre_lean_ratio(mm))
    ride = Ride(TwoWheelerSim(mm, speed=speed, q=q), r)
    return ride.run(seconds)       # raises Fall if it falls


def _steady_roll_ratio(log, k):
    t, roll, u, kap = log[:, 0], log[:, 3], log[:, 6], log[:, 9]
    phi0 = -np.arctan(u ** 2 * kap / G)
    ref = phi0 + np.arcsin(k * np.sin(phi0))
    # steady: on a loop (full curvature) for the last 2 s, i.e. at least 2 s after entering it
    on = np.abs(kap) > 0.95 / RADIUS
    since = np.zeros_like(t)
    for i in range(1, t.size):
        since[i] = since[i - 1] + (t[i] - t[i - 1]) if on[i] and np.sign(kap[i]) == np.sign(kap[i - 1]) else 0.0
    steady = since > 2.0
    assert steady.sum() > 1000
    return roll[steady] / ref[steady]


def test_double_lane_change_at_22_m_s(bike):
    px, py = double_lane_change(offset=3.5, entry=40.0, transition=60.0, hold=30.0, exit=60.0)
    log = _ride(bike, px, py, 22.0, (px[-1] - px[0]) / 22.0 - 1.0)
    n = log[log[:, 0] > 1.0, 7]
    assert np.sqrt(np.mean(n ** 2)) <= 0.3
    assert np.abs(log[:, 3]).max() > 0.1, "it leans into the lane changes"


def test_figure_eight_path_and_steady_lean(bike):
    px, py = figure_eight(RADIUS, straight=20.0)
    log = _ride(bike, px, py, 10.0, 30.0, closed=True)
    n = log[log[:, 0] > 1.0, 7]
    assert np.sqrt(np.mean(n ** 2)) <= 0.3
    ratio = _steady_roll_ratio(log, tyre_lean_ratio(bike))
    assert abs(np.median(ratio) - 1.0) < 0.1
    assert (log[:, 3].min() < -0.3) and (log[:, 3].max() > 0.3), "leans both ways"


def test_figure_eight_on_knife_edge_wheels_leans_atan(bike):
    data = load_toml(VEHICLE)
    data["tyres"] = {"model": "knife_edge"}
    mm = build_motorcycle(validate(MotorcycleConfig, data, "knife-edge motorcycle"), ROOT)
    px, py = figure_eight(RADIUS, straight=20.0)
    log = _ride(mm, px, py, 10.0, 30.0, closed=True)
    n = log[log[:, 0] > 1.0, 7]
    assert np.sqrt(np.mean(n ** 2)) <= 0.3
    assert abs(np.median(_steady_roll_ratio(log, 0.0)) - 1.0) < 0.1
