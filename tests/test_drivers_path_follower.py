"""Closed-loop lateral driver (drivers/path_follower.py) on a kinematic bicycle (reference point at
the rear axle, exact arc integration over each 1 ms step, constant speed)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.base import I_STEER, NINPUT, NSTATE, DriverView
from drivers.path_follower import PathPar, PathState, circle_points, path_follower, path_follower_step

DT = 1e-3
WB = 2.6      # m
RATIO = 16.0


def simulate(pf, x, y, yaw, v, t_end):
    """Returns rear-axle x, y, yaw, steering-wheel command, the follower's arc length and cross-track
    error, per step."""
    n = int(round(t_end / DT))
    state = np.zeros(NSTATE)
    out = np.zeros(NINPUT)
    X, Y, H, SW, S, E = (np.empty(n) for _ in range(6))
    for k in range(n):
        state[DriverView.SPEED], state[DriverView.X], state[DriverView.Y], state[DriverView.YAW] = v, x, y, yaw
        path_follower_step(pf, k * DT, state, out)
        sw = out[I_STEER]
        w = v * math.tan(sw / RATIO) / WB
        if abs(w) > 1e-12:
            yaw2 = yaw + w * DT
            x += v / w * (math.sin(yaw2) - math.sin(yaw))
            y -= v / w * (math.cos(yaw2) - math.cos(yaw))
            yaw = yaw2
        else:
            x += v * DT * math.cos(yaw)
            y += v * DT * math.sin(yaw)
        X[k], Y[k], H[k], SW[k], S[k], E[k] = x, y, yaw, sw, pf.st[PathState.S], pf.st[PathState.E]
    return X, Y, H, SW, S, E


def reference_point(method, X, Y, H):
    """The point each law steers onto the path: rear axle (pure pursuit), front axle (Stanley)."""
    if method == "stanley":
        return X + WB * np.cos(H), Y + WB * np.sin(H)
    return X, Y


@pytest.mark.parametrize("method", ["pure_pursuit", "stanley"])
def test_straight_line_with_initial_offset(method):
    pf = path_follower([0.0, 300.0], [0.0, 0.0], method=method, wheelbase=WB, steering_ratio=RATIO)
    X, Y, H, SW, S, E = simulate(pf, 0.0, 1.0, 0.0, 10.0, 6.0)   # 1 m left of the line, parallel
    px, py = reference_point(method, X, Y, H)
    after = X > 20.0                                           # after 20 m travelled
    assert np.max(np.abs(py[after])) < 0.05
    assert abs(py[-1]) < 0.005
    assert SW[0] <= 0.0 and SW.min() < 0.0                     # it steers right (negative) towards the line


@pytest.mark.parametrize("method", ["pure_pursuit", "stanley"])
def test_circle_radius_30(method):
    R = 30.0
    cx, cy = circle_points(R, spacing=0.5, center=(0.0, R))    # counter-clockwise, starting at the origin
    pf = path_follower(cx, cy, method=method, closed=True, wheelbase=WB, steering_ratio=RATIO)
    X, Y, H, SW, S, E = simulate(pf, 0.0, 0.0, 0.0, 10.0, 30.0)   # 1.6 laps
    px, py = reference_point(method, X, Y, H)
    err = np.hypot(px, py - R) - R
    T = DT * np.arange(X.size)
    steady = T > 12.0                                          # after about two thirds of a lap
    assert np.max(np.abs(err[steady])) < 0.10
    # steady steering: road-wheel angle of the kinematic car on that circle (rear axle radius)
    r_rear = R if method == "pure_pursuit" else math.sqrt(R * R - WB * WB)
    assert np.mean(SW[steady]) / RATIO == pytest.approx(math.atan(WB / r_rear), rel=0.01)
    assert np.max(np.abs(E[steady])) < 0.10                    # the follower's own error estimate agrees


def test_self_crossing_path_keeps_its_branch():
    # a figure of eight (lemniscate, 40 m lobes) crosses itself at the origin: tracking the previous
    # nearest index must keep the driver on its branch through the crossing
    a = 40.0
    u = np.linspace(0.0, 2.0 * math.pi, 801)[:-1]
    x = a * np.cos(u) / (1.0 + np.sin(u) ** 2)
    y = a * np.sin(u) * np.cos(u) / (1.0 + np.sin(u) ** 2)
    pf = path_follower(x, y, closed=True, wheelbase=WB, steering_ratio=RATIO, la_min=4.0)
    h0 = math.atan2(y[1] - y[0], x[1] - x[0])
    length = pf.par[PathPar.LENGTH]
    X, Y, H, SW, S, E = simulate(pf, x[0], y[0], h0, 8.0, 30.0)   # 240 m: crosses the origin 2 times
    ds = np.diff(S)
    ds[ds < -0.5 * length] += length                           # lap wrap
    assert np.all(ds > 0.0) and np.all(ds < 2.0 * 8.0 * DT)    # arc length only moves forward, smoothly
    assert np.sum(ds) == pytest.approx(240.0, rel=0.02)
    assert np.max(np.abs(E[DT * np.arange(E.size) > 3.0])) < 0.3  # on the path, including the crossings


def test_angle_and_rate_limits():
    pf = path_follower([0.0, 100.0], [0.0, 0.0], wheelbase=WB, steering_ratio=RATIO,
                       max_wheel_angle=0.4, max_rate=5.0)
    state = np.zeros(NSTATE)
    out = np.zeros(NINPUT)
    # far left, heading away
    state[DriverView.SPEED], state[DriverView.X], state[DriverView.Y], state[DriverView.YAW] = 5.0, 0.0, 8.0, 0.5
    sw = []
    for k in range(2000):
        path_follower_step(pf, k * DT, state, out)
        sw.append(out[I_STEER])
    sw = np.array(sw)
    assert pf.st[PathState.DELTA] < -0.4                               # the law asks for more than the limit
    assert sw[0] == 0.0                                         # starts from the centred wheel
    assert np.max(np.abs(np.diff(sw))) <= 5.0 * DT * (1.0 + 1e-9)
    assert sw[-1] == pytest.approx(-0.4 * RATIO)                # held at the angle limit


def test_nearest_index_tracking_amortised():
    # a long, finely sampled path: after the first call each step only moves the tracked index by the
    # segments actually travelled
    n = 20001
    xs = np.linspace(0.0, 2000.0, n)
    pf = path_follower(xs, 0.5 * np.sin(xs / 50.0), wheelbase=WB, steering_ratio=RATIO)
    state = np.zeros(NSTATE)
    out = np.zeros(NINPUT)
    state[DriverView.SPEED] = 20.0
    idx = []
    for k in range(200):
        state[DriverView.X] = 20.0 * k * DT + 1000.0
        path_follower_step(pf, k * DT, state, out)
        idx.append(pf.st[PathState.IDX])
    d = np.diff(idx)
    assert idx[0] == pytest.approx(10000, abs=1) and np.all((d >= 0) & (d <= 1))


@pytest.mark.parametrize("kw", [dict(x=[0.0], y=[0.0]), dict(x=[0.0, 1.0], y=[0.0]),
                                dict(x=[0.0, 0.0, 1.0], y=[0.0, 0.0, 0.0]), dict(x=[0, 1], y=[0, 0], method="lqr"),
                                dict(x=[0, 1], y=[0, 0], wheelbase=0.0),
                                dict(x=[0, 1], y=[0, 0], la_min=5.0, la_max=2.0)])
def test_invalid_paths(kw):
    with pytest.raises(ValueError):
        path_follower(**kw)
