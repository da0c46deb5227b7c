"""Steer-by-wire against analytic results: unloaded steady state, static torsion-bar torque under a rack
force, motor torque limit, rack kinematics consistent with the step, co-simulation with an inertial
linkage (stable with the linkage-mass estimate, unstable without it)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.vehicle.kit import steering as S

DT = 1e-3


def setup(**cfg):
    c = S.steering_config(cfg or None)
    p = S.steering_params(c)
    return c, p, S.steering_state(p, DT)


def simulate(p, s, cmd, force, n):
    out = np.zeros(S.SO_SIZE)
    inp = np.array([cmd, force])
    hist = np.zeros((n, S.SO_SIZE))
    for k in range(n):
        S.steering_step(p, s, inp, DT, out)
        hist[k] = out
    return hist


def test_unloaded_steady_state_follows_command():
    c, p, s = setup(linkage_mass=0.0)    # the force input here has no inertial part
    h = simulate(p, s, 0.5, 0.0, 6000)
    last = h[-1]
    assert last[S.SO_SW_ANGLE] == pytest.approx(0.5, abs=1e-7)
    assert abs(last[S.SO_TORQUE]) < 1e-9
    assert abs(last[S.SO_MOTOR_TORQUE]) < 1e-9
    assert last[S.SO_RACK_POS] == pytest.approx(0.5 * c.rack_travel_per_rad, rel=1e-9)
    assert abs(last[S.SO_RACK_VEL]) < 1e-9 and abs(last[S.SO_RACK_ACC]) < 1e-6
    # a reasonably quick, well damped position loop
    assert np.argmax(h[:, S.SO_SW_ANGLE] > 0.45) * DT < 0.1
    assert h[:, S.SO_SW_ANGLE].max() < 0.5 * 1.1


@pytest.mark.parametrize("force", [1500.0, -800.0])
def test_rack_force_static_torque(force):
    c, p, s = setup(linkage_mass=0.0)
    last = simulate(p, s, 0.3, force, 6000)[-1]
    rp = c.rack_travel_per_rad
    assert last[S.SO_TORQUE] == pytest.approx(force * rp, rel=1e-2)
    assert last[S.SO_TORQUE] == pytest.approx(force * rp, rel=1e-8)        # (exactly, in fact)
    # the integral action keeps the steering wheel on the command; the pinion lags by the twist
    assert last[S.SO_SW_ANGLE] == pytest.approx(0.3, abs=1e-7)
    twist = force * rp / c.torsion_bar_stiffness
    assert last[S.SO_PINION_ANGLE] == pytest.approx(0.3 - twist, abs=1e-7)
    # the motor carries it through the reduction
    motor = force * rp / (c.reduction_ratio * c.reduction_efficiency)
    assert last[S.SO_MOTOR_TORQUE] == pytest.approx(motor, rel=1e-8)


def test_motor_torque_limit_respected():
    c, p, s = setup(linkage_mass=0.0)
    h = simulate(p, s, 3.0, 2500.0, 3000)
    tm = h[:, S.SO_MOTOR_TORQUE]
    assert np.all(np.abs(tm) <= c.motor_torque_limit * (1 + 1e-12))
    assert np.max(np.abs(tm)) == pytest.approx(c.motor_torque_limit)     # it did saturate
    assert h[-1, S.SO_SW_ANGLE] == pytest.approx(3.0, abs=1e-6)
    # a load beyond the motor's capacity: the limit holds and the wheel is pushed back
    c, p, s = setup(linkage_mass=0.0)
    cap = S.describe(c)["rack_force_capacity_N"]
    h = simulate(p, s, 1.0, 1.5 * cap, 2000)
    assert np.all(np.abs(h[:, S.SO_MOTOR_TORQUE]) <= c.motor_torque_limit * (1 + 1e-12))
    assert h[-1, S.SO_SW_ANGLE] < 0.0


def test_rack_outputs_consistent_with_the_step():
    c, p, s = setup(linkage_mass=0.0)
    h = simulate(p, s, 0.8, 500.0, 400)
    x, v, a = h[:, S.SO_RACK_POS], h[:, S.SO_RACK_VEL], h[:, S.SO_RACK_ACC]
    assert np.allclose(np.diff(x), DT * v[1:], rtol=0, atol=1e-15)
    assert np.allclose(np.diff(v), DT * a[1:], rtol=0, atol=1e-12)
    assert np.allclose(x, c.rack_travel_per_rad * h[:, S.SO_PINION_ANGLE], rtol=1e-15, atol=0)


def coupled(linkage_mass, m_link=120.0, k_align=2.0e4, n=4000):
    """Steering + a linkage driven through the rack (mass m_link at the rack, aligning stiffness
    k_align), its force fed back one step late as a multibody model would."""
    c, p, s = setup(linkage_mass=linkage_mass)
    out = np.zeros(S.SO_SIZE)
    force = 0.0
    for _ in range(n):
        S.steering_step(p, s, np.array([0.5, force]), DT, out)
        force = m_link * out[S.SO_RACK_ACC] + k_align * out[S.SO_RACK_POS]
        if not abs(force) < 1e7:
            return c, None, force
    return c, out, force


def test_coupled_linkage_stable_with_mass_estimate():
    c, out, force = coupled(100.0, n=6000)
    assert out is not None
    assert out[S.SO_SW_ANGLE] == pytest.approx(0.5, abs=1e-7)
    assert out[S.SO_TORQUE] == pytest.approx(force * c.rack_travel_per_rad, rel=1e-6)
    # without the estimate the explicit force feedback of a heavy linkage diverges
    with np.errstate(all="ignore"):
        c, out, force = coupled(0.0, n=1000)
    assert out is None


def test_command_delay_and_bounds():
    c, p, s = setup(linkage_mass=0.0, command={"delay": 0.02, "min": -2.0, "max": 2.0})
    h = simulate(p, s, 5.0, 0.0, 100)
    assert np.all(h[:19, S.SO_CMD] == 0.0) and np.all(h[20:, S.SO_CMD] == 2.0)


def test_describe_and_config_errors():
    d = S.describe()
    assert d["rack_travel_per_steering_wheel_turn_m"] == pytest.approx(2 * math.pi * 6.4e-3)
    assert d["torsion_bar_Nm_per_deg"] == pytest.approx(1.5)
    with pytest.raises(ConfigError, match=r"steering\.rack_travel_per_rad"):
        S.steering_config({"rack_travel_per_rad": 0.04 * 2 * math.pi * 10})
    with pytest.raises(ConfigError, match=r"steering\.kp"):
        S.steering_config({"kp": -1.0})
