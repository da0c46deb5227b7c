"""The X-by-wire vehicle model: suspension kinematics against the linkage they were fitted to, static
equilibrium against the weight split, a brake hold on a 5 % grade, and the kinematic consistency of a
steady turn. References are the model's own inputs (masses, geometry) and rigid-body kinematics, never
numbers the model printed."""
from __future__ import annotations

import numpy as np
import pytest

from pathlib import Path

from drivers.scenario import load_scenario
from rtsim.errors import ConfigError
from rtsim.road.model import make_grade, make_plane
from rtsim.vehicle.car.config import load_vehicle, validate, VehicleConfig, load_toml
from rtsim.vehicle.car.step import TyreOut
from rtsim.vehicle.kit.linkages import (
    OUT_AXIS, OUT_CENTRE, _pose_points, _solve_double_wishbone, _solve_macpherson, solve_corner,
)
from rtsim.vehicle.car.build import _geometry, build_vehicle
from rtsim.vehicle.car.sim import VehicleSim

ROOT = Path(__file__).resolve().parents[1]
from rtsim.mbs.model import ST_MAX_PHI, ST_MAX_PHID

G = 9.81
VEHICLE = "configs/vehicles/xbw.toml"


@pytest.fixture(scope="module")
def model():
    cfg, base = load_vehicle(VEHICLE)
    return build_vehicle(cfg, base)


def _chassis(sim):
    names = sim.vm.mech.coordinate_names
    i = names.index("chassis.x")
    return i


# ---- kinematics -------------------------------------------------------------------------------------
def test_front_fit_follows_the_linkage(model):
    """The fitted wheel-centre path and spin axis agree with a fresh solve of the double wishbone at
    points between the fit's grid nodes, to the fit error it reports (and that error is < 0.5 mm)."""
    cfg = model.config
    geom = _geometry(cfg.front, right=False)
    kin = model.corners[0]
    assert kin.fit_error < 5e-4
    rng = np.random.default_rng(3)
    for z, s in rng.uniform([-0.07, -0.06], [0.07, 0.06], size=(8, 2)):
        x = _solve_double_wishbone(geom, z, s, np.zeros(6))
        centre = _pose_points(x, geom.wheel_centre[None, :], geom.wheel_centre)[0]
        assert np.max(np.abs(kin.evaluate(OUT_CENTRE, z, s) - centre)) <= 2 * kin.fit_error + 1e-9
        assert abs(centre[2] - geom.wheel_centre[2] - z) < 1e-9


def test_rear_fit_follows_the_macpherson_linkage(model):
    geom = _geometry(model.config.rear, right=False)
    kin = model.corners[2]
    for z in np.linspace(-0.07, 0.07, 9):
        x = _solve_macpherson(geom, z, np.zeros(6))
        centre = _pose_points(x, geom.wheel_centre[None, :], geom.wheel_centre)[0]
        assert np.max(np.abs(kin.evaluate(OUT_CENTRE, z) - centre)) <= 2 * kin.fit_error + 1e-9


def test_rack_steers_both_front_wheels_left_and_mirrors(model):
    """Positive rack travel steers both front wheels left (ISO 8855); the right corner at rack +s is
    the mirror image of the left corner at -s."""
    fl, fr = model.corners[0], model.corners[1]
    for s in (0.01, 0.03):
        for kin in (fl, fr):
            a = kin.evaluate(OUT_AXIS, 0.0, s)
            assert np.arctan2(-a[0], a[1]) > 0.0
        left = fl.evaluate(OUT_CENTRE, 0.02, -s)
        right = fr.evaluate(OUT_CENTRE, 0.02, s)
        assert np.allclose(left * [1, -1, 1], right, atol=2 * fl.fit_error)


# ---- statics ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def parked(model):
    sim = VehicleSim(model, make_plane(), 1e-3, brake_pressure=2000.0)
    sim.step(3000)
    return sim


def test_static_wheel_loads_carry_the_weight(parked, model):
    """Sum of the tyre loads = total mass x g within 0.1 %; the front share is the one the centre of
    mass predicts (sprung and unsprung masses and their positions) within 1 %."""
    cfg = model.config
    m_total = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    fz = parked.vd.tyre[:, TyreOut.FZ]
    assert abs(fz.sum() - m_total * G) <= 1e-3 * m_total * G
    w = model.design_wheel_centre
    xf, xr = w[0, 0], w[2, 0]
    xs = cfg.chassis.cg_m[0]
    front = (cfg.chassis.mass_kg * (xs - xr) / (xf - xr) + 2 * cfg.front.unsprung_mass_kg) / m_total
    assert abs((fz[0] + fz[1]) / fz.sum() - front) <= 0.01 * front
    assert abs(fz[0] - fz[1]) < 1e-3 * fz[0] and abs(fz[2] - fz[3]) < 1e-3 * fz[2]   # symmetric car


def test_constraints_hold_while_parked(parked):
    st = parked.data.stats
    assert st[ST_MAX_PHI] <= 1e-8 and st[ST_MAX_PHID] <= 1e-6


@pytest.mark.parametrize("grade", [0.05, -0.05])
def test_brake_holds_the_car_on_a_5_percent_grade(model, grade):
    """Held by the brake on a 5 % grade (up or down), the car moves less than 1 mm in 10 s (after a
    2 s settling of the suspension and tyres)."""
    sim = VehicleSim(model, make_grade(grade), 1e-3, brake_pressure=3000.0)
    i = _chassis(sim)
    sim.step(2000)
    p0 = sim.data.q[i:i + 2].copy()
    sim.step(10000)
    assert np.linalg.norm(sim.data.q[i:i + 2] - p0) < 1e-3


# ---- dynamics ---------------------------------------------------------------------------------------
def test_steady_turn_is_kinematically_consistent():
    """step_steer_80kph (35 deg at the steering wheel from 80 km/h, speed held): at its steady state
    the lateral acceleration of the centre of mass (horizontal, normal to its velocity) equals yaw
    rate x speed within 2 %, and the outer (right) wheels carry more load than the inner ones."""
    from rtsim.vehicle.offline import prepare, run
    sim, sc = prepare(None, load_scenario("configs/scenarios/step_steer_80kph.toml", check_files=True))
    run(sim, sc)
    d = sim.data
    model = sim.vm
    i = _chassis(sim)
    v = d.qd[i:i + 3]
    a = d.qdd[i:i + 3]
    speed = np.linalg.norm(v[:2])
    lateral = np.array([-v[1], v[0]]) / speed
    a_lat = float(a[:2] @ lateral)
    names = model.mech.coordinate_names
    u = d.q[names.index("chassis.u.x"):names.index("chassis.u.x") + 3]
    ud = d.qd[names.index("chassis.u.x"):names.index("chassis.u.x") + 3]
    yaw_rate = float(np.cross(u, ud)[2] / max(1e-9, np.linalg.norm(u[:2]) ** 2))
    assert yaw_rate > 0.05                       # turning left
    assert abs(a_lat - yaw_rate * speed) <= 0.02 * abs(a_lat)
    fz = sim.vd.tyre[:, TyreOut.FZ]
    assert fz[1] > fz[0] and fz[3] > fz[2]
    assert d.stats[ST_MAX_PHI] <= 1e-8 and d.stats[ST_MAX_PHID] <= 1e-6


# ---- bad input --------------------------------------------------------------------------------------
def test_bad_vehicle_file_names_the_key(tmp_path):
    data = load_toml(VEHICLE)
    data["chassis"]["mass_kg"] = -5.0
    with pytest.raises(ConfigError, match=r"chassis\.mass_kg.*-5"):
        validate(VehicleConfig, data, "bad.toml")
    del data["front"]
    with pytest.raises(ConfigError, match="front: missing"):
        validate(VehicleConfig, data, "bad.toml")


def test_unreachable_travel_range_is_a_clear_error():
    """A travel range the linkage cannot reach (the lower arm would have to stretch) is rejected with
    a message naming the travel, not a solver traceback."""
    cfg, _ = load_vehicle(VEHICLE)
    geom = _geometry(cfg.front, right=False)
    from rtsim.errors import ModelError
    with pytest.raises(ModelError, match="cannot reach travel"):
        solve_corner(geom, z_range=(-0.6, 0.6), nz=5, ns=3)


def test_bad_subsystem_value_names_the_key(tmp_path):
    """A bad brake value in the vehicle file is reported with the file and its dotted key on load."""
    from rtsim.vehicle.car.config import load_vehicle
    src = ROOT / "configs" / "vehicles" / "xbw.toml"
    text = src.read_text().replace('property_file = "../tyres/', f'property_file = "{(ROOT / "configs/tyres").as_posix()}/')
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("mu = 0.38 ", "mu = -1.0 "))
    with pytest.raises(ConfigError, match=r"bad.toml: brakes\.front\.mu = -1\.0"):
        load_vehicle(bad)


def test_linear_tyre_model_is_used_when_configured():
    """tyres.model = "linear" in the vehicle file switches every tyre to the seed's linearised law:
    in a steady turn each tyre's lateral force is -C_alpha x slip angle (mirrored on the right side),
    with C_alpha from the same .tir at FNOMIN."""
    from rtsim.vehicle.car.step import TyreOut
    from rtsim.vehicle.kit.tyre.tir import P_LIN_CALPHA
    cfg, base = load_vehicle(VEHICLE)
    lin = cfg.model_copy(update={"tyres": cfg.tyres.model_copy(update={"model": "linear"})})
    sim = VehicleSim(build_vehicle(lin, base), make_plane(), 1e-3, speed=15.0)
    from rtsim.vehicle.car.step import CMD_STEER
    sim.io.commands[CMD_STEER] = 0.3
    sim.step(3000)
    t = sim.vd.tyre
    c_alpha = sim.tp[P_LIN_CALPHA]
    for i in range(4):
        # steady state: the transient slip equals the steady one, and the law is linear there
        assert abs(t[i, TyreOut.FY] - (-c_alpha * t[i, TyreOut.ALPHA])) < 1e-3 * abs(t[i, TyreOut.FY]) + 1.0
    assert np.all(np.abs(t[:, TyreOut.FY]) > 50.0)
