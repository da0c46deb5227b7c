"""The shared lag block: exact first-order step response, rate limit, transport delay in whole steps,
saturation; config plumbing."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.vehicle.kit import actuators as A


def response(p, u, n, dt, y0=0.0):
    s = A.lag_state(p, dt, y0)
    return np.array([A.lag_step(p, 0, s, 0, u, dt) for _ in range(n)])


@pytest.mark.parametrize("tau,dt", [(0.05, 1e-3), (0.04, 1e-3), (0.03, 2e-3), (0.045, 1e-3)])
def test_first_order_step_reaches_63_percent_at_tau(tau, dt):
    p = A.lag_params(tau=tau)
    y = response(p, 1.0, int(round(3 * tau / dt)) + 2, dt)
    k = int(round(tau / dt))          # y[k - 1] is the output at t = k dt
    t_k = k * dt
    assert y[k - 1] == pytest.approx(1.0 - math.exp(-t_k / tau), rel=1e-12)
    # 63.2 % is crossed within one step of t = tau
    k63 = int(np.argmax(y >= 1.0 - math.exp(-1.0)))
    assert abs((k63 + 1) * dt - tau) <= dt * (1 + 1e-9)
    assert np.all(np.diff(y) > 0) and np.all(y < 1.0)


def test_zero_time_constant_is_pass_through():
    p = A.lag_params()
    assert response(p, 0.7, 3, 1e-3)[0] == 0.7


def test_rate_limit_respected():
    dt, rate = 1e-3, 20.0
    p = A.lag_params(tau=0.01, rate=rate)
    y = response(p, 1.0, 200, dt)
    assert np.all(np.abs(np.diff(np.r_[0.0, y])) <= rate * dt * (1 + 1e-12))
    assert y[0] == pytest.approx(rate * dt)       # rate-limited at first
    assert y[-1] == pytest.approx(1.0, abs=1e-6)  # then the lag takes over
    y = response(p, -1.0, 200, dt, y0=1.0)        # and downwards
    assert np.all(np.diff(np.r_[1.0, y]) >= -rate * dt * (1 + 1e-12))


@pytest.mark.parametrize("delay,dt,steps", [(0.02, 1e-3, 20), (0.0306, 1e-3, 31), (0.01, 2e-3, 5), (0.0, 1e-3, 0)])
def test_delay_exact_in_steps(delay, dt, steps):
    assert A.delay_steps(delay, dt) == steps
    p = A.lag_params(delay=delay)          # pure delay (no lag)
    s = A.lag_state(p, dt, 0.0)
    assert s.shape[0] == A.LAG_BUF + steps
    u = np.sin(np.arange(100) * 0.37) + 2.0
    y = np.array([A.lag_step(p, 0, s, 0, x, dt) for x in u])
    assert np.array_equal(y[steps:], u[:100 - steps])
    assert np.all(y[:steps] == 0.0)
    # delay + lag: the lag's step response shifted by exactly `steps`
    p2 = A.lag_params(tau=0.05, delay=delay)
    y2 = response(p2, 1.0, 60 + steps, dt)
    y_nodelay = response(A.lag_params(tau=0.05), 1.0, 60, dt)
    assert np.array_equal(y2[steps:], y_nodelay) and np.all(y2[:steps] == 0.0)


def test_saturation_of_command_and_output():
    p = A.lag_params(tau=0.02, lo=-0.5, hi=1.5)
    y = response(p, 4.0, 400, 1e-3)
    assert np.all(y <= 1.5) and y[-1] == pytest.approx(1.5, abs=1e-6)
    # the lag heads for the clipped command (no extra speed from an out-of-range command)
    assert y[19] == pytest.approx(1.5 * (1 - math.exp(-1.0)), rel=1e-12)
    assert A.saturate(3.0, -1.0, 2.0) == 2.0 and A.saturate(-3.0, -1.0, 2.0) == -1.0
    assert A.rate_limit(0.0, 1.0, 10.0, 0.01) == pytest.approx(0.1)


def _act():
    return A.LagConfig(time_constant=0.05, min=0.0, max=2.0)


@A.pydantic_config
@dataclass(frozen=True)
class _Section:
    gain: float = 1.0
    act: A.LagConfig = field(default_factory=_act)

    def __post_init__(self):
        A.check(self.gain > 0, "gain", self.gain, "expected > 0")


def test_config_plumbing():
    s = A.part_config(_Section, {"act": {"rate_limit": 3.0}}, "sec")
    assert s.act == A.LagConfig(time_constant=0.05, rate_limit=3.0, min=0.0, max=2.0)   # merged over the default
    with pytest.raises(ConfigError, match=r"sec\.gain = -1\.0"):
        A.part_config(_Section, {"gain": -1.0}, "sec")
    with pytest.raises(ConfigError, match=r"sec\.act\.max"):
        A.part_config(_Section, {"act": {"min": 3.0}}, "sec")
    with pytest.raises(ConfigError, match=r"sec\.act\.delay = 'x'"):
        A.part_config(_Section, {"act": {"delay": "x"}}, "sec")
    with pytest.raises(ConfigError, match=r"unknown key"):
        A.part_config(_Section, {"gian": 2.0}, "sec")
    assert A.part_config(_Section, None, "sec") == _Section()
