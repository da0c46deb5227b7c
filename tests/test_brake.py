"""Brake-by-wire against analytic results: seed eq. 5 in sliding, exact hold on a grade (no drift, no
chatter), breakaway at the analytic pressure, proportioning valve, derivatives, actuator path."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.vehicle.kit import brake as B

DT = 1e-3
G = 9.81


def make(pressure=0.0, stuck=False, **cfg):
    c = B.brake_config(cfg or None)
    p = B.brake_params(c)
    s = B.brake_state(p, DT, pressure=pressure, stuck=stuck)
    return c, p, s


def set_pressure(p, s, kpa):
    """Put the line pressure at kpa at once (bypassing the actuator dynamics)."""
    s[B.BS_ACT:] = kpa
    s[B.BS_ACT + 1] = 0.0   # LAG_HEAD
    s[B.BS_ACT + 2] = 0.0   # LAG_NBUF (no delay configured)
    B._update_limits(p, s, kpa)


def test_sliding_torque_is_n_mu_p_A_R():
    c, p, s = make()
    for kpa in (150.0, 1000.0, 2500.0, 6000.0):
        set_pressure(p, s, kpa)
        for i in range(4):
            axle = c.front if i < 2 else c.rear
            pw = kpa if i < 2 else B.rear_pressure(c, kpa)
            expect = axle.pads * axle.mu * (pw * 1e3) * axle.piston_area * axle.effective_radius
            for w in (3.0, -7.5):
                tau, dw, dth = B.brake_wheel_torque(p, s, i, 0.4, w)
                assert tau == pytest.approx(-math.copysign(expect, w), rel=1e-12)
                assert dw == 0.0 and dth == 0.0
    # proportioning valve: line pressure below the knee, knee + ratio (p - knee) above
    assert B.rear_pressure(c, 2000.0) == 2000.0
    assert B.rear_pressure(c, 4500.0) == pytest.approx(2500.0 + 0.4 * 2000.0)


def test_gains_for_describe():
    c = B.brake_config()
    g = B.brake_gains(c)
    assert g["front_Nm_per_kPa"] == pytest.approx(2 * 0.38 * 1.81e-3 * 0.095 * 1e3)
    assert g["rear_Nm_per_kPa"] == pytest.approx(2 * 0.35 * 1.13e-3 * 0.085 * 1e3)
    assert g["rear_above_knee_Nm_per_kPa_line"] == pytest.approx(0.4 * g["rear_Nm_per_kPa"])


def test_derivatives_match_finite_differences():
    c, p, s = make(pressure=1500.0)
    h = 1e-7
    # sliding band and stick spring (both away from the kinks)
    for mode, theta, w in ((B.SLIDE, 0.0, 0.013), (B.STICK, 0.002, -0.01)):
        s[B.BS_MODE] = mode
        s[B.BS_ANCHOR] = 0.0
        t0, dw, dth = B.brake_wheel_torque(p, s, 0, theta, w)
        fw = (B.brake_wheel_torque(p, s, 0, theta, w + h)[0] - B.brake_wheel_torque(p, s, 0, theta, w - h)[0]) / (2 * h)
        fth = (B.brake_wheel_torque(p, s, 0, theta + h, w)[0] - B.brake_wheel_torque(p, s, 0, theta - h, w)[0]) / (2 * h)
        assert dw == pytest.approx(fw, rel=1e-6)
        assert dth == pytest.approx(fth, rel=1e-6, abs=1e-6)
    # stick: clipped at the breakaway torque, zero tangent beyond it
    s[B.BS_MODE] = B.STICK
    tau, dw, dth = B.brake_wheel_torque(p, s, 0, -1.0, 0.0)
    assert tau == pytest.approx(s[B.BS_TAU_BREAK]) and dw == 0.0 and dth == 0.0


# ---------------------------------------------------------------------------- 1-DOF wheel + mass
M_CAR = 200.0          # kg carried by the wheel (a quarter of the car)
R_WHEEL = 0.28         # m
J_WHEEL = 0.8          # kg m^2
J_EFF = J_WHEEL + M_CAR * R_WHEEL ** 2
GRADE = 0.05
# the car faces uphill; gravity rolls it backwards (negative omega)
T_LOAD = -M_CAR * G * math.sin(math.atan(GRADE)) * R_WHEEL


def advance(p, s, theta, w, scheme):
    """One 1 ms step of J_EFF dw/dt = T_LOAD + tau_brake for wheel 0, then the brake commit."""
    tau, dtw, dtth = B.brake_wheel_torque(p, s, 0, theta, w)
    if scheme == "symplectic":          # semi-implicit Euler, explicit torque
        w1 = w + DT / J_EFF * (T_LOAD + tau)
    else:                                # linearly implicit Euler with the brake's tangent
        lhs = J_EFF - DT * dtw - DT * DT * dtth
        w1 = w + DT * (T_LOAD + tau + DT * dtth * w) / lhs
    th1 = theta + DT * w1
    B.brake_commit_wheel(p, s, 0, th1, w1)
    return th1, w1


@pytest.mark.parametrize("scheme", ["symplectic", "linear-implicit"])
def test_held_on_grade_no_drift_no_chatter(scheme):
    c, p, s = make(pressure=2000.0, stuck=True)
    theta, w = 0.0, 0.0
    hist, torque = [], []
    for k in range(12000):
        theta, w = advance(p, s, theta, w, scheme)
        hist.append(theta)
        torque.append(B.brake_wheel_torque(p, s, 0, theta, w)[0])
    hist = np.array(hist)
    torque = np.array(torque)
    assert s[B.BS_MODE] == B.STICK
    # static deflection of the anchor spring, then nothing moves for 10 s
    assert hist[2000] == pytest.approx(T_LOAD / c.anchor_stiffness, rel=1e-6)
    drift = np.max(np.abs(hist[2000:] - hist[2000]))
    assert drift < 1e-6
    # the brake carries the load exactly, with a constant torque (no chatter)
    # (after the spring-damper's transient has decayed: zeta ~ 0.18 at this inertia)
    assert np.all(torque[4000:] == pytest.approx(-T_LOAD, rel=1e-9))
    assert np.ptp(torque[4000:]) < 1e-9 * abs(T_LOAD)


@pytest.mark.parametrize("scheme", ["symplectic", "linear-implicit"])
def test_release_at_analytic_breakaway_pressure(scheme):
    c, p, s = make(pressure=600.0, stuck=True)
    # breakaway when (mu_s/mu) n mu p A R = |T_LOAD|
    p_break = abs(T_LOAD) / (c.front.gain() * c.front.mu_static / c.front.mu)
    theta, w = 0.0, 0.0
    rate = 100.0    # kPa/s ramp down
    kpa = 600.0
    released_at = None
    for k in range(7000):
        kpa = max(600.0 - rate * (k + 1) * DT, 0.0)
        set_pressure(p, s, kpa)
        theta, w = advance(p, s, theta, w, scheme)
        if released_at is None and s[B.BS_MODE] == B.SLIDE:
            released_at = kpa
            theta_release = theta
        if released_at is None:
            held_theta = theta
    assert released_at is not None
    assert released_at == pytest.approx(p_break, abs=rate * DT + 1e-9)
    # still exactly at the static deflection just before the release
    assert abs(held_theta - T_LOAD / c.anchor_stiffness) < 1e-6
    # and rolling backwards afterwards
    assert w < -1.0 and theta < theta_release - 0.5


def test_rolls_to_a_stop_and_holds():
    """Rolling back down the grade at 2 m/s, the brake is applied: the wheel stops, sticks and holds."""
    c, p, s = make(pressure=1000.0, stuck=False)
    theta, w = 0.0, -2.0 / R_WHEEL
    ts = s[B.BS_TAU_SLIDE]
    t_stop = (-w) * J_EFF / (ts + T_LOAD)     # constant deceleration (T_LOAD < 0 opposes the brake)
    thetas = []
    stuck_at = None
    for k in range(6000):
        theta, w = advance(p, s, theta, w, "linear-implicit")
        thetas.append(theta)
        if stuck_at is None and s[B.BS_MODE] == B.STICK:
            stuck_at = (k + 1) * DT
    assert stuck_at == pytest.approx(t_stop, abs=0.01)
    thetas = np.array(thetas)
    assert np.max(np.abs(thetas[3000:] - thetas[3000])) < 1e-6
    assert s[B.BS_MODE] == B.STICK


def test_no_brake_no_stick():
    c, p, s = make(pressure=0.0, stuck=True)
    theta, w = 0.0, 0.0
    for _ in range(500):
        theta, w = advance(p, s, theta, w, "linear-implicit")
    assert s[B.BS_MODE] == B.SLIDE
    assert w == pytest.approx(T_LOAD / J_EFF * 0.5, rel=1e-3)


def test_pressure_actuator_lag_rate_and_split():
    c, p, s = make(actuator={"time_constant": 0.04, "rate_limit": 1e9, "min": 0.0, "max": 12000.0})
    out = np.zeros(B.BO_SIZE)
    inp = np.array([1000.0])
    for _ in range(40):
        B.brake_step(p, s, inp, DT, out)
    assert out[B.BO_LINE] == pytest.approx(1000.0 * (1 - math.exp(-1.0)), rel=1e-9)
    # rate limit (default 40 MPa/s) on a large step
    c, p, s = make()
    inp[0] = 10000.0
    prev = 0.0
    for _ in range(100):
        B.brake_step(p, s, inp, DT, out)
        assert out[B.BO_LINE] - prev <= c.actuator.rate_limit * DT * (1 + 1e-12)
        prev = out[B.BO_LINE]
    assert out[B.BO_REAR] == pytest.approx(B.rear_pressure(c, out[B.BO_LINE]))
    assert out[B.BO_TAU_SLIDE + 2] == pytest.approx(c.rear.gain() * out[B.BO_REAR])
    assert out[B.BO_TAU_BREAK + 0] == pytest.approx(c.front.gain() * out[B.BO_LINE] * 0.45 / 0.38)


def test_four_wheel_helpers():
    c, p, s = make(pressure=800.0, stuck=True)
    th = np.array([0.001, -0.001, 0.0, 0.0])
    w = np.array([0.0, 0.0, 0.0, 0.1])
    out = np.zeros(B.BO_SIZE)
    B.brake_torques(p, s, th, w, out)
    for i in range(4):
        assert out[B.BO_TORQUE + i] == B.brake_wheel_torque(p, s, i, th[i], w[i])[0]
    assert out[B.BO_TORQUE] == pytest.approx(-c.anchor_stiffness * 0.001)
    B.brake_commit(p, s, th, w)
    assert list(s[B.BS_MODE:B.BS_MODE + 4]) == [1.0, 1.0, 1.0, 1.0]


def test_config_errors():
    with pytest.raises(ConfigError, match=r"brake\.front\.mu_static"):
        B.brake_config({"front": {"mu": 0.5, "mu_static": 0.4}})
    with pytest.raises(ConfigError, match="unknown key"):
        B.brake_config({"frnt": {}})
    with pytest.raises(ConfigError, match=r"brake\.actuator\.time_constant"):
        B.brake_config({"actuator": {"time_constant": "fast"}})
