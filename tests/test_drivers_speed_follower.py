"""Closed-loop longitudinal driver (drivers/speed_follower.py) on a 1-D point-mass car:

    m dv/dt = k_throttle * throttle - k_brake * brake - c0 - c2 v^2 + m g sin(slope)

with first-order actuator lags; the brake and the rolling resistance act as friction at standstill
(they cannot push the car backwards)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.base import I_BRAKE, I_THROTTLE, NINPUT, NSTATE, DriverView
from drivers.speed_follower import SpeedFollowerParams, SpeedState, speed_follower, speed_follower_step

DT = 1e-3
M = 1300.0           # kg
K_THR = 3700.0       # N per rad of throttle (about 4 m/s^2 at 1.4 rad)
K_BRK = 1.6          # N per kPa (about 1 g at 8000 kPa)
C0 = 150.0           # N, rolling resistance
C2 = 0.42            # N/(m/s)^2, aerodynamic drag
TAU = 0.1            # s, throttle and brake actuator lags
G = 9.81

# the follower's pedal gains matched to this car (demand in m/s^2 -> pedal)
PARAMS = SpeedFollowerParams(throttle_gain=M / K_THR, brake_gain=M / K_BRK)


def simulate(sf, t_end, v0=0.0, slope=0.0):
    """Returns time, speed, throttle and brake commands (arrays)."""
    n = int(round(t_end / DT))
    state = np.zeros(NSTATE)
    out = np.zeros(NINPUT)
    v = v0
    thr = brk = 0.0
    T = np.empty(n)
    V = np.empty(n)
    TH = np.empty(n)
    BR = np.empty(n)
    a_grade = G * math.sin(slope)
    for k in range(n):
        t = k * DT
        state[DriverView.SPEED] = v
        speed_follower_step(sf, t, state, out)
        T[k], V[k], TH[k], BR[k] = t, v, out[I_THROTTLE], out[I_BRAKE]
        thr += (out[I_THROTTLE] - thr) * DT / TAU
        brk += (out[I_BRAKE] - brk) * DT / TAU
        drive = K_THR * thr - C2 * v * v + M * a_grade
        resist = K_BRK * brk + C0
        if v > 0.0 or drive > resist:
            v = max(v + (drive - resist) / M * DT, 0.0)
        else:
            v = 0.0
    return T, V, TH, BR


def pedal_switches(TH, BR):
    """How often the driver goes from the throttle to the brake or back (coasting ignored)."""
    side = np.where(TH > 0.0, 1, np.where(BR > 0.0, -1, 0))
    side = side[side != 0]
    return int(np.count_nonzero(np.diff(side)))


def test_reaches_holds_and_stops_without_chatter():
    # rest (held) -> 20 m/s at 2 m/s^2 -> hold 28 s -> stop at 2 m/s^2 -> held at zero
    sf = speed_follower([0.0, 2.0, 12.0, 40.0, 50.0], [0.0, 0.0, 20.0, 20.0, 0.0], params=PARAMS)
    T, V, TH, BR = simulate(sf, 60.0)
    # held by the brake before the target rises
    assert np.all(V[T < 2.0] == 0.0)
    assert BR[0] == BR[T < 2.0][-1] == pytest.approx(PARAMS.hold_pressure)
    # follows the acceleration ramp closely (feed-forward), reaches and holds the target within 1 %
    ramp = (T > 4.0) & (T < 12.0)
    assert np.max(np.abs(V[ramp] - 2.0 * (T[ramp] - 2.0))) < 0.5
    hold = (T > 15.0) & (T < 40.0)
    assert np.max(np.abs(V[hold] - 20.0)) < 0.01 * 20.0
    assert abs(V[int(39.9 / DT)] - 20.0) < 0.002 * 20.0           # settled
    # exactly two pedal changes: hold brake -> throttle at the start, throttle -> brake for the stop
    assert pedal_switches(TH, BR) == 2
    assert np.all(BR[hold] == 0.0) and np.all(TH[(T > 40.5)] == 0.0)
    # stops and stays stopped, held by the hold pressure
    stopped = T > 53.0
    assert np.all(V[stopped] == 0.0)
    assert np.all(TH[stopped] == 0.0)
    assert BR[-1] == pytest.approx(PARAMS.hold_pressure)
    assert V[int(50.5 / DT)] < 1.0                                    # stopped close to the target's stop


def test_no_chatter_when_holding_speed_needs_light_braking():
    # downhill 3 %: at 15 m/s gravity beats drag and rolling resistance, so holding the speed needs a
    # little brake, a demand inside the dead band; the driver settles on the brake without toggling
    sf = speed_follower([0.0], [15.0], params=PARAMS)
    T, V, TH, BR = simulate(sf, 40.0, v0=15.0, slope=math.atan(0.03))
    late = T > 10.0
    assert np.max(np.abs(V[late] - 15.0)) < 0.01 * 15.0
    assert pedal_switches(TH[late], BR[late]) == 0
    assert np.all(BR[late] > 0.0) and np.all(TH[late] == 0.0)
    assert pedal_switches(TH, BR) <= 1


def test_anti_windup_limits_overshoot_at_full_throttle():
    # a target step the car cannot follow (full throttle for seconds): without anti-windup the
    # integrator would overshoot by metres per second
    sf = speed_follower([0.0, 1.0, 1.001], [10.0, 10.0, 25.0], params=PARAMS)
    T, V, TH, BR = simulate(sf, 30.0, v0=10.0)
    sat = (T > 1.5) & (T < 2.5)
    assert np.all(TH[sat] == pytest.approx(PARAMS.throttle_max))     # saturated while catching up
    assert V.max() < 25.0 + 0.5
    assert np.max(np.abs(V[T > 15.0] - 25.0)) < 0.01 * 25.0
    assert pedal_switches(TH[T > 1.0], BR[T > 1.0]) == 0


def test_target_over_distance():
    # 10 m/s for the first 100 m, then slowing to 5 m/s at 200 m, held to the end
    sf = speed_follower([0.0, 100.0, 200.0], [10.0, 10.0, 5.0], by="distance", params=PARAMS)
    T, V, TH, BR = simulate(sf, 40.0, v0=10.0)
    dist = np.concatenate(([0.0], np.cumsum(0.5 * (V[1:] + V[:-1]) * DT)))
    assert sf.st[SpeedState.DIST] == pytest.approx(dist[-1] + V[-1] * 0.0, rel=1e-6)   # its odometer agrees
    for d, v_ref, tol in ((80.0, 10.0, 0.1), (150.0, 7.5, 0.3), (260.0, 5.0, 0.05)):
        i = int(np.searchsorted(dist, d))
        assert abs(V[i] - v_ref) < tol, (d, V[i])


def test_restart_after_time_goes_back_resets():
    sf = speed_follower([0.0], [5.0], params=PARAMS)
    simulate(sf, 2.0, v0=0.0)
    T, V, TH, BR = simulate(sf, 2.0, v0=0.0)     # time restarts at 0: fresh controller state
    assert TH[0] == pytest.approx(min(PARAMS.kp * 5.0 * PARAMS.throttle_gain, PARAMS.throttle_max))


@pytest.mark.parametrize("kw", [dict(target_x=[0, 1], target_v=[1.0]), dict(target_x=[0, 0], target_v=[1, 1]),
                                dict(target_x=[0], target_v=[-1.0]), dict(target_x=[0], target_v=[1], by="x"),
                                dict(target_x=[0], target_v=[1], kp=-1.0),
                                dict(target_x=[0], target_v=[1], brake_gain=0.0)])
def test_invalid_parameters(kw):
    with pytest.raises(ValueError):
        speed_follower(**kw)
