"""Motorcycle rider (rtsim/vehicle/motorcycle/rider.py) and reference paths (rtsim/road/paths.py):
curvilinear coordinates, curvature, lean reference, reaction delay, speed PI on a point mass, and the closed loop on the
linearised benchmark bicycle of Meijaard et al. (2007).

Benchmark bicycle in ISO 8855. The paper's axes are x forward, y right, z down: its roll phi_M is
positive leaning right (as ours), its steer delta_M and yaw psi_M are positive to the right (ours: to
the left). With S = diag(1, -1), q = [phi, delta] = S q_M and the inputs [T_phi, tau] = S [T_phi,
T_delta_M], the equations M q_M'' + v C1 q_M' + (g K0 + v^2 K2) q_M = f_M become
(S M S) q'' + v (S C1 S) q' + (g S K0 S + v^2 S K2 S) q = [T_phi, tau]. The yaw rate keeps its form,
r = (v delta + c delta') cos(lambda) / w, in ISO signs; the rear contact point (the reference point,
no side slip) moves at v along the heading.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial import cKDTree

from drivers import rider as R
from rtsim.road.paths import circle_points, double_lane_change, figure_eight, polyline, vertex_curvature
from drivers.rider import (NRO, NRV, RO_BRAKE_F, RO_BRAKE_R, RO_THROTTLE, RO_TORQUE, RV_DELTA, RV_DELTADOT,
                           RV_PHI, RV_PHIDOT, RV_R, RV_T, RV_U, RV_X, RV_Y, RV_YAW, rider, rider_step)

G = 9.81
DT = 1e-3

# Meijaard, Papadopoulos, Ruina, Schwab (2007), benchmark bicycle
M_B = np.array([[80.81722, 2.31941332208709], [2.31941332208709, 0.29784188199686]])
C1_B = np.array([[0.0, 33.86641391492494], [-0.85035641456978, 1.68540397397560]])
K0_B = np.array([[-80.95, -2.59951685249872], [-2.59951685249872, -0.80329488458618]])
K2_B = np.array([[0.0, 76.59734589573222], [0.0, 2.65431523794604]])
W_B, C_B, LAM_B = 1.02, 0.08, math.pi / 10.0
S_ISO = np.diag([1.0, -1.0])


def view_of(t=0.0, x=0.0, y=0.0, yaw=0.0, u=0.0, r=0.0, phi=0.0, phidot=0.0, delta=0.0, deltadot=0.0):
    v = np.zeros(NRV)
    v[RV_T], v[RV_X], v[RV_Y], v[RV_YAW], v[RV_U], v[RV_R] = t, x, y, yaw, u, r
    v[RV_PHI], v[RV_PHIDOT], v[RV_DELTA], v[RV_DELTADOT] = phi, phidot, delta, deltadot
    return v


def one_call(rd, **kw):
    out = np.zeros(NRO)
    R.reset(rd)
    rider_step(rd, view_of(**kw), out)
    return out


# --------------------------------------------------------------------------------------------------
# Paths and curvilinear coordinates


@pytest.mark.parametrize("y, yaw", [(1.2, 0.1), (-0.7, -0.3)])
def test_curvilinear_coordinates_straight_line(y, yaw):
    rd = rider([0.0, 100.0], [0.0, 0.0])
    one_call(rd, x=30.0, y=y, yaw=yaw, u=5.0)
    assert rd.st[R.RiderState.S] == pytest.approx(30.0, abs=1e-12)
    assert rd.st[R.RiderState.N] == pytest.approx(y, abs=1e-12)          # left of the path positive
    assert rd.st[R.RiderState.PSI_E] == pytest.approx(yaw, abs=1e-12)    # yaw - path heading
    la = 1.0 + 0.6 * 5.0
    rd2 = rider([0.0, 100.0], [0.0, 0.0], la_min=1.0, la_time=0.6)
    one_call(rd2, x=30.0, y=y, yaw=yaw, u=5.0)
    assert rd2.st[R.RiderState.E_LA] == pytest.approx(y + la * math.sin(yaw), abs=1e-12)


def test_curvilinear_coordinates_circle():
    rad = 25.0
    cx, cy = circle_points(rad, spacing=0.25)                  # counter-clockwise, centre at the origin
    rd = rider(cx, cy, closed=True)
    n = cx.size
    for k, d, he in [(n // 8, 0.4, 0.05), (n // 3, -0.9, -0.1), (3 * n // 4, 0.0, 0.2)]:
        a = -0.5 * math.pi + 2.0 * math.pi * k / n             # angle of vertex k
        rr = rad - d                                           # left of a left turn: inside
        tangent = a + 0.5 * math.pi
        one_call(rd, x=rr * math.cos(a), y=rr * math.sin(a), yaw=tangent + he, u=5.0)
        arc = 2.0 * math.pi * rad * k / n
        assert rd.st[R.RiderState.S] == pytest.approx(arc, rel=1e-4)
        assert rd.st[R.RiderState.N] == pytest.approx(d, abs=1e-3)
        assert rd.st[R.RiderState.PSI_E] == pytest.approx(he, abs=2e-4)     # heading interpolated on the chord


def test_curvature_of_a_sampled_circle():
    for rad, ccw in [(10.0, True), (40.0, False)]:
        cx, cy = circle_points(rad, spacing=0.7, ccw=ccw)
        px, py, ps, hd, seg, closed = polyline(cx, cy, closed=True)
        for smooth in (0.0, 5.0):
            k = vertex_curvature(px, py, closed, smooth)
            assert np.allclose(k, (1.0 if ccw else -1.0) / rad, rtol=1e-3)


def test_figure_eight_geometry():
    rad, spacing = 15.0, 0.5
    for straight in (0.0, 10.0):
        x, y = figure_eight(rad, straight=straight, spacing=spacing)
        px, py, ps, hd, seg, closed = polyline(x, y, closed=True)
        assert np.max(seg) <= spacing + 1e-9 and np.min(seg) > 0.2 * spacing   # closes on itself, evenly
        assert ps[-1] == pytest.approx(2.0 * straight + 2.0 * rad * (math.pi + 2.0 * math.atan2(rad, straight / 2)),
                                       rel=1e-3)
        turn = np.diff(np.unwrap(np.arctan2(np.diff(py), np.diff(px))))
        assert np.max(np.abs(turn)) < 1.01 * spacing / rad      # heading continuous, no corner
        k = vertex_curvature(px, py, closed)[:-1]
        assert x[0] == 0.0 and y[0] == 0.0 and abs(hd[0]) < spacing / rad   # origin, heading +x
        left = k > 0.0
        on_loop = np.abs(np.abs(k) - 1.0 / rad) < 1e-3 / rad
        loops = 2.0 * rad * (math.pi + 2.0 * math.atan2(rad, straight / 2))
        assert np.sum(on_loop) >= k.size * loops / ps[-1] - 4   # curvature +-1/R on the loops ...
        assert np.sum(~on_loop & (np.abs(k) > 1e-9)) <= 4       # ... 0 on the straights, else only at joins
        assert abs(np.sum(left & on_loop) - np.sum(~left & on_loop)) <= 2   # one loop each way
    # left_first: the first loop turns left (curvature +1/R just after the start)
    x, y = figure_eight(rad, straight=0.0, left_first=True)
    assert vertex_curvature(*polyline(x, y, True)[:2], True)[5] == pytest.approx(1.0 / rad, rel=1e-3)
    x, y = figure_eight(rad, straight=0.0, left_first=False)
    assert vertex_curvature(*polyline(x, y, True)[:2], True)[5] == pytest.approx(-1.0 / rad, rel=1e-3)


def test_double_lane_change_geometry():
    off, tr = 3.5, 50.0
    x, y = double_lane_change(off, entry=40.0, transition=tr, hold=30.0, exit=40.0, spacing=0.25)
    assert y[0] == 0.0 and y[-1] == pytest.approx(0.0, abs=1e-12) and np.max(y) == pytest.approx(off)
    assert x[-1] == pytest.approx(40.0 + 2 * tr + 30.0 + 40.0)
    px, py, ps, hd, seg, closed = polyline(x, y)
    k = vertex_curvature(px, py, closed)
    assert np.max(k) == pytest.approx(2.0 * math.pi * off / tr ** 2, rel=0.02)
    assert np.max(np.abs(np.diff(k))) < 0.05 * np.max(k)       # curvature continuous (no jump)
    assert np.all(k[x < 40.0] == pytest.approx(0.0, abs=1e-12))


def test_lean_reference_on_a_circle():
    rad, u = 30.0, 12.0
    cx, cy = circle_points(rad, spacing=0.5, center=(0.0, rad))   # left turn starting at the origin
    rd = rider(cx, cy, closed=True, preview_dist=3.0, preview_time=0.2)
    one_call(rd, yaw=0.0, u=u, r=u / rad)
    ref = -math.atan(u * u / (rad * G))
    assert ref < 0.0                                           # leaning left into a left turn
    assert rd.st[R.RiderState.KAPPA] == pytest.approx(1.0 / rad, rel=1e-3)
    assert rd.st[R.RiderState.PHI_FF] == pytest.approx(ref, rel=1e-3)
    assert rd.st[R.RiderState.PHI_REF] == pytest.approx(ref, rel=1e-3)    # on the path: no correction
    assert R.roll_reference(u, 1.0 / rad) == pytest.approx(ref)
    # the preview looks ahead: on a straight leading into a left bend the lean starts before it
    x = np.concatenate((np.linspace(0.0, 50.0, 101), 50.0 + rad * np.sin(np.linspace(0.01, 1.0, 60))))
    y = np.concatenate((np.zeros(101), rad * (1.0 - np.cos(np.linspace(0.01, 1.0, 60)))))
    rd = rider(x, y, preview_dist=0.0, preview_time=0.5)
    one_call(rd, x=46.0, u=u)                                  # 6 m preview reaches the bend
    assert rd.st[R.RiderState.KAPPA] == pytest.approx(1.0 / rad, rel=0.01) and rd.st[R.RiderState.PHI_FF] < 0.0
    one_call(rd, x=40.0, u=u)                                  # ... not yet
    assert rd.st[R.RiderState.KAPPA] == pytest.approx(0.0, abs=1e-9)


def test_signs_of_the_corrections():
    """Left of the path or heading left of it: lean right (phi_ref > 0), so counter-steer left
    (positive torque); leaning further right than asked: negative torque."""
    rd = rider([0.0, 200.0], [0.0, 0.0])
    for pos in (dict(y=0.5), dict(yaw=0.1), dict(y=-0.5, yaw=0.0)):
        one_call(rd, x=50.0, u=8.0, **pos)
        side = 1.0 if pos.get("y", 0.0) >= 0.0 else -1.0
        assert side * rd.st[R.RiderState.PHI_REF] > 0.0 and side * rd.st[R.RiderState.TAU_CMD] > 0.0
    one_call(rd, x=50.0, u=8.0, phi=0.1)
    assert rd.st[R.RiderState.PHI_REF] == 0.0
    assert rd.st[R.RiderState.TAU_CMD] == pytest.approx(-0.1 * rd.par[R.RiderPar.P_ROLL])
    one_call(rd, x=50.0, u=8.0, phidot=0.1)
    assert rd.st[R.RiderState.TAU_CMD] == pytest.approx(-0.1 * rd.par[R.RiderPar.D_ROLL])
    # a big error: the lean correction is clipped
    one_call(rd, x=50.0, u=8.0, y=30.0)
    assert rd.st[R.RiderState.PHI_REF] == pytest.approx(rd.par[R.RiderPar.MAX_CORR])
    # the report's variant: the path correction goes to the torque
    rd = rider([0.0, 200.0], [0.0, 0.0], path_to_torque=True, p_n=5.0, p_psi=0.0, d_n=0.0)
    one_call(rd, x=50.0, u=8.0, y=0.5)
    assert rd.st[R.RiderState.PHI_REF] == 0.0 and rd.st[R.RiderState.TAU_CMD] == pytest.approx(5.0 * 0.5)


# --------------------------------------------------------------------------------------------------
# Reaction delay, torque limits, speed PI


def test_reaction_delay_is_a_pure_transport_delay():
    delay, period = 0.05, 1e-3
    rd = rider([0.0, 200.0], [0.0, 0.0], delay=delay, period=period, max_torque_rate=1e6, max_torque=1e3)
    out = np.zeros(NRO)
    k0, nd = 100, round(delay / period)
    cmd, got = [], []
    for k in range(300):
        phi = 0.0 if k < k0 else -0.05                          # the step in the demanded torque
        rider_step(rd, view_of(t=k * period, x=5.0 + k * period, u=1.0, phi=phi), out)
        cmd.append(rd.st[R.RiderState.TAU])
        got.append(out[RO_TORQUE])
    cmd, got = np.array(cmd), np.array(got)
    assert cmd[k0] > cmd[k0 - 1] + 1.0                          # the demand steps at k0 ...
    assert np.all(got[:k0 + nd] == got[0])                      # ... the output holds for nd calls ...
    assert np.array_equal(got[nd:], cmd[:-nd])                  # ... and is the demand nd calls late
    assert got[k0 + nd] == cmd[k0]
    with pytest.raises(ValueError):
        rider([0.0, 1.0], [0.0, 0.0], delay=0.5, period=1e-4)   # 5000 calls: longer than the buffer


def test_torque_limits():
    rd = rider([0.0, 200.0], [0.0, 0.0], max_torque=20.0, max_torque_rate=100.0)
    out = np.zeros(NRO)
    taus = []
    for k in range(500):
        rider_step(rd, view_of(t=k * DT, x=5.0, u=5.0, phi=-1.0), out)
        taus.append(out[RO_TORQUE])
    taus = np.array(taus)
    assert taus[0] == 0.0 and np.max(np.diff(taus)) <= 100.0 * DT * (1 + 1e-9)
    assert taus[-1] == pytest.approx(20.0)


def test_speed_pi_on_a_point_mass():
    """m dv/dt = F_max throttle - (front + rear brake pressure) * (m / gain) - c v^2: the rider's
    scalings are the plant's own, within 20 %."""
    m, f_max, cd = 250.0, 2500.0, 0.3
    front_gain, rear_gain = 150.0, 300.0                       # kPa per m/s^2 each brake gives
    rd = rider([0.0, 5000.0], [0.0, 0.0], speed=([0.0, 20.0, 20.5, 40.0], [15.0, 15.0, 8.0, 8.0]),
               speed_by="time", throttle_gain=1.2 * m / f_max, front_gain=0.8 * front_gain,
               rear_gain=0.8 * rear_gain, brake_front=0.7, kp_speed=1.0, ki_speed=0.3)
    out = np.zeros(NRO)
    v, x = 5.0, 0.0
    log = []
    for k in range(int(40.0 / DT)):
        t = k * DT
        rider_step(rd, view_of(t=t, x=x, u=v), out)
        assert 0.0 <= out[RO_THROTTLE] <= 1.0 and out[RO_BRAKE_F] >= 0.0 and out[RO_BRAKE_R] >= 0.0
        assert out[RO_THROTTLE] == 0.0 or out[RO_BRAKE_F] + out[RO_BRAKE_R] == 0.0
        a = (f_max * out[RO_THROTTLE] - cd * v * v) / m - out[RO_BRAKE_F] / front_gain - out[RO_BRAKE_R] / rear_gain
        v += a * DT
        x += v * DT
        log.append((t, v, out[RO_BRAKE_F], out[RO_BRAKE_R]))
    log = np.array(log)
    t, vs = log[:, 0], log[:, 1]
    assert np.all(np.abs(vs[(t > 15.0) & (t < 20.0)] - 15.0) < 0.05)
    assert np.all(np.abs(vs[t > 35.0] - 8.0) < 0.05)
    braking = (t > 20.0) & (t < 22.0)
    assert np.max(log[braking, 2]) > 0.0 and np.max(log[braking, 3]) > 0.0    # both brakes used
    # the front share of the deceleration: 0.7
    i = np.argmax(log[:, 2])
    share = (log[i, 2] / (0.8 * front_gain)) / (log[i, 2] / (0.8 * front_gain) + log[i, 3] / (0.8 * rear_gain))
    assert share == pytest.approx(0.7)


# --------------------------------------------------------------------------------------------------
# Closed loop on the benchmark bicycle


def bicycle(v):
    """Zero-order-hold discretisation (step DT) of the benchmark bicycle at speed v in ISO signs:
    state [phi, delta, phi', delta'], input the steering torque tau (positive steering left)."""
    m = S_ISO @ M_B @ S_ISO
    k = S_ISO @ (G * K0_B + v * v * K2_B) @ S_ISO
    c = v * S_ISO @ C1_B @ S_ISO
    mi = np.linalg.inv(m)
    a = np.zeros((4, 4))
    a[:2, 2:] = np.eye(2)
    a[2:, :2] = -mi @ k
    a[2:, 2:] = -mi @ c
    b = np.zeros(4)
    b[2:] = mi[:, 1]
    e = expm(np.block([[a, b[:, None]], [np.zeros((1, 5))]]) * DT)
    return e[:4, :4], e[:4, 4]


def ride(rd, v, t_end, x=0.0, y=0.0, yaw=0.0):
    """Closed loop at constant speed v; per step: t, x, y, yaw, phi, delta, torque. Stops at a fall."""
    ad, bd = bicycle(v)
    kr = math.cos(LAM_B) / W_B
    q = np.zeros(4)
    out = np.zeros(NRO)
    n = int(round(t_end / DT))
    rec = np.zeros((n, 7))
    for k in range(n):
        r = (v * q[1] + C_B * q[3]) * kr
        rider_step(rd, view_of(k * DT, x, y, yaw, v, r, q[0], q[2], q[1], q[3]), out)
        rec[k] = (k * DT, x, y, yaw, q[0], q[1], out[RO_TORQUE])
        q = ad @ q + bd * out[RO_TORQUE]
        r2 = (v * q[1] + C_B * q[3]) * kr
        yaw2 = yaw + 0.5 * (r + r2) * DT
        ym = 0.5 * (yaw + yaw2)
        x += v * DT * math.cos(ym)
        y += v * DT * math.sin(ym)
        yaw = yaw2
        if abs(q[0]) > 1.0:
            return rec[:k + 1]
    return rec


def test_benchmark_bicycle_counter_steers():
    """Open loop: a positive (steer-left) torque step leans the bicycle right and it ends up turning
    right; the rider's roll loop relies on this sign."""
    ad, bd = bicycle(6.0)
    q = np.zeros(4)
    for _ in range(int(3.0 / DT)):
        q = ad @ q + bd * 0.5
    assert q[0] > 0.0 and q[1] < 0.0                           # leaning right, steering right


def test_closed_loop_circle():
    rad, v = 20.0, 6.0
    cx, cy = circle_points(rad, spacing=0.5, center=(0.0, rad))
    rd = rider(cx, cy, closed=True, speed=v, delay=0.02)
    rec = ride(rd, v, 20.0)
    assert rec[-1, 0] == pytest.approx(20.0 - DT)              # no fall
    err = np.hypot(rec[:, 1], rec[:, 2] - rad) - rad
    steady = rec[:, 0] > 12.0
    assert np.max(np.abs(err)) < 0.6 and np.max(np.abs(err[steady])) < 0.05
    ref = -math.atan(v * v / (rad * G))
    phi = np.mean(rec[steady, 4])
    assert phi < 0.0 and abs(phi - ref) < 0.1 * abs(ref)       # leaning left into the left turn


def test_closed_loop_double_lane_change():
    v = 6.0
    lx, ly = double_lane_change(3.5, entry=20.0, transition=25.0, hold=15.0, exit=30.0)
    rd = rider(lx, ly, speed=v, delay=0.02)
    t_end = (lx[-1] - 5.0) / v
    rec = ride(rd, v, t_end)
    assert rec[-1, 0] == pytest.approx(t_end - DT, abs=2 * DT)
    lat = rec[:, 2] - np.interp(rec[:, 1], lx, ly)
    assert np.sqrt(np.mean(lat ** 2)) < 0.2 and np.max(np.abs(lat)) < 0.5
    assert abs(lat[-1]) < 0.05 and np.max(rec[:, 2]) > 3.0     # back in its lane, after reaching the other


def test_closed_loop_figure_eight():
    rad, straight, v = 15.0, 10.0, 6.0
    fx, fy = figure_eight(rad, straight=straight)
    rd = rider(fx, fy, closed=True, speed=v, max_roll_rate=0.5)
    t_end = 1.1 * (2 * straight + 2 * rad * (math.pi + 2 * math.atan2(rad, straight / 2))) / v   # > 1 lap
    rec = ride(rd, v, t_end)
    assert rec[-1, 0] == pytest.approx(t_end - DT, abs=2 * DT)
    dx, dy = figure_eight(rad, straight=straight, spacing=0.01)
    d = cKDTree(np.c_[dx, dy]).query(rec[:, 1:3])[0]            # distance to the path
    assert np.sqrt(np.mean(d ** 2)) < 0.15 and np.max(d) < 0.4
    assert np.min(rec[:, 4]) < -0.25 and np.max(rec[:, 4]) > 0.25   # leaned both ways


# --------------------------------------------------------------------------------------------------
# Scenario files


SCENARIO = """
name = "rider_eight"
description = "figure-eight ridden by the rider"
road = "../roads/flat.toml"
duration = 10.0

[rider]
speed = 6.0
p_roll = 120.0
delay = 0.1
max_roll_rate = 0.5

[rider.figure_eight]
radius = 15.0
straight = 10.0
"""


def test_rider_section_of_a_scenario(tmp_path):
    from drivers.scenario import load_scenario
    from rtsim.errors import ConfigError

    f = tmp_path / "s.toml"
    f.write_text(SCENARIO)
    sc = load_scenario(f)
    rd = sc.rider()
    assert rd.par[R.RiderPar.P_ROLL] == 120.0 and rd.par[R.RiderPar.NDELAY] == 100 and rd.par[R.RiderPar.CLOSED] == 1.0
    assert rd.par[R.RiderPar.D_ROLL] == R.RiderParams().d_roll              # defaults for the rest
    assert rd.par[R.RiderPar.LENGTH] == pytest.approx(20.0 + 30.0 * (math.pi + 2.0 * math.atan(3.0)), rel=1e-3)
    assert rd.tab_v[0] == 6.0 and sc.driver() is not None
    f.write_text(SCENARIO.replace("p_roll = 120.0", "p_roll = -1.0"))
    with pytest.raises(ConfigError, match=r"rider.p_roll = -1.0: out of range \(allowed 0 <= p_roll <= 100000 N m/rad\)"):
        load_scenario(f)
    f.write_text(SCENARIO.replace("speed = 6.0", "speed = [5.0, 8.0]\ndistance = [0.0, 50.0]"))
    rd = load_scenario(f).rider()
    assert list(rd.tab_x) == [0.0, 50.0] and rd.par[R.RiderPar.SPEED_BY_S] == 1.0
    f.write_text(SCENARIO.replace("[rider.figure_eight]", "x = [0, 1]\ny = [0, 0]\n[rider.figure_eight]"))
    with pytest.raises(ConfigError, match=r"exactly one of"):
        load_scenario(f)
