"""Limit handling and the linear range of the vehicle model.

Limit cases must run through without NaN or convergence failure (a pure-Python multibody peer,
CommonRoad's MB model, ends in NaN on the spin case): a spin from 80 km/h braked to a stop, wheels
locked by a panic stop, all wheels leaving the ground and landing again. The linear range is checked
against the linear single-track model computed from the model's own parameters."""
import numpy as np
import pytest

from rtsim.mbs.model import ST_MAX_PHI, ST_MAX_PHID
from rtsim.road.model import make_plane
from rtsim.vehicle.config import load_vehicle
from rtsim.vehicle.dynamics import CMD_BRAKE, CMD_STEER, TO_FZ, TO_KAPPA
from rtsim.vehicle.model import build_vehicle
from rtsim.vehicle.run import describe, prepare, run
from rtsim.vehicle.sim import VehicleSim

G = 9.81


@pytest.fixture(scope="module")
def model():
    cfg, base = load_vehicle("configs/vehicles/xbw.toml")
    return build_vehicle(cfg, base)


def _speed(sim):
    names = sim.vm.mech.coordinate_names
    i = names.index("chassis.x")
    return float(np.linalg.norm(sim.data.qd[i:i + 3]))


def _yaw(sim):
    names = sim.vm.mech.coordinate_names
    i = names.index("chassis.u.x")
    return float(np.degrees(np.arctan2(sim.data.q[i + 1], sim.data.q[i])))


def test_spin_from_80kph_runs_to_a_stop(model):
    """3 rad at the steering wheel (about 0.16 rad at the road wheels) at 80 km/h: the car spins
    (yaw beyond 90 degrees), then the brake stops it; finite throughout, constraints held."""
    sim = VehicleSim(model, make_plane(), 1e-3, speed=22.22)
    sim.step(500)
    sim.io.commands[CMD_STEER] = 3.0
    sim.step(3500)
    assert abs(_yaw(sim)) > 90.0
    sim.io.commands[CMD_BRAKE] = 4000.0
    sim.step(6000)
    assert _speed(sim) < 0.05
    assert np.all(np.isfinite(sim.data.q))
    assert sim.data.stats[ST_MAX_PHI] <= 1e-8 and sim.data.stats[ST_MAX_PHID] <= 1e-6


def test_panic_stop_locks_the_wheels_and_stops(model):
    sim = VehicleSim(model, make_plane(), 1e-3, speed=22.22)
    sim.io.commands[CMD_BRAKE] = 10000.0
    sim.step(1500)
    assert np.all(sim.vd.tyre[:, TO_KAPPA] < -0.99)        # all four locked (kappa = -1)
    sim.step(3000)
    assert _speed(sim) < 0.05
    assert sim.data.stats[ST_MAX_PHI] <= 1e-8


def test_wheels_leave_the_ground_and_land(model):
    """Dropped from 5 cm above its resting height: every tyre load is zero in the air, and the car
    lands and comes to rest carrying its weight again."""
    sim = VehicleSim(model, make_plane(), 1e-3)
    names = model.mech.coordinate_names
    for n in names:
        if n.endswith(".z") and not n.startswith("chassis.") or n == "chassis.z":
            sim.data.q[names.index(n)] += 0.05
    sim.step(20)
    assert np.all(sim.vd.tyre[:, TO_FZ] == 0.0)
    sim.step(4000)
    cfg = model.config
    m_total = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    assert abs(sim.vd.tyre[:, TO_FZ].sum() - m_total * G) < 1e-3 * m_total * G
    assert sim.data.stats[ST_MAX_PHI] <= 1e-8


def test_braking_in_a_turn_shifts_load_to_the_front():
    sim, sc = prepare(None, "configs/scenarios/step_steer_braking_80kph.toml")
    res = run(sim, sc)
    t = res.column("time")
    before = (t > 4.0) & (t < 4.9)
    during = (t > 5.5) & (t < 6.5)
    front = res.column("tyre_fz_fl") + res.column("tyre_fz_fr")
    rear = res.column("tyre_fz_rl") + res.column("tyre_fz_rr")
    assert front[during].mean() > front[before].mean() + 500.0
    assert rear[during].mean() < rear[before].mean() - 500.0
    assert np.max(res.column("constraint_violation")) <= 1e-8


def test_steady_circle_yaw_gain_matches_the_single_track_model(model):
    """At low lateral acceleration (< 2 m/s^2) the yaw-rate gain per mean front road-wheel angle is
    within 5 % of the linear single-track model V / (L (1 + K V^2)) with the understeer gradient
    K = m/L (b/C_f - a/C_r) from the model's own mass, weight split and axle cornering stiffnesses."""
    sim, sc = prepare(None, "configs/scenarios/steady_circle.toml")
    info = describe(model, VehicleSim(model, make_plane(), 1e-3))
    res = run(sim, sc)
    t = res.column("time")
    ay = res.column("accel_y")
    sel = (t > 8.0) & (np.abs(ay) < 2.0) & (np.abs(ay) > 0.3)
    assert sel.sum() > 100
    v = res.column("speed")[sel]
    delta = 0.5 * (res.column("steer_angle_fl") + res.column("steer_angle_fr"))[sel]
    r = res.column("gyro_z")[sel]
    m, L = info["mass"], info["wheelbase"]
    a = info["cg_to_front_axle"]
    b = L - a
    cf, cr = 2 * info["cornering_stiffness_front"], 2 * info["cornering_stiffness_rear"]
    k = m / L * (b / cf - a / cr)
    gain_linear = v / (L * (1.0 + k * v * v))
    gain = r / delta
    assert np.max(np.abs(gain / gain_linear - 1.0)) < 0.05
