"""The motorcycle's engine and gearbox (rtsim.vehicle.motorcycle.engine) against references: full
throttle in a gear gives the full-load curve times the ratios and the efficiency; engine braking is
the closed-throttle curve the other way; the clutch pulls away from rest; the rev limiter cuts the
fuel; the automatic box shifts at its speeds without hunting; on the road the motorcycle in top gear
reaches the speed where the drive force equals aerodynamic drag plus rolling resistance."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from rtsim.configfile import load_toml, validate
from rtsim.errors import ConfigError
from rtsim.vehicle.motorcycle.build import build_motorcycle
from rtsim.vehicle.motorcycle.config import MotorcycleConfig, load_motorcycle
from rtsim.vehicle.motorcycle.engine import (ES_CLUTCH_SLIP, ES_ENGINE_SPEED, ES_GEAR, RPM, engine_state,
                                             pack_engine, rear_wheel_torque)
from rtsim.vehicle.kit.tyre.two_wheel import two_wheel_tyre_forces
from rtsim.vehicle.motorcycle.parts import make_parts
from rtsim.vehicle.motorcycle.ride import Ride
from rtsim.vehicle.motorcycle.sim import TwoWheelerSim, static_pose

ROOT = Path(__file__).resolve().parents[1]
VEHICLE = ROOT / "configs" / "vehicles" / "motorcycle.toml"
G = 9.81
DT = 1e-3


@pytest.fixture(scope="module")
def cfg():
    return load_motorcycle(VEHICLE)[0]


def _ratio(cfg, gear):
    pt = cfg.powertrain
    return pt.primary_ratio * pt.gear_ratios[gear - 1] * cfg.final_ratio


def _torque(ep, throttle, wheel_speed, es=None):
    es = engine_state() if es is None else es
    return rear_wheel_torque(ep, es, throttle, wheel_speed, DT), es


def test_full_throttle_is_the_curve_times_the_ratios(cfg):
    pt = cfg.powertrain
    for gear in (1, 3, 6):
        ep = pack_engine(pt, cfg.final_ratio, fixed_gear=gear)
        g = _ratio(cfg, gear)
        for rpm, t_full in zip(pt.engine_speed_rpm, pt.full_load_torque_nm):
            if not pt.launch_rpm < rpm < pt.rev_limit_rpm - pt.limiter_band_rpm:
                continue
            tw, es = _torque(ep, 1.0, rpm * RPM / g)
            assert es[ES_GEAR] == gear and es[ES_CLUTCH_SLIP] == 0.0
            assert es[ES_ENGINE_SPEED] == pytest.approx(rpm * RPM, rel=1e-12)
            assert tw == pytest.approx(pt.efficiency * g * t_full, rel=1e-12)
        # between nodes: the linear interpolant (9500 rpm: halfway between 9000 and 10000)
        tw, _ = _torque(ep, 1.0, 9500 * RPM / g)
        assert tw == pytest.approx(pt.efficiency * g * 0.5 * (106 + 111), rel=1e-12)


def test_engine_braking_and_part_throttle(cfg):
    pt = cfg.powertrain
    ep = pack_engine(pt, cfg.final_ratio, fixed_gear=2)
    g = _ratio(cfg, 2)
    w = 6000 * RPM / g                           # node: full 90 N m, closed 15 N m
    tw, _ = _torque(ep, 0.0, w)
    assert tw == pytest.approx(-g * 15.0 / pt.efficiency, rel=1e-12), "the wheel drives the engine: G T / eta"
    tw, _ = _torque(ep, 0.4, w)
    assert tw == pytest.approx(pt.efficiency * g * (0.4 * 90.0 - 0.6 * 15.0), rel=1e-12)


def test_rev_limiter_cuts_the_fuel(cfg):
    pt = cfg.powertrain
    ep = pack_engine(pt, cfg.final_ratio, fixed_gear=4)
    g = _ratio(cfg, 4)
    tw, _ = _torque(ep, 1.0, (pt.rev_limit_rpm + 100) * RPM / g)
    closed = np.interp(pt.rev_limit_rpm + 100, pt.engine_speed_rpm, pt.closed_throttle_torque_nm)
    assert tw == pytest.approx(-g * closed / pt.efficiency, rel=1e-12)
    mid = pt.rev_limit_rpm - 0.5 * pt.limiter_band_rpm       # half the fuel
    tw, _ = _torque(ep, 1.0, mid * RPM / g)
    full, closed = (np.interp(mid, pt.engine_speed_rpm, c) for c in (pt.full_load_torque_nm, pt.closed_throttle_torque_nm))
    assert tw == pytest.approx(pt.efficiency * g * (0.5 * full - 0.5 * closed), rel=1e-9)


def test_clutch_pulls_away_from_rest_and_locks(cfg):
    pt = cfg.powertrain
    ep = pack_engine(pt, cfg.final_ratio)
    g1 = _ratio(cfg, 1)
    tw, es = _torque(ep, 0.0, 0.0)
    assert tw == 0.0 and es[ES_ENGINE_SPEED] == pytest.approx(pt.idle_rpm * RPM), "clutch in, idling"
    es = engine_state()
    full_at_launch = np.interp(pt.launch_rpm, pt.engine_speed_rpm, pt.full_load_torque_nm)
    for w in (0.0, 1.0, 0.99 * pt.launch_rpm * RPM / g1):    # slipping: the engine held at the launch speed
        tw, es = _torque(ep, 1.0, w, es)
        assert es[ES_GEAR] == 1 and es[ES_CLUTCH_SLIP] == 1.0
        assert es[ES_ENGINE_SPEED] == pytest.approx(pt.launch_rpm * RPM)
        assert tw == pytest.approx(pt.efficiency * g1 * min(full_at_launch, pt.clutch_capacity_nm), rel=1e-12)
    tw, es = _torque(ep, 1.0, 1.01 * pt.launch_rpm * RPM / g1, es)
    assert es[ES_CLUTCH_SLIP] == 0.0, "locked once the gearbox reaches the launch speed"
    tw, es = _torque(ep, 0.0, 0.9 * pt.launch_rpm * RPM / g1, es)
    assert es[ES_CLUTCH_SLIP] == 0.0 and tw < 0.0, "stays locked, engine braking, above idle"


def test_automatic_box_shifts_at_its_speeds_without_hunting(cfg):
    pt = cfg.powertrain
    ep = pack_engine(pt, cfg.final_ratio)
    es = engine_state()
    gears = []
    sweep = np.linspace(5.0, 280.0, 30000)            # a slow sweep up at full throttle, 30 s
    for w in sweep:
        rear_wheel_torque(ep, es, 1.0, w, DT)
        gears.append(es[ES_GEAR])
    gears = np.array(gears)
    assert np.all(np.diff(gears) >= 0) and gears[-1] == len(pt.gear_ratios)
    up = np.nonzero(np.diff(gears) > 0)[0]
    assert len(up) == len(pt.gear_ratios) - 1
    for i in up:                    # each upshift just past the upshift speed (in the gear it leaves)
        assert pt.upshift_rpm < sweep[i + 1] * _ratio(cfg, int(gears[i])) / RPM < pt.upshift_rpm + 100
    for w in np.linspace(280.0, 5.0, 30000):
        rear_wheel_torque(ep, es, 0.0, w, DT)
        gears = np.append(gears, es[ES_GEAR])
    assert np.all(np.diff(gears[30000:]) <= 0) and gears[-1] == 1


def test_bad_powertrain_names_key_and_value():
    data = load_toml(VEHICLE)
    data["powertrain"]["gear_ratios"] = [2.6, 2.7, 1.8]
    with pytest.raises(ConfigError, match="gear_ratios"):
        validate(MotorcycleConfig, data, "bad.toml")
    data = load_toml(VEHICLE)
    data["powertrain"]["downshift_rpm"] = 8000
    with pytest.raises(ConfigError, match="downshift_rpm.*hunt"):
        validate(MotorcycleConfig, data, "bad.toml")


def test_top_speed_where_drive_force_meets_drag_and_rolling_resistance():
    """Full throttle in top gear with an upright rider's drag area (0.9 m^2: the equilibrium lies inside
    the torque curve, not at the rev limiter). Steady running at v: the rear tyre's force Fx_r balances
    the drag D = 1/2 rho CdA v^2 and the front tyre's rolling resistance; the wheel's moments balance,
    T = Fx_r r_l + R Fz_r f(v) with T = eta G T_full(omega_e), omega_e = G v (1 + kappa) / r_e, f(v) =
    f0 + f2 v^2, r_l = R - Fz / kz the loaded radius and r_e = R - (R - r_l) / 3 the rolling radius; the
    slip kappa is the tyre law's for Fx_r, and the loads are the static ones less the lift and the drag's
    pitching moment about the contacts. The run starts 2 m/s short of it."""
    data = load_toml(VEHICLE)
    data["aero"]["drag_area_m2"] = 0.9
    data["powertrain"]["gear"] = 6
    cfg = validate(MotorcycleConfig, data, "upright motorcycle")
    mm = build_motorcycle(cfg, ROOT)
    pt, a = cfg.powertrain, cfg.aero
    g6 = _ratio(cfg, 6)
    q, loads = static_pose(mm)
    weight = loads.sum()
    wheelbase = cfg.geometry.wheelbase_m
    tp = make_parts(mm).tp
    radius = (cfg.front_wheel.radius_m, cfg.rear_wheel.radius_m)
    kz = (cfg.tyres.front.radial_stiffness_n_per_m, cfg.tyres.rear.radial_stiffness_n_per_m)

    def resisting(v):
        half = 0.5 * a.air_density_kg_m3 * v * v
        drag, lift = half * a.drag_area_m2, half * a.lift_area_m2
        xcp, zcp = a.centre_of_pressure_m
        fz_f = loads[0] - (lift * xcp + drag * zcp) / wheelbase
        fz = (fz_f, weight - lift - fz_f)
        rl = [radius[i] - fz[i] / kz[i] for i in range(2)]
        my = [-two_wheel_tyre_forces(tp[i], fz[i], 0.0, 0.0, 0.0, v, 1.0)[3] for i in range(2)]
        return drag + my[0] / rl[0], fz[1], rl[1], my[1]

    def residual(v):
        fx_r, fz_r, rl, my_r = resisting(v)
        kappa = brentq(lambda k: two_wheel_tyre_forces(tp[1], fz_r, k, 0.0, 0.0, v, 1.0)[0] - fx_r, 0.0, 0.1)
        re = radius[1] - (radius[1] - rl) / 3.0
        rpm = g6 * v * (1.0 + kappa) / re / RPM
        torque = pt.efficiency * g6 * np.interp(rpm, pt.engine_speed_rpm, pt.full_load_torque_nm)
        return torque - fx_r * rl - my_r

    v_top = brentq(residual, 30.0, 80.0)
    assert g6 * v_top / radius[1] < (pt.rev_limit_rpm - pt.limiter_band_rpm) * RPM, "inside the torque curve"
    ride = Ride(TwoWheelerSim(mm, speed=v_top - 2.0, q=q), None, open_loop={"throttle": lambda t: 1.0})
    speeds = []
    for _ in range(int(round(24.0 / DT))):
        ride.step()
        speeds.append(ride.sim.velocity[0])
    assert abs(ride.sim.roll) < 1e-3, "upright"
    assert abs(speeds[-1] - speeds[-2000]) < 0.05, "settled"
    assert speeds[-1] == pytest.approx(v_top, rel=2e-3)
