"""Limit handling and the linear range of the vehicle model.

Limit cases must run through without NaN or convergence failure (a pure-Python multibody peer,
CommonRoad's MB model, ends in NaN on the spin case): a spin from 80 km/h braked to a stop, wheels
locked by a panic stop, all wheels leaving the ground and landing again. The linear range is checked
against the linear single-track model computed from the model's own parameters."""
import numpy as np
import pytest

from drivers.scenario import load_scenario
from rtsim.mbs.model import ST_MAX_PHI, ST_MAX_PHID
from rtsim.road.model import make_plane
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, TyreOut
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.car.describe import describe
from rtsim.vehicle.offline import prepare, run
from rtsim.vehicle.car.sim import VehicleSim

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


def test_wheels_leave_the_ground_and_land(model):
    """Dropped from 5 cm above its resting height: every tyre load is zero in the air, and the car
    lands and comes to rest carrying its weight again."""
    sim = VehicleSim(model, make_plane(), 1e-3)
    names = model.mech.coordinate_names
    for n in names:
        if n.endswith(".z") and not n.startswith("chassis.") or n == "chassis.z":
            sim.data.q[names.index(n)] += 0.05
    sim.step(20)
    assert np.all(sim.vd.tyre[:, TyreOut.FZ] == 0.0)
    sim.step(4000)
    cfg = model.config
    m_total = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    assert abs(sim.vd.tyre[:, TyreOut.FZ].sum() - m_total * G) < 1e-3 * m_total * G
    assert sim.data.stats[ST_MAX_PHI] <= 1e-8


def test_braking_in_a_turn_shifts_load_to_the_front():
    sim, sc = prepare(None, load_scenario("configs/scenarios/step_steer_braking_80kph.toml", check_files=True))
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
    sim, sc = prepare(None, load_scenario("configs/scenarios/steady_circle.toml", check_files=True))
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


@pytest.mark.parametrize("pressure", [10000.0, 12000.0])
def test_rear_lock_in_a_panic_stop_is_set_by_the_brakes_not_the_powertrain(model, pressure):
    """From 80 km/h, whether the rear wheels lock is the same in D and in N (no drive torque at all):
    the converter, slipping, passes the engine's spin-down and the creep only as a few tens of N m at
    each rear wheel in the first 1.5 s (measured: 27 N m at most at 10 MPa, 49 N m at 12 MPa; the rear
    brake gives 370 and 424 N m), so it moves the rear slip by less than 0.02. Whether the rears lock is the brake balance: the
    proportioning valve's rear torque against the rear tyres' peak braking torque under load transfer."""
    from rtsim.vehicle.car.step import EX_SELECTOR
    kappa = []
    for selector in (1.0, 0.0):
        sim = VehicleSim(model, make_plane(), 1e-3, speed=22.22)
        sim.io.commands[CMD_BRAKE] = pressure
        sim.io.extra[EX_SELECTOR] = selector
        sim.step(1500)
        assert np.all(sim.vd.tyre[:2, TyreOut.KAPPA] < -0.99)     # the fronts lock either way
        kappa.append(sim.vd.tyre[2:, TyreOut.KAPPA].copy())
    assert np.all(np.abs(kappa[0] - kappa[1]) < 0.02)
    assert np.all(kappa[0] < -0.99) == np.all(kappa[1] < -0.99)


def test_panic_stop_at_full_pressure_locks_all_four_and_the_converter_only_creeps(model):
    """The brake actuator's full pressure from 80 km/h in D: all four wheels lock, the car stops. The
    gearbox downshifts to 1st (the schedule sees the wheels stopped), the idle controller holds the
    engine at its idle speed against the stalled converter, whose output is then the creep torque
    0.5 eta i_1 i_fd TR(0) (w_idle / K(0))^2 per rear wheel (about 99 N m), a quarter of the rear brake
    torque: the held car does not move."""
    from rtsim.vehicle.kit.brake import rear_pressure
    from rtsim.vehicle.kit.powertrain import PO_ENGINE_SPEED, PO_GEAR, PO_TORQUE_LEFT
    sim = VehicleSim(model, make_plane(), 1e-3, speed=22.22)
    p_line = sim.bcfg.actuator.max
    sim.io.commands[CMD_BRAKE] = p_line
    sim.step(1500)
    assert np.all(sim.vd.tyre[:, TyreOut.KAPPA] < -0.99)
    sim.step(3000)
    assert _speed(sim) < 0.05
    e, c, g = sim.ptcfg.engine, sim.ptcfg.converter, sim.ptcfg.gearbox
    creep = (0.5 * g.efficiency * g.ratios[0] * g.final_drive * c.torque_ratio[0]
             * (e.idle_speed / c.k_factor[0]) ** 2)
    out = sim.io.pt_out
    assert out[PO_GEAR] == 1
    assert out[PO_ENGINE_SPEED] == pytest.approx(e.idle_speed, rel=1e-2)
    assert out[PO_TORQUE_LEFT] == pytest.approx(creep, rel=1e-2)
    rear_brake = sim.bcfg.rear.gain() * rear_pressure(sim.bcfg, p_line)
    assert creep < 0.3 * rear_brake
    x0 = sim.data.q[model.mech.coordinate_names.index("chassis.x")]
    sim.step(2000)
    assert abs(sim.data.q[model.mech.coordinate_names.index("chassis.x")] - x0) < 1e-3
