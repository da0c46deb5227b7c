"""Powertrain against analytic results: bilinear engine map, capacity-factor converter (stall, coupling
point), idle speed control, stall equilibrium (stable at large steps), lock-up, gear schedule with
hysteresis, open differential, measured-torque mode, throttle-by-wire actuator."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator
from scipy.optimize import brentq

from rtsim.errors import ConfigError
from rtsim.vehicle.kit import powertrain as P

DT = 1e-3


def setup(data=None, dt=DT, **state):
    cfg = P.powertrain_config(data)
    p = P.powertrain_params(cfg)
    s = P.powertrain_state(p, dt, **state)
    return cfg, p, s


def inputs(throttle=0.0, w_rl=0.0, w_rr=None, selector=1.0, t_rl=0.0, t_rr=0.0):
    u = np.zeros(P.PtIn.SIZE)
    u[P.PtIn.THROTTLE_CMD] = throttle
    u[P.PtIn.OMEGA_LEFT] = w_rl
    u[P.PtIn.OMEGA_RIGHT] = w_rl if w_rr is None else w_rr
    u[P.PtIn.SELECTOR] = selector
    u[P.PtIn.TORQUE_LEFT] = t_rl
    u[P.PtIn.TORQUE_RIGHT] = t_rr
    return u


def run(p, s, u, n, dt=DT):
    out = np.zeros(P.PO_SIZE)
    for _ in range(n):
        P.powertrain_step(p, s, u, dt, out)
    return out


# ------------------------------------------------------------------------------------- engine map
def test_engine_map_exact_at_nodes_and_bilinear_between():
    cfg, p, _ = setup()
    e = cfg.engine
    tab = np.array(e.torque_table)
    for i, th in enumerate(e.throttle_nodes):
        for j, w in enumerate(e.speed_nodes):
            assert P.engine_map_torque(p, th, w)[0] == tab[i, j]
    ref = RegularGridInterpolator((np.array(e.throttle_nodes), np.array(e.speed_nodes)), tab)
    rng = np.random.default_rng(1)
    for _ in range(200):
        th = rng.uniform(0.0, e.throttle_nodes[-1])
        w = rng.uniform(0.0, e.speed_nodes[-1])
        t, dth, dw = P.engine_map_torque(p, th, w)
        assert t == pytest.approx(float(ref((th, w))), abs=1e-10)
        h = 1e-7
        assert dth == pytest.approx((float(ref((th + h, w))) - float(ref((th - h, w)))) / (2 * h), rel=1e-5, abs=1e-6)
        assert dw == pytest.approx((float(ref((th, w + h))) - float(ref((th, w - h)))) / (2 * h), rel=1e-5, abs=1e-6)
    # held constant beyond the table's edges
    assert P.engine_map_torque(p, 2.0, 1e4)[0] == tab[-1, -1]
    # plausible small engine: ~100 N m peak, ~45 kW, negative (friction + pumping) at closed throttle
    d = P.describe(cfg)
    assert 95 <= d["peak_torque_Nm"] <= 105 and 40 <= d["peak_power_kW"] <= 50
    assert all(v < 0 for v in tab[0, 1:])


# -------------------------------------------------------------------------------- torque converter
def test_converter_stall_and_k_factor_interpolation():
    cfg, p, _ = setup()
    c = cfg.converter
    for wp in (50.0, 150.0, 250.0):
        tp, tt, *_ = P.converter_torques(p, wp, 0.0)
        assert tp == pytest.approx((wp / c.k_factor[0]) ** 2, rel=1e-13)
        assert tt == pytest.approx(c.torque_ratio[0] * tp, rel=1e-13)
    wp = 200.0
    for sr in (0.1, 0.33, 0.65, 0.82, 0.93):
        tp, tt, *_ = P.converter_torques(p, wp, sr * wp)
        k = np.interp(sr, c.speed_ratio_nodes, c.k_factor)
        tr = np.interp(sr, c.torque_ratio_nodes, c.torque_ratio)
        assert tp == pytest.approx((wp / k) ** 2, rel=1e-12)
        assert tt == pytest.approx(tr * tp, rel=1e-12)
    # a turbine turning backwards is treated as stall
    assert P.converter_torques(p, wp, -10.0)[0] == pytest.approx((wp / c.k_factor[0]) ** 2)


def test_converter_coupling_point():
    cfg, p, _ = setup()
    src = cfg.converter.coupling_point()
    assert src == 0.85
    wp = 300.0
    srs = np.linspace(0.0, 0.999, 400)
    tr = []
    for sr in srs:
        tp, tt, *_ = P.converter_torques(p, wp, sr * wp)
        assert tp > 0.0
        tr.append(tt / tp)
    tr = np.array(tr)
    assert np.all(tr[srs >= src] == 1.0)            # coupling: turbine torque = pump torque
    assert np.all(tr[srs < src - 1e-9] > 1.0)        # multiplication below the coupling point
    assert np.all(np.diff(tr) <= 1e-12)              # torque ratio falls continuously to 1
    # the transmitted torque vanishes as the speed ratio reaches 1, and reverses in overrun
    assert P.converter_torques(p, wp, wp)[0] == 0.0
    assert P.converter_torques(p, wp, 0.999999 * wp)[0] == pytest.approx(0.0, abs=1e-3)
    tp, tt, *_ = P.converter_torques(p, 100.0, 200.0)
    assert tp == tt == pytest.approx(-(200.0 / np.interp(0.5, cfg.converter.speed_ratio_nodes,
                                                         cfg.converter.k_factor)) ** 2)


def test_converter_derivatives():
    _, p, _ = setup()
    h = 1e-6
    for wp, wt in ((200.0, 50.0), (200.0, 150.0), (300.0, 290.0), (120.0, 180.0), (150.0, 0.0)):
        d = P.converter_torques(p, wp, wt)
        for k, (dp, dt_) in enumerate(((1, 0), (0, 1))):
            hp, ht = h * dp, h * dt_
            fp = P.converter_torques(p, wp + hp, wt + ht)
            if wt == 0.0:     # one-sided at standstill (the stall branch starts there)
                fm = P.converter_torques(p, wp, wt)
                scale = 1.0
            else:
                fm = P.converter_torques(p, wp - hp, wt - ht)
                scale = 2.0
            assert d[2 + k] == pytest.approx((fp[0] - fm[0]) / (scale * h), rel=1e-4, abs=1e-6)
            assert d[4 + k] == pytest.approx((fp[1] - fm[1]) / (scale * h), rel=1e-4, abs=1e-6)


# ------------------------------------------------------------------------------ engine dynamics
@pytest.mark.parametrize("selector", [0.0, 1.0])
def test_idle_speed_with_closed_throttle(selector):
    """Neutral, and drive with the car held (converter at stall): the engine idles at the set speed."""
    cfg, p, s = setup(engine_speed=150.0, gear=int(selector))
    out = run(p, s, inputs(0.0, 0.0, selector=selector), 8000)
    assert out[P.PO_ENGINE_SPEED] == pytest.approx(cfg.engine.idle_speed, rel=1e-3)
    assert 0.0 < out[P.PO_IDLE_OPENING] < cfg.engine.idle_max_opening
    # the idle air just balances friction (+ converter drag in D)
    assert out[P.PO_ENGINE_TORQUE] == pytest.approx(out[P.PO_PUMP_TORQUE], abs=0.05)
    if selector:
        k0 = cfg.converter.k_factor[0]
        assert out[P.PO_PUMP_TORQUE] == pytest.approx((out[P.PO_ENGINE_SPEED] / k0) ** 2, rel=1e-9)


@pytest.mark.parametrize("dt", [1e-3, 5e-2])
def test_stall_speed_held_by_brake_is_stable(dt):
    """Full throttle in D, wheels held: the engine settles, without overshoot or oscillation, where the
    map torque equals the converter's stall capacity (omega / K(0))^2."""
    cfg, p, s = setup(dt=dt)
    e, k0 = cfg.engine, cfg.converter.k_factor[0]
    wot = np.array(e.torque_table[-1])
    w_stall = brentq(lambda w: np.interp(w, e.speed_nodes, wot) - (w / k0) ** 2, 50.0, 600.0)
    u = inputs(1.4, 0.0)
    out = np.zeros(P.PO_SIZE)
    ws = []
    for _ in range(int(round(5.0 / dt))):
        P.powertrain_step(p, s, u, dt, out)
        ws.append(out[P.PO_ENGINE_SPEED])
    ws = np.array(ws)
    assert ws[-1] == pytest.approx(w_stall, rel=1e-6)
    assert np.all(ws <= w_stall * (1 + 1e-9))          # no overshoot
    assert np.all(np.diff(ws[int(0.5 / dt):]) >= -1e-12)  # monotone approach, no oscillation
    ratio = cfg.gearbox.ratios[0] * cfg.gearbox.final_drive
    tt = cfg.converter.torque_ratio[0] * (w_stall / k0) ** 2
    assert out[P.PO_TORQUE_LEFT] == pytest.approx(0.5 * cfg.gearbox.efficiency * ratio * tt, rel=1e-5)


def test_lockup_clutch_stiff_coupling_is_stable():
    """A very stiff lock-up clutch (c dt / J = 67, explicit Euler would diverge): the engine follows the
    turbine with slip T_e / c, no oscillation."""
    data = {"converter": {"lockup": True, "lockup_gear": 3, "lockup_speed": 15.0,
                          "lockup_damping": 1.0e4, "lockup_capacity": 500.0}}
    cfg, p, s = setup(data, engine_speed=300.0, gear=3, throttle=0.3)
    w_wheel = 20.0 / cfg.gearbox.wheel_radius
    wt = w_wheel * cfg.gearbox.final_drive
    u = inputs(0.3, w_wheel)
    out = np.zeros(P.PO_SIZE)
    ws = []
    for _ in range(2000):
        P.powertrain_step(p, s, u, DT, out)
        ws.append(out[P.PO_ENGINE_SPEED])
    assert s[P.PS_LOCKED] == 1.0
    slip = out[P.PO_ENGINE_SPEED] - wt
    assert out[P.PO_LOCKUP_TORQUE] == pytest.approx(1.0e4 * slip, rel=1e-9)
    assert out[P.PO_ENGINE_TORQUE] == pytest.approx(out[P.PO_LOCKUP_TORQUE] + out[P.PO_PUMP_TORQUE], abs=1e-6)
    assert abs(slip) < 0.05
    assert np.ptp(ws[1000:]) < 1e-9


# ------------------------------------------------------------------------------------------ gearbox
def drive_speed_profile(p, s, throttle, v_of_t, t_end, rw):
    """Feed wheel speeds v(t)/rw at a constant throttle; return times, speeds and gears per step."""
    out = np.zeros(P.PO_SIZE)
    u = inputs(throttle)
    ts, vs, gears = [], [], []
    for k in range(int(round(t_end / DT))):
        t = (k + 1) * DT
        v = v_of_t(t)
        u[P.PtIn.OMEGA_LEFT] = u[P.PtIn.OMEGA_RIGHT] = v / rw
        P.powertrain_step(p, s, u, DT, out)
        ts.append(t)
        vs.append(v)
        gears.append(out[P.PO_GEAR])
    return np.array(ts), np.array(vs), np.array(gears)


def test_upshift_at_schedule_speed_with_delay():
    cfg, p, s = setup(throttle=0.5)
    g = cfg.gearbox
    v_up = float(np.interp(0.5, g.schedule_throttle, g.upshift_speeds[0]))
    acc = 0.5
    ts, vs, gears = drive_speed_profile(p, s, 0.5, lambda t: acc * t, 40.0, g.wheel_radius)
    k12 = int(np.argmax(gears >= 2))
    # the request starts at the first step with v > v_up and is executed after the shift delay
    v_request = vs[k12] - acc * (g.shift_delay - DT)
    assert v_request == pytest.approx(v_up, abs=acc * DT * 1.01)
    assert np.all(gears[:k12] == 1)
    v_up2 = float(np.interp(0.5, g.schedule_throttle, g.upshift_speeds[1]))
    k23 = int(np.argmax(gears >= 3))
    assert vs[k23] - acc * (g.shift_delay - DT) == pytest.approx(v_up2, abs=acc * DT * 1.01)
    assert gears[-1] == 3
    # the ratio moves linearly over the shift time
    assert np.all(np.diff(gears) >= 0)


def test_hysteresis_prevents_hunting():
    cfg, p, s = setup(throttle=0.5)
    g = cfg.gearbox
    v_up = float(np.interp(0.5, g.schedule_throttle, g.upshift_speeds[0]))
    v_dn = float(np.interp(0.5, g.schedule_throttle, g.downshift_speeds[0]))
    amp = 0.45 * (v_up - v_dn)
    centre = v_up - 0.5 * (v_up - v_dn) + amp * 0.5   # oscillates across the upshift line only
    ts, vs, gears = drive_speed_profile(p, s, 0.5, lambda t: centre + amp * math.sin(2 * math.pi * 0.5 * t),
                                        20.0, g.wheel_radius)
    assert vs.max() > v_up and vs.min() > v_dn
    assert np.count_nonzero(np.diff(gears)) == 1 and gears[-1] == 2
    # and a dip below the downshift line does bring it back to first
    ts, vs, gears = drive_speed_profile(p, s, 0.5, lambda t: v_dn - 0.5, 1.0, g.wheel_radius)
    assert gears[-1] == 1


def test_short_excursion_shorter_than_delay_does_not_shift():
    cfg, p, s = setup(throttle=0.5)
    g = cfg.gearbox
    v_up = float(np.interp(0.5, g.schedule_throttle, g.upshift_speeds[0]))
    ts, vs, gears = drive_speed_profile(
        p, s, 0.5, lambda t: v_up + (0.3 if 1.0 < t < 1.0 + 0.5 * g.shift_delay else -0.3), 3.0,
        g.wheel_radius)
    assert np.all(gears == 1)


def test_open_differential_equal_torques_and_ratio():
    # cornering (different wheel speeds), engine driving (15, 18) and overrunning (30, 36)
    for w_rl, w_rr, eta_pow in ((15.0, 18.0, 1), (30.0, 36.0, -1)):
        cfg, p, s = setup(throttle=0.8, engine_speed=300.0)
        out = run(p, s, inputs(0.8, w_rl, w_rr), 1)
        assert out[P.PO_TORQUE_LEFT] == out[P.PO_TORQUE_RIGHT]
        rtot = cfg.gearbox.ratios[0] * cfg.gearbox.final_drive
        assert out[P.PO_TURBINE_SPEED] == pytest.approx(rtot * 0.5 * (w_rl + w_rr))
        total = out[P.PO_TORQUE_LEFT] + out[P.PO_TORQUE_RIGHT]
        assert np.sign(total) == eta_pow
        eff = cfg.gearbox.efficiency ** eta_pow
        assert total == pytest.approx(eff * rtot * out[P.PO_TURBINE_TORQUE], rel=1e-12)
        # tangent: d T_rl / d omega_rl against a finite difference on fresh states
        h = 1e-5
        outs = []
        for dw in (h, -h):
            _, p2, s2 = setup(throttle=0.8, engine_speed=300.0)
            o = np.zeros(P.PO_SIZE)
            P.powertrain_step(p2, s2, inputs(0.8, w_rl + dw, w_rr), DT, o)
            outs.append(o[P.PO_TORQUE_LEFT])
        fd = (outs[0] - outs[1]) / (2 * h)
        assert out[P.PO_DTDW] == pytest.approx(fd, rel=0.02)   # (the engine's own response is excluded)
    # neutral transmits nothing; reverse drives backwards
    _, p, s = setup(gear=0)
    assert run(p, s, inputs(0.3, 0.0, selector=0.0), 200)[P.PO_TORQUE_LEFT] == 0.0
    _, p, s = setup(gear=-1, throttle=0.3)
    assert run(p, s, inputs(0.3, 0.0, selector=-1.0), 500)[P.PO_TORQUE_LEFT] < -50.0


def test_measured_torque_mode_passes_through():
    cfg, p, s = setup({"wheel_torque_source": "measured"})
    out = run(p, s, inputs(0.5, 10.0, 11.0, t_rl=123.4, t_rr=-56.7), 50)
    assert out[P.PO_TORQUE_LEFT] == 123.4 and out[P.PO_TORQUE_RIGHT] == -56.7 and out[P.PO_DTDW] == 0.0
    assert out[P.PO_ENGINE_SPEED] > 0.0   # the engine still runs for its sensor channel


# ------------------------------------------------------------------------------------ throttle
def test_throttle_by_wire_lag_and_rate_limit():
    cfg, p, s = setup({"throttle": {"time_constant": 0.05, "rate_limit": 1e9, "max": 1.4}})
    out = np.zeros(P.PO_SIZE)
    u = inputs(0.4, selector=0.0)
    ys = []
    for _ in range(100):
        P.powertrain_step(p, s, u, DT, out)
        ys.append(out[P.PO_THROTTLE])
    assert ys[49] == pytest.approx(0.4 * (1 - math.exp(-1.0)), rel=1e-9)     # 63.2 % at t = tau
    cfg, p, s = setup()     # default: 5 rad/s
    u = inputs(1.4, selector=0.0)
    prev = 0.0
    for _ in range(700):
        P.powertrain_step(p, s, u, DT, out)
        assert out[P.PO_THROTTLE] - prev <= 5.0 * DT * (1 + 1e-12)
        prev = out[P.PO_THROTTLE]
    assert out[P.PO_THROTTLE] == pytest.approx(1.4, abs=1e-3)
    u[P.PtIn.THROTTLE_CMD] = 3.0            # saturated at the plate's travel
    for _ in range(300):
        P.powertrain_step(p, s, u, DT, out)
        assert out[P.PO_THROTTLE] <= 1.4
    assert out[P.PO_THROTTLE] == pytest.approx(1.4, abs=1e-6)


def test_config_errors():
    with pytest.raises(ConfigError, match=r"powertrain\.gearbox\.downshift_speeds\[0\]"):
        P.powertrain_config({"gearbox": {"downshift_speeds": [[4.0, 7.0, 10.0, 16.0], [4.5, 7.5, 11.0, 19.0]]}})
    with pytest.raises(ConfigError, match=r"powertrain\.converter\.torque_ratio"):
        P.powertrain_config({"converter": {"torque_ratio": [2.0, 1.8, 1.6, 1.4, 1.2, 1.1, 1.05, 1.02]}})
    with pytest.raises(ConfigError, match="wheel_torque_source"):
        P.powertrain_config({"wheel_torque_source": "guess"})
    four = P.powertrain_config({"gearbox": {
        "ratios": [2.45, 1.45, 1.0, 0.69], "upshift_speeds": [[3.5, 6, 10, 15], [6.5, 11, 17, 25], [12, 16, 22, 32]],
        "downshift_speeds": [[2, 3.5, 6, 10], [4.5, 7.5, 11, 19], [9, 12, 17, 26]]}})
    assert len(four.gearbox.ratios) == 4
