"""A car started at speed starts with its powertrain in steady motion with it.

`VehicleSim(..., speed=v)` used to start the powertrain at idle in 1st gear under wheels turning at
v / r_e: at 22 m/s the converter, overrun by a turbine at 9.6 times the wheel speed, dragged the rear
wheels from 79 to 28 rad/s in 0.1 s. Now the gear is the shift schedule's, the turbine turns with the
wheels and the engine runs where its closed-throttle torque balances the converter
(rtsim.vehicle.kit.powertrain.powertrain_state_rolling). References here are independent: the schedule and
the overrun equilibrium from the config's tables (numpy interpolation, scipy root finding), and an
analytic coasting deceleration (aero drag + MF 5.2 rolling resistance + engine braking over the
effective mass)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from rtsim.road.model import make_plane
from rtsim.vehicle.kit import powertrain as P
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.car.sim import VehicleSim
from rtsim.vehicle.kit.tyre.tir import P_LMY, P_LONGVL, P_QSY1, P_QSY3, P_QSY4, P_UNLOADED_RADIUS, load_tir

DT = 1e-3
G = 9.81


def schedule_gear_ref(cfg, v, throttle):
    g = cfg.gearbox
    gear = 1
    for row in g.upshift_speeds:
        if v > np.interp(throttle, g.schedule_throttle, row):
            gear += 1
        else:
            break
    return gear


def capacity_ref(cfg, sr):
    """1/K^2 of the config's converter: K linear in its nodes, then linear to 0 at SR = 1."""
    c = cfg.converter
    if sr <= c.speed_ratio_nodes[-1]:
        return 1.0 / np.interp(sr, c.speed_ratio_nodes, c.k_factor) ** 2
    return (1.0 - sr) / (1.0 - c.speed_ratio_nodes[-1]) / c.k_factor[-1] ** 2


def coasting_ref(cfg, wheel_speed):
    """Closed throttle, turbine above idle: gear, turbine speed, engine speed where the closed-throttle
    map torque equals the overrun converter torque -s C(w_e/w_t) w_t^2, and the drive torque per rear
    wheel (N*m, negative: engine braking; the wheels drive, so the losses divide by the efficiency)."""
    g, e = cfg.gearbox, cfg.engine
    gear = schedule_gear_ref(cfg, g.wheel_radius * wheel_speed, 0.0)
    rtot = g.ratios[gear - 1] * g.final_drive
    wt = rtot * wheel_speed
    scale = cfg.converter.overrun_capacity_scale

    def net(w):
        return np.interp(w, e.speed_nodes, e.torque_table[0]) + scale * capacity_ref(cfg, w / wt) * wt * wt

    we = brentq(net, e.idle_speed, wt, xtol=1e-12)
    tp = -scale * capacity_ref(cfg, we / wt) * wt * wt
    return gear, wt, we, 0.5 * rtot * tp / g.efficiency


# ------------------------------------------------------------------------------ powertrain alone
@pytest.mark.parametrize("v", [0.0, 1.0, 3.0, 5.0, 10.0, 20.0, 30.0])
@pytest.mark.parametrize("throttle", [0.0, 0.3])
def test_rolling_state_is_a_fixed_point_of_the_step(v, throttle):
    """Stepping the initial state 1 s with the wheels held at its speed changes nothing: engine speed,
    gear, idle integral and drive torque stay where they started (no start-up transient)."""
    cfg = P.powertrain_config()
    p = P.powertrain_params(cfg)
    w = v / cfg.gearbox.wheel_radius
    s = P.powertrain_state_rolling(p, DT, w, throttle=throttle)
    assert int(s[P.PS_GEAR]) == schedule_gear_ref(cfg, v, throttle)
    s0 = s.copy()
    u = np.zeros(P.PtIn.SIZE)
    u[P.PtIn.THROTTLE_CMD] = throttle
    u[P.PtIn.OMEGA_LEFT] = u[P.PtIn.OMEGA_RIGHT] = w
    u[P.PtIn.SELECTOR] = 1.0
    out = np.zeros(P.PO_SIZE)
    P.powertrain_step(p, s, u, DT, out)
    t_first = out[P.PO_TORQUE_LEFT]
    for _ in range(999):
        P.powertrain_step(p, s, u, DT, out)
    assert s[P.PS_GEAR] == s0[P.PS_GEAR]
    assert s[P.PS_OMEGA_E] == pytest.approx(s0[P.PS_OMEGA_E], rel=1e-7, abs=1e-7)
    assert s[P.PS_IDLE_I] == pytest.approx(s0[P.PS_IDLE_I], abs=1e-9)
    assert out[P.PO_TORQUE_LEFT] == pytest.approx(t_first, rel=1e-6, abs=1e-6)
    # steady: engine torque = pump torque
    assert out[P.PO_ENGINE_TORQUE] == pytest.approx(out[P.PO_PUMP_TORQUE], abs=1e-6)


def test_coasting_state_matches_the_overrun_equilibrium():
    """Closed throttle at 10 and 20 m/s: top gear from the schedule, engine a few per cent below the
    turbine where friction and pumping balance the converter in overrun, idle controller off."""
    cfg = P.powertrain_config()
    p = P.powertrain_params(cfg)
    for v in (10.0, 20.0):
        w = v / cfg.gearbox.wheel_radius
        gear, wt, we, t_wheel = coasting_ref(cfg, w)
        s = P.powertrain_state_rolling(p, DT, w)
        assert int(s[P.PS_GEAR]) == gear == 3
        assert s[P.PS_OMEGA_E] == pytest.approx(we, rel=1e-9)
        assert 0.9 * wt < we < wt
        assert s[P.PS_IDLE_I] == 0.0
        out = np.zeros(P.PO_SIZE)
        u = np.zeros(P.PtIn.SIZE)
        u[P.PtIn.OMEGA_LEFT] = u[P.PtIn.OMEGA_RIGHT] = w
        u[P.PtIn.SELECTOR] = 1.0
        P.powertrain_step(p, s, u, DT, out)
        assert out[P.PO_TORQUE_LEFT] == pytest.approx(t_wheel, rel=1e-6)
        assert t_wheel < 0.0


def test_at_rest_in_drive_the_engine_idles_against_the_stalled_converter():
    """Wheels still in D: engine at the idle set speed, the bypass (idle integral) carrying the stall
    load (idle / K(0))^2, creep torque TR(0) times that through 1st gear."""
    cfg = P.powertrain_config()
    p = P.powertrain_params(cfg)
    s = P.powertrain_state_rolling(p, DT, 0.0)
    e, c, g = cfg.engine, cfg.converter, cfg.gearbox
    assert int(s[P.PS_GEAR]) == 1 and s[P.PS_OMEGA_E] == e.idle_speed
    t_stall = (e.idle_speed / c.k_factor[0]) ** 2
    u = np.zeros(P.PtIn.SIZE)
    u[P.PtIn.SELECTOR] = 1.0
    out = np.zeros(P.PO_SIZE)
    P.powertrain_step(p, s, u, DT, out)
    assert out[P.PO_PUMP_TORQUE] == pytest.approx(t_stall, rel=1e-9)
    assert out[P.PO_ENGINE_TORQUE] == pytest.approx(t_stall, rel=1e-9)
    assert out[P.PO_IDLE_OPENING] == pytest.approx(s[P.PS_IDLE_I], rel=1e-12)
    creep = 0.5 * g.efficiency * g.ratios[0] * g.final_drive * c.torque_ratio[0] * t_stall
    assert out[P.PO_TORQUE_LEFT] == pytest.approx(creep, rel=1e-9)


def test_rolling_state_with_lockup_engaged():
    """A lock-up clutch in its gear above its speed starts engaged, the engine slipping T / c above
    the turbine, and stays there."""
    data = {"converter": {"lockup": True, "lockup_gear": 3, "lockup_speed": 15.0}}
    cfg = P.powertrain_config(data)
    p = P.powertrain_params(cfg)
    w = 25.0 / cfg.gearbox.wheel_radius
    s = P.powertrain_state_rolling(p, DT, w, throttle=0.3)
    assert s[P.PS_LOCKED] == 1.0 and int(s[P.PS_GEAR]) == 3
    w0 = s[P.PS_OMEGA_E]
    u = np.zeros(P.PtIn.SIZE)
    u[P.PtIn.THROTTLE_CMD] = 0.3
    u[P.PtIn.OMEGA_LEFT] = u[P.PtIn.OMEGA_RIGHT] = w
    u[P.PtIn.SELECTOR] = 1.0
    out = np.zeros(P.PO_SIZE)
    for _ in range(500):
        P.powertrain_step(p, s, u, DT, out)
    assert s[P.PS_LOCKED] == 1.0
    assert s[P.PS_OMEGA_E] == pytest.approx(w0, rel=1e-7)
    slip = w0 - out[P.PO_TURBINE_SPEED]
    assert out[P.PO_LOCKUP_TORQUE] == pytest.approx(cfg.converter.lockup_damping * slip, rel=1e-9)
    assert out[P.PO_ENGINE_TORQUE] == pytest.approx(out[P.PO_LOCKUP_TORQUE] + out[P.PO_PUMP_TORQUE], abs=1e-6)


# ----------------------------------------------------------------------------------- the vehicle
@pytest.fixture(scope="module")
def model():
    cfg, base = load_vehicle("configs/vehicles/xbw.toml")
    return build_vehicle(cfg, base), base


def coasting_deceleration(vm, base, ptcfg, gear, v, t_wheel, re_f, re_r):
    """Analytic coasting deceleration (m/s^2): aero drag 1/2 rho CdA v^2, MF 5.2 rolling resistance
    Fz R0 (QSY1 + QSY3 v/Vref + QSY4 (v/Vref)^4) / r_e on the car's weight, and engine braking
    2 T / r_e on the rear axle, over the mass plus the wheels' spin inertias / r_e^2 plus the engine's,
    which the converter slows with the turbine: J_e (i / r_e)^2 / eta (i: gear x final drive)."""
    cfg = vm.config
    tp = load_tir(Path(base) / cfg.tyres.property_file).params
    m = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    g = ptcfg.gearbox
    i = g.ratios[gear - 1] * g.final_drive
    m_eff = (m + 2 * cfg.front.wheel_spin_inertia_kgm2 / re_f ** 2 + 2 * cfg.rear.wheel_spin_inertia_kgm2 / re_r ** 2
             + ptcfg.engine.inertia * (i / re_r) ** 2 / g.efficiency)
    q = v / tp[P_LONGVL]
    f_rr = tp[P_QSY1] + tp[P_QSY3] * q + tp[P_QSY4] * q ** 4
    r_mean = 0.5 * (re_f + re_r)
    force = (0.5 * cfg.aero.air_density_kg_m3 * cfg.aero.drag_area_m2 * v * v
             + m * G * tp[P_UNLOADED_RADIUS] * f_rr * tp[P_LMY] / r_mean
             - 2.0 * t_wheel / re_r)
    return force / m_eff


@pytest.mark.parametrize("v0", [10.0, 20.0])
def test_started_at_speed_the_car_coasts_without_transient(model, v0):
    """Zero throttle from 10 and 20 m/s: over the first 0.5 s the rear wheels follow the analytic
    coasting line (v0 - a t) / r_e within 0.5 rad/s (the tyres only take up the small longitudinal slip
    of the engine braking; the old start lost 44 rad/s at 20 m/s), the car decelerates at the analytic
    rate within 10 %, and gear and engine speed stay at their steady values."""
    vm, base = model
    sim = VehicleSim(vm, make_plane(), DT, speed=v0)
    names = vm.mech.coordinate_names
    k_rl, k_rr, k_fl = (names.index(f"spin_{w}") for w in ("rl", "rr", "fl"))
    kx = names.index("chassis.x")
    w0 = sim.data.qd[k_rl]
    re_r = v0 / w0
    re_f = v0 / sim.data.qd[k_fl]
    cfg = sim.ptcfg
    gear, _, we, t_wheel = coasting_ref(cfg, w0)
    a = coasting_deceleration(vm, base, cfg, gear, v0, t_wheel, re_f, re_r)
    assert 0.1 < a < 1.5
    ts, wr, vs, gears, wes = [], [], [], [], []
    for k in range(100):
        sim.step(5)
        ts.append((k + 1) * 5 * DT)
        wr.append([sim.data.qd[k_rl], sim.data.qd[k_rr]])
        vs.append(np.linalg.norm(sim.data.qd[kx:kx + 3]))
        gears.append(sim.io.pt_out[P.PO_GEAR])
        wes.append(sim.io.pt_out[P.PO_ENGINE_SPEED])
    ts, wr = np.array(ts), np.array(wr)
    line = (v0 - a * ts) / re_r
    assert np.max(np.abs(wr - line[:, None])) < 0.5
    late = ts >= 0.1
    decel = -np.polyfit(ts[late], np.array(vs)[late], 1)[0]
    assert decel == pytest.approx(a, rel=0.10)
    assert np.all(np.array(gears) == gear)
    # the engine only slows with the turbine: by about i a t / r_e (0.5 s), plus 1 rad/s
    i = cfg.gearbox.ratios[gear - 1] * cfg.gearbox.final_drive
    assert np.max(np.abs(np.array(wes) - we)) < 1.0 + i * a * 0.5 / re_r
