"""Motorcycle rider: steering torque on the handlebars (plus throttle and brakes) to follow a path.

Axes and signs (ISO 8855): x forward, y left, z up; yaw positive turning left; roll phi positive
leaning right (right side down); steer angle and steering torque positive turning the handlebar to
steer left; path curvature kappa positive in a left turn.

Tracking. The path is a polyline (`rtsim.road.paths`). Each call projects the motorcycle's reference
point on it (nearest segment tracked from the previous call): arc length s, lateral offset n (left of
the path positive) and heading error psi_e = yaw - path heading. The rider looks ahead by
L = la_min + la_time u along the line of sight: the lateral error of that point from the path
tangent is e = n + L sin(psi_e). The rates come from the measured motion, not from differences:

    n' = u sin(psi_e) + v cos(psi_e)          s' = (u cos(psi_e) - v sin(psi_e)) / (1 - n kappa(s))
    psi_e' = r - kappa(s) s'                  e' = n' + L cos(psi_e) psi_e'

Lean reference. The steady turn at speed u on curvature kappa needs the lean -atan(u^2 kappa / g)
(leaning into the turn). The rider takes kappa at a preview point d = preview_dist + preview_time u
ahead of s, so he leans before the bend begins (and straightens before it ends):

    phi_0 = -atan(u^2 kappa(s + d) / g),  phi_ff = phi_0 + asin(k sin phi_0),  its rate limited to max_roll_rate

The second term is the extra lean of tyres of crown radius rho (Cossalter, Motorcycle Dynamics, ch. 2):
the contact point moves round the crown towards the inside of the turn, so the frame must lean past
phi_0 until the line from the contact to the mass centre (height h) leans by phi_0; k = rho / (h - rho)
(`tyre_lean`, 0 for knife-edge wheels).

Path correction (cascade, default). A rider corrects a path error by leaning more or less, not by a
torque of its own: a motorcycle left of its path (e > 0) or heading left of it (psi_e > 0) must turn
right, hence lean right. So the path PD shifts the lean reference:

    c = p_n e + d_n e' + p_psi psi_e + d_psi psi_e' + I_n,     I_n' = i_n e  (|I_n| <= i_n_max)
    phi_ref = clip(phi_ff + clip(c, +-max_correction), +-max_roll)

Acting through the lean keeps the roll loop in charge of balance: the path errors cannot ask for a
torque that topples the motorcycle, and the steady correction is a lean angle the rider can bound.
With `path_to_torque` the correction is instead added to the torque (the gains then in N m per m,
N m per rad; no max_correction clip), as in the report's controller.

Roll loop. Counter-steering: to lean right the rider first steers left, i.e. applies a positive torque.

    tau = p_roll (phi_ref - phi) + d_roll (phi_ff' - phi') + I_roll - d_steer delta'
    I_roll' = i_roll (phi_ref - phi)  (|I_roll| <= i_roll_max)

phi_ff' is the derivative of the (smooth) feed-forward lean, filtered with time constant tau_ref;
phi' and delta' are measured. The path correction is not differentiated again: its rates already
enter through d_n and d_psi, and differentiating them would feed the steer acceleration back. tau is clipped to +-max_torque and its rate to +-max_torque_rate.

Speed. A PI on the speed error to a target (constant, or piecewise linear over time or over the path's
arc length s, with its slope as acceleration feed-forward) gives an acceleration demand a. a > 0:
throttle = throttle_gain a (clipped to [0, 1]); a < -band: the deceleration -a is shared between the
brakes, front pressure = brake_front (-a) front_gain, rear = (1 - brake_front) (-a) rear_gain (kPa,
each clipped to brake_max); in between the rider coasts. The integrator is frozen while the pedal on
its side saturates.

Reaction delay. The outputs (torque after its limits, throttle, brakes) pass through a pure transport
delay of round(delay / period) calls (a ring buffer of NBUF rows): the rider must be called once per
`period`. A transport delay of the commands equals one of the perceived state for this controller up
to its integrators, and keeps the state it reads current. At the first call the buffer is filled
with the first command.

Model/data: `Rider` is a named tuple of arrays (path `px, py, ps, hd, seg_len`, vertex curvature
`kap`, target speed table `tab_x, tab_v`, parameters `par`, state `st`, delay buffer `buf`);
`rider_step(r, view, out)` is a compiled kernel that reads `view` (RV_*) and writes `out` (RO_*) and
allocates nothing. A call at a time earlier than the previous one restarts the rider.

The rider lives with the two-wheeler because the two-wheeler runs it inside its compiled step
(rtsim.vehicle.motorcycle.plant); its view (RV_*), outputs (RO_*), parameters (P_*) and state (ST_*) are
declared here once, and the drivers and scenarios take them from here (drivers.rider).
"""
from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import asdict, dataclass
from enum import IntEnum

import numpy as np
from pydantic import create_model

from rtsim.configfile import Strict, check_ranges, range_fields
from rtsim.jit import inline_kernel, kernel
from rtsim.mbs.model import EARTH_GRAVITY

from rtsim.road.paths import (bracket, nearest_segment, on_segment, polyline, seg_project, value_at, vertex_curvature,
                              wrap_angle)

G = EARTH_GRAVITY  # m/s^2, the gravity the rider's lean references assume
NBUF = 1024       # rows of the delay ring buffer (0.5 s at 1 ms needs 501)

# What the motorcycle reports each call (view).
RV_T = 0          # s, time
RV_X = 1          # m, reference point x, road frame
RV_Y = 2          # m, reference point y
RV_YAW = 3        # rad, yaw, positive turning left
RV_U = 4          # m/s, forward speed of the reference point
RV_V = 5          # m/s, lateral speed of the reference point in the heading frame, left positive
RV_R = 6          # rad/s, yaw rate
RV_PHI = 7        # rad, roll, positive leaning right
RV_PHIDOT = 8     # rad/s, roll rate
RV_DELTA = 9      # rad, steer angle, positive steering left
RV_DELTADOT = 10  # rad/s, steer rate
NRV = 11

# What the rider commands (out).
RO_TORQUE = 0     # N m, steering torque on the handlebars, positive steering left
RO_THROTTLE = 1   # -, throttle, 0 .. 1
RO_BRAKE_F = 2    # kPa, front brake pressure
RO_BRAKE_R = 3    # kPa, rear brake pressure
NRO = 4


class RiderPar(IntEnum):
    """The rider's parameter array (par): gains, limits, preview and path geometry."""
    P_ROLL = 0      # N m/rad
    D_ROLL = 1      # N m s/rad
    I_ROLL = 2      # N m/(rad s)
    I_ROLL_MAX = 3  # N m
    TAU_REF = 4     # s, filter of the lean feed-forward's derivative
    P_N = 5         # rad/m (N m/m with path_to_torque)
    D_N = 6         # rad s/m
    P_PSI = 7       # rad/rad
    D_PSI = 8       # rad s/rad
    I_N = 9         # rad/(m s)
    I_N_MAX = 10    # rad
    MAX_CORR = 11   # rad, clip of the path correction of the lean reference
    MAX_ROLL = 12   # rad, clip of the lean reference
    PREV_DIST = 13  # m, curvature preview distance at standstill
    PREV_TIME = 14  # s, curvature preview per unit speed
    LA_MIN = 15     # m, look-ahead distance at standstill
    LA_TIME = 16    # s, look-ahead per unit speed
    D_STEER = 17    # N m s/rad, damping of the steer rate
    MAX_TORQUE = 18  # N m
    MAX_RATE = 19   # N m/s
    KP_V = 20       # 1/s, speed PI (m/s^2 per m/s)
    KI_V = 21       # 1/s^2
    I_V_MAX = 22    # m/s^2
    THR_GAIN = 23   # s^2/m, throttle per m/s^2 of demand
    BAND = 24       # m/s^2, coasting band below zero demand
    BRAKE_FRONT = 25  # -, share of the deceleration given to the front brake
    FRONT_GAIN = 26  # kPa per m/s^2 (front)
    REAR_GAIN = 27  # kPa per m/s^2 (rear)
    BRAKE_MAX = 28  # kPa
    NDELAY = 29     # calls of reaction delay (round(delay / period))
    TO_TORQUE = 30  # 1: path correction added to the torque
    SPEED_BY_S = 31  # 1: target speed over arc length s, 0: over time
    CLOSED = 32     # 1 for a closed path
    NSEG = 33       # number of segments
    LENGTH = 34     # m, path length
    MAX_ROLL_RATE = 35  # rad/s, rate limit of the lean feed-forward
    TYRE_LEAN = 36  # -, k = rho / (h - rho) of the tyres' crown radius rho and the mass centre's height h


NPAR = len(RiderPar)     # slots in par


class RiderState(IntEnum):
    """The rider's state array (st): memory between calls and diagnostics."""
    INIT = 0
    T = 1          # s, time of the last call
    IDX = 2        # segment nearest to the reference point at the last call
    HEAD = 3       # next row of the delay buffer
    TAU = 4        # N m, last torque after limits (before the delay)
    I_ROLL = 5     # N m, roll integrator
    I_N = 6        # rad, path integrator
    I_V = 7        # m/s^2, speed integrator
    PHI_FF_PREV = 8
    DPHI_FF = 9    # rad/s, filtered derivative of the lean feed-forward phi_ff
    S = 10         # diagnostics: arc length of the reference point, m
    N = 11         # diagnostics: lateral offset of the reference point, left positive, m
    PSI_E = 12     # diagnostics: yaw - path heading, rad
    E_LA = 13      # diagnostics: lateral error at the look-ahead distance, m
    KAPPA = 14     # diagnostics: preview curvature, 1/m
    PHI_FF = 15    # diagnostics: -atan(u^2 kappa / g), rad
    PHI_REF = 16   # diagnostics: lean reference, rad
    CORR = 17      # diagnostics: path correction (rad, or N m with path_to_torque)
    V_REF = 18     # diagnostics: target speed, m/s
    A_DEM = 19     # diagnostics: acceleration demand, m/s^2
    TAU_CMD = 20   # diagnostics: torque demand before limits, N m


NST = len(RiderState)    # slots in st

Rider = namedtuple("Rider", ["px", "py", "ps", "hd", "seg_len", "kap", "tab_x", "tab_v", "par", "st", "buf"])


@dataclass(frozen=True)
class RiderParams:
    """Rider gains and limits. The lateral defaults are tuned on the linearised benchmark bicycle
    (Meijaard et al. 2007) at 4-8 m/s; a motorcycle needs its own (set them in the scenario file)."""
    p_roll: float = 160.0
    d_roll: float = 32.0
    i_roll: float = 0.0
    i_roll_max: float = 20.0
    tau_ref: float = 0.05
    p_n: float = 0.1
    d_n: float = 0.0
    p_psi: float = 0.5
    d_psi: float = 0.0
    i_n: float = 0.0
    i_n_max: float = 0.1
    max_correction: float = 0.35
    max_roll: float = 0.8
    max_roll_rate: float = 1.0
    tyre_lean: float = 0.0
    preview_dist: float = 0.0
    preview_time: float = 0.3
    la_min: float = 1.0
    la_time: float = 0.6
    d_steer: float = 0.0
    max_torque: float = 50.0
    max_torque_rate: float = 500.0
    kp_speed: float = 1.0
    ki_speed: float = 0.2
    speed_i_max: float = 3.0
    throttle_gain: float = 0.25
    band: float = 0.05
    brake_front: float = 0.7
    front_gain: float = 150.0
    rear_gain: float = 300.0
    brake_max: float = 15000.0
    delay: float = 0.0
    period: float = 0.001
    path_to_torque: bool = False

    def __post_init__(self):
        check_ranges(_PARAMS_MODEL, {n: getattr(self, n) for n in RIDER_RANGES}, "rider")
        if self.delay / self.period > NBUF - 1 + 1e-9:
            raise ValueError(f"rider: delay = {self.delay!r}: must be <= {NBUF - 1} periods "
                             f"({(NBUF - 1) * self.period:g} s at period = {self.period!r} s)")


#: Allowed ranges of the parameters: name -> (lo, hi, unit, lo_open); the scenario files use them too.
RIDER_RANGES = {
    "p_roll": (0.0, 1e5, "N m/rad", False),
    "d_roll": (0.0, 1e4, "N m s/rad", False),
    "i_roll": (0.0, 1e5, "N m/(rad s)", False),
    "i_roll_max": (0.0, 1e4, "N m", False),
    "tau_ref": (0.0, 10.0, "s", False),
    "p_n": (0.0, 1e4, "rad/m", False),
    "d_n": (0.0, 1e4, "rad s/m", False),
    "p_psi": (0.0, 1e4, "rad/rad", False),
    "d_psi": (0.0, 1e4, "rad s/rad", False),
    "i_n": (0.0, 1e3, "rad/(m s)", False),
    "i_n_max": (0.0, 1.5, "rad", False),
    "max_correction": (0.0, 1.5, "rad", False),
    "max_roll": (0.0, 1.5, "rad", True),
    "max_roll_rate": (0.0, 100.0, "rad/s", True),
    "tyre_lean": (0.0, 1.0, "", False),
    "preview_dist": (0.0, 500.0, "m", False),
    "preview_time": (0.0, 10.0, "s", False),
    "la_min": (0.0, 500.0, "m", False),
    "la_time": (0.0, 10.0, "s", False),
    "d_steer": (0.0, 1e4, "N m s/rad", False),
    "max_torque": (0.0, 1e4, "N m", True),
    "max_torque_rate": (0.0, 1e6, "N m/s", True),
    "kp_speed": (0.0, 100.0, "1/s", False),
    "ki_speed": (0.0, 100.0, "1/s^2", False),
    "speed_i_max": (0.0, 100.0, "m/s^2", False),
    "throttle_gain": (0.0, 100.0, "s^2/m", False),
    "band": (0.0, 10.0, "m/s^2", False),
    "brake_front": (0.0, 1.0, "", False),
    "front_gain": (0.0, 1e5, "kPa s^2/m", False),
    "rear_gain": (0.0, 1e5, "kPa s^2/m", False),
    "brake_max": (0.0, 20000.0, "kPa", False),
    "delay": (0.0, 1.0, "s", False),
    "period": (1e-5, 0.1, "s", False),
}
_PARAMS_MODEL = create_model("RiderParamsModel", __base__=Strict,
                             **range_fields(RIDER_RANGES, {n: 0.0 for n in RIDER_RANGES}))


def rider(path_x, path_y, closed: bool = False, speed=10.0, speed_by: str = "s", kappa_smooth: float = 0.0,
          params: RiderParams | None = None, **gains) -> Rider:
    """Build a rider for the polyline through (path_x[i], path_y[i]) (m, road frame).

    speed: target speed, m/s: a number, or a table (axis, values) over the path's arc length s (m,
    speed_by="s") or over time (s, speed_by="time"), piecewise linear, ends held. kappa_smooth (m):
    window of the curvature's moving average (0: none). gains: `RiderParams` fields."""
    if params is None:
        params = RiderParams(**gains)
    elif gains:
        params = RiderParams(**{**asdict(params), **gains})
    if speed_by not in ("s", "time"):
        raise ValueError(f"rider: speed_by = {speed_by!r}: use 's' or 'time'")
    px, py, ps, hd, seg, closed = polyline(path_x, path_y, closed)
    kap = vertex_curvature(px, py, closed, kappa_smooth)
    if np.ndim(speed) == 0:
        tab_x, tab_v = np.zeros(1), np.array([float(speed)])
    else:
        tab_x = np.array(speed[0], dtype=np.float64).reshape(-1)
        tab_v = np.array(speed[1], dtype=np.float64).reshape(-1)
        if tab_x.size < 1 or tab_x.shape != tab_v.shape:
            raise ValueError(f"rider: speed table has {tab_x.size} axis and {tab_v.size} speed values")
        if np.any(np.diff(tab_x) <= 0.0):
            raise ValueError("rider: speed table axis must be strictly increasing")
    if not (np.all(np.isfinite(tab_x)) and np.all(np.isfinite(tab_v))) or np.any(tab_v < 0.0):
        raise ValueError("rider: target speeds must be finite and >= 0")
    par = np.zeros(NPAR)
    for i, name in enumerate(("p_roll", "d_roll", "i_roll", "i_roll_max", "tau_ref", "p_n", "d_n", "p_psi",
                              "d_psi", "i_n", "i_n_max", "max_correction", "max_roll", "preview_dist",
                              "preview_time", "la_min", "la_time", "d_steer", "max_torque",
                              "max_torque_rate", "kp_speed", "ki_speed", "speed_i_max", "throttle_gain",
                              "band", "brake_front", "front_gain", "rear_gain", "brake_max")):
        par[i] = getattr(params, name)
    par[RiderPar.MAX_ROLL_RATE] = params.max_roll_rate
    par[RiderPar.TYRE_LEAN] = params.tyre_lean
    par[RiderPar.NDELAY] = round(params.delay / params.period)
    par[RiderPar.TO_TORQUE] = 1.0 if params.path_to_torque else 0.0
    par[RiderPar.SPEED_BY_S] = 1.0 if speed_by == "s" else 0.0
    par[RiderPar.CLOSED] = 1.0 if closed else 0.0
    par[RiderPar.NSEG] = seg.size
    par[RiderPar.LENGTH] = ps[-1]
    return Rider(px, py, ps, hd, seg, kap, tab_x, tab_v, par, np.zeros(NST), np.zeros((NBUF, NRO)))


def reset(r: Rider) -> None:
    """Back to the state before the first call."""
    r.st[:] = 0.0
    r.buf[:] = 0.0


def roll_reference(u: float, kappa: float) -> float:
    """Steady lean (rad, ISO: positive right) of a turn of curvature kappa (1/m, left positive) at
    speed u (m/s)."""
    return -math.atan(u * u * kappa / G)


# --------------------------------------------------------------------------------------------------
# Kernels


@inline_kernel
def _clip(x, lim):
    return min(max(x, -lim), lim)


@inline_kernel
def _table(xs, vs, x):
    """Piecewise-linear value at x and its slope (ends held, slope 0 there)."""
    n = xs.size
    if n == 1 or x <= xs[0]:
        return vs[0], 0.0
    if x >= xs[n - 1]:
        return vs[n - 1], 0.0
    lo, hi = bracket(xs, n, x)
    slope = (vs[hi] - vs[lo]) / (xs[hi] - xs[lo])
    return vs[lo] + slope * (x - xs[lo]), slope


@kernel
def rider_step(r, view, out):
    """Write out[RO_*] (steering torque, throttle, brake pressures) for the motorcycle's view[RV_*]."""
    p = r.par
    st = r.st
    t = view[RV_T]
    first = st[RiderState.INIT] == 0.0 or t < st[RiderState.T]
    if first:
        for k in range(NST):
            st[k] = 0.0
    dt = 0.0 if first else t - st[RiderState.T]
    x = view[RV_X]
    y = view[RV_Y]
    yaw = view[RV_YAW]
    u = view[RV_U]
    v = view[RV_V]
    closed = p[RiderPar.CLOSED] != 0.0
    nseg = int(p[RiderPar.NSEG])

    # curvilinear coordinates of the reference point
    i = nearest_segment(r.px, r.py, nseg, closed, first, int(st[RiderState.IDX]), x, y)
    st[RiderState.IDX] = i
    f, d2 = seg_project(r.px, r.py, i, x, y, nseg, closed)
    n, heading = on_segment(r.px, r.py, r.hd, r.seg_len, i, f, x, y)
    s = r.ps[i] + f * r.seg_len[i]
    psi = wrap_angle(yaw - heading)
    kap0 = value_at(r.ps, r.kap, closed, s, 0.0)
    cp = math.cos(psi)
    sp = math.sin(psi)
    ndot = u * sp + v * cp
    sdot = (u * cp - v * sp) / max(1.0 - n * kap0, 0.1)
    psidot = view[RV_R] - kap0 * sdot
    uf = max(u, 0.0)
    la = p[RiderPar.LA_MIN] + p[RiderPar.LA_TIME] * uf
    e = n + la * sp
    edot = ndot + la * cp * psidot

    # lean reference: preview curvature, then the path correction
    kap = value_at(r.ps, r.kap, closed, s + p[RiderPar.PREV_DIST] + p[RiderPar.PREV_TIME] * uf, 0.0)
    phi_ff = -math.atan(u * u * kap / G)
    phi_ff += math.asin(p[RiderPar.TYRE_LEAN] * math.sin(phi_ff))
    if not first:
        lim = p[RiderPar.MAX_ROLL_RATE] * dt
        phi_ff = min(max(phi_ff, st[RiderState.PHI_FF_PREV] - lim), st[RiderState.PHI_FF_PREV] + lim)
    st[RiderState.I_N] = _clip(st[RiderState.I_N] + p[RiderPar.I_N] * e * dt, p[RiderPar.I_N_MAX])
    corr = (p[RiderPar.P_N] * e + p[RiderPar.D_N] * edot + p[RiderPar.P_PSI] * psi + p[RiderPar.D_PSI] * psidot
            + st[RiderState.I_N])
    tau_path = 0.0
    if p[RiderPar.TO_TORQUE] != 0.0:
        tau_path = corr
        phi_ref = _clip(phi_ff, p[RiderPar.MAX_ROLL])
    else:
        corr = _clip(corr, p[RiderPar.MAX_CORR])
        phi_ref = _clip(phi_ff + corr, p[RiderPar.MAX_ROLL])
    if dt > 0.0:
        raw = (phi_ff - st[RiderState.PHI_FF_PREV]) / dt
        st[RiderState.DPHI_FF] += (raw - st[RiderState.DPHI_FF]) * dt / (p[RiderPar.TAU_REF] + dt)
    st[RiderState.PHI_FF_PREV] = phi_ff

    # roll loop -> steering torque
    err = phi_ref - view[RV_PHI]
    st[RiderState.I_ROLL] = _clip(st[RiderState.I_ROLL] + p[RiderPar.I_ROLL] * err * dt, p[RiderPar.I_ROLL_MAX])
    tau = (p[RiderPar.P_ROLL] * err + p[RiderPar.D_ROLL] * (st[RiderState.DPHI_FF] - view[RV_PHIDOT])
           + st[RiderState.I_ROLL] + tau_path - p[RiderPar.D_STEER] * view[RV_DELTADOT])
    st[RiderState.TAU_CMD] = tau
    tau = _clip(tau, p[RiderPar.MAX_TORQUE])
    step = p[RiderPar.MAX_RATE] * dt
    tau = min(max(tau, st[RiderState.TAU] - step), st[RiderState.TAU] + step)
    st[RiderState.TAU] = tau

    # speed PI -> throttle and brakes
    if p[RiderPar.SPEED_BY_S] != 0.0:
        vref, slope = _table(r.tab_x, r.tab_v, s)
        aref = vref * slope
    else:
        vref, aref = _table(r.tab_x, r.tab_v, t)
    ev = vref - u
    a = aref + p[RiderPar.KP_V] * ev + st[RiderState.I_V]
    thr = 0.0
    decel = 0.0
    if a > 0.0:
        thr = min(p[RiderPar.THR_GAIN] * a, 1.0)
    elif a < -p[RiderPar.BAND]:
        decel = -a
    bf = min(p[RiderPar.BRAKE_FRONT] * decel * p[RiderPar.FRONT_GAIN], p[RiderPar.BRAKE_MAX])
    br = min((1.0 - p[RiderPar.BRAKE_FRONT]) * decel * p[RiderPar.REAR_GAIN], p[RiderPar.BRAKE_MAX])
    saturated = (thr >= 1.0 and ev > 0.0) or (bf >= p[RiderPar.BRAKE_MAX] and br >= p[RiderPar.BRAKE_MAX] and ev < 0.0)
    if not saturated:
        st[RiderState.I_V] = _clip(st[RiderState.I_V] + p[RiderPar.KI_V] * ev * dt, p[RiderPar.I_V_MAX])

    # reaction delay
    head = int(st[RiderState.HEAD])
    if first:
        for k in range(NBUF):
            r.buf[k, RO_TORQUE] = tau
            r.buf[k, RO_THROTTLE] = thr
            r.buf[k, RO_BRAKE_F] = bf
            r.buf[k, RO_BRAKE_R] = br
        head = 0
    r.buf[head, RO_TORQUE] = tau
    r.buf[head, RO_THROTTLE] = thr
    r.buf[head, RO_BRAKE_F] = bf
    r.buf[head, RO_BRAKE_R] = br
    k = head - int(p[RiderPar.NDELAY])
    if k < 0:
        k += NBUF
    for j in range(NRO):
        out[j] = r.buf[k, j]
    st[RiderState.HEAD] = head + 1 if head + 1 < NBUF else 0

    st[RiderState.INIT] = 1.0
    st[RiderState.T] = t
    st[RiderState.S] = s
    st[RiderState.N] = n
    st[RiderState.PSI_E] = psi
    st[RiderState.E_LA] = e
    st[RiderState.KAPPA] = kap
    st[RiderState.PHI_FF] = phi_ff
    st[RiderState.PHI_REF] = phi_ref
    st[RiderState.CORR] = corr
    st[RiderState.V_REF] = vref
    st[RiderState.A_DEM] = a
