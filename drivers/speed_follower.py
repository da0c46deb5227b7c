"""Closed-loop longitudinal driver: follows a target speed with the throttle or the brake.

Target. A table of target speed (m/s) over time (s) or over distance travelled (m), piecewise linear,
end values held. Its slope is the target acceleration and enters as feed-forward (over distance:
a = v_ref dv_ref/ds). The distance is the driver's own odometer, integrated from the measured speed.

Control law, evaluated once per integrator step from the time t and the measured speed v:

    e = v_ref - v
    u = ff_gain (a_ref + a_res0 sign(v) + a_res2 v^2) + kp e + I - kd dv/dt_filtered      [m/s^2]

u is a demanded acceleration. A driver either presses the throttle or the brake, so u goes to one
*side* at a time: on the throttle side, throttle = throttle_gain u clipped to [0, throttle_max] (0 for
u < 0: coasting); on the brake side, brake = -brake_gain u clipped to [0, brake_max] (0 for u > 0).
The side changes only when u leaves a dead band: throttle -> brake when u < -band, brake ->
throttle when u > +band. Within the band the car coasts, so a demand near zero never toggles between
the pedals. The derivative acts on the measurement (no kick on target steps), filtered with time
constant tau_d. Anti-windup: the integrator I += ki e dt is frozen while the pedal on the current
side is at its maximum and the error pushes further, and is clipped to +-i_max.

Standstill. When the target is (nearly) zero (v_ref <= v_eps) and the car has (nearly) stopped
(|v| <= v_stop), the driver holds the car: throttle 0, brake rising to hold_pressure at hold_rate,
integrator reset. It lets go as soon as the target rises above v_eps. A car starting at rest with a
zero target therefore starts held (at the hold pressure from the first step).

Model/data: `SpeedFollower` is a named tuple of arrays (parameters `par`, target table `tab_x`,
`tab_v`, mutable controller state `st`); `speed_follower_step` is a compiled kernel that writes
out[I_THROTTLE] and out[I_BRAKE] and allocates nothing. Parameters are indexed by `P_*`; the
`SpeedFollowerParams` defaults are starting values for a small passenger car, to be tuned against the
vehicle model (throttle_gain and brake_gain are the inverse of the car's acceleration per radian of
throttle and per kPa of brake pressure).
"""
from __future__ import annotations

from collections import namedtuple
from dataclasses import asdict, dataclass
from enum import IntEnum

import numpy as np
from pydantic import create_model

from rtsim.configfile import Strict, check_ranges, range_fields
from rtsim.jit import inline_kernel, kernel

from .base import I_BRAKE, I_THROTTLE, LIMITS, DriverView


class SpeedPar(IntEnum):
    """The speed follower's parameter array (par), one slot per gain or limit."""
    KP = 0          # 1/s, proportional gain (m/s^2 per m/s)
    KI = 1          # 1/s^2, integral gain
    KD = 2          # -, derivative gain on the measured acceleration
    TAU_D = 3       # s, derivative filter time constant
    THR_GAIN = 4    # rad per m/s^2 of demand
    THR_MAX = 5     # rad, maximum throttle angle
    BRK_GAIN = 6    # kPa per m/s^2 of deceleration demand
    BRK_MAX = 7     # kPa, maximum brake pressure
    BAND = 8        # m/s^2, half width of the dead band between throttle and brake
    HOLD_P = 9      # kPa, brake pressure that holds the car at standstill
    HOLD_RATE = 10  # kPa/s, rate at which the hold pressure is applied
    V_STOP = 11     # m/s, speed below which the car counts as stopped
    V_EPS = 12      # m/s, target speed below which the target counts as zero
    I_MAX = 13      # m/s^2, integrator clip
    BY_DIST = 14    # 0: target over time, 1: over distance
    A_RES0 = 15     # m/s^2, road-load feed-forward, constant part (rolling resistance / mass)
    A_RES2 = 16     # 1/m, road-load feed-forward, quadratic part (aero drag / mass)
    FF_GAIN = 17    # -, weight of the feed-forward


NPAR = len(SpeedPar)     # slots in par


class SpeedState(IntEnum):
    """The speed follower's controller state array (st): memory between calls and diagnostics."""
    INIT = 0   # 0 until the first call
    T = 1      # time of the previous call
    V = 2      # speed at the previous call
    I = 3      # integrator, m/s^2
    SIDE = 4   # +1 throttle side, -1 brake side
    DVF = 5    # filtered measured acceleration, m/s^2
    DIST = 6   # odometer, m
    HOLD = 7   # 1 while holding at standstill
    BRK = 8    # last brake output, kPa (for the hold ramp)
    VREF = 9   # diagnostics: target speed, m/s
    AREF = 10  # diagnostics: target acceleration, m/s^2
    U = 11     # diagnostics: demand u, m/s^2


NST = len(SpeedState)    # slots in st

SpeedFollower = namedtuple("SpeedFollower", ["par", "tab_x", "tab_v", "st"])


@dataclass(frozen=True)
class SpeedFollowerParams:
    kp: float = 0.8
    ki: float = 0.15
    kd: float = 0.0
    tau_d: float = 0.05
    throttle_gain: float = 0.35
    throttle_max: float = 1.4
    brake_gain: float = 800.0
    brake_max: float = 10000.0
    band: float = 0.15
    hold_pressure: float = 2500.0
    hold_rate: float = 5000.0
    v_stop: float = 0.1
    v_eps: float = 0.01
    i_max: float = 3.0
    a_res0: float = 0.0
    a_res2: float = 0.0
    ff_gain: float = 1.0

    def __post_init__(self):
        check_ranges(_PARAMS_MODEL, asdict(self), "speed follower")


#: Allowed ranges of the parameters: name -> (lo, hi, unit, lo_open); the scenario files use them too.
SPEED_FOLLOWER_RANGES = {
    "kp": (0.0, 50.0, "1/s", False),
    "ki": (0.0, 50.0, "1/s^2", False),
    "kd": (0.0, 10.0, "", False),
    "tau_d": (0.0, 10.0, "s", False),
    "throttle_gain": (0.0, 10.0, "rad/(m/s^2)", True),
    "throttle_max": (0.0, LIMITS["throttle_angle_cmd"][1], "rad", True),
    "brake_gain": (0.0, 1e4, "kPa/(m/s^2)", True),
    "brake_max": (0.0, LIMITS["brake_pressure_cmd"][1], "kPa", True),
    "band": (0.0, 5.0, "m/s^2", False),
    "hold_pressure": (0.0, LIMITS["brake_pressure_cmd"][1], "kPa", False),
    "hold_rate": (0.0, 1e6, "kPa/s", True),
    "v_stop": (0.0, 2.0, "m/s", False),
    "v_eps": (0.0, 1.0, "m/s", False),
    "i_max": (0.0, 20.0, "m/s^2", False),
    "a_res0": (0.0, 5.0, "m/s^2", False),
    "a_res2": (0.0, 0.1, "1/m", False),
    "ff_gain": (0.0, 2.0, "", False),
}
_PARAMS_MODEL = create_model("SpeedFollowerParamsModel", __base__=Strict,
                             **range_fields(SPEED_FOLLOWER_RANGES, {n: 0.0 for n in SPEED_FOLLOWER_RANGES}))


_ORDER = ("kp", "ki", "kd", "tau_d", "throttle_gain", "throttle_max", "brake_gain", "brake_max", "band",
          "hold_pressure", "hold_rate", "v_stop", "v_eps", "i_max", None, "a_res0", "a_res2", "ff_gain")
assert len(_ORDER) == NPAR


def speed_follower(target_x, target_v, by: str = "time",
                   params: SpeedFollowerParams | None = None, **kw) -> SpeedFollower:
    """Build a speed follower for the target table (target_x: times in s or distances in m,
    strictly increasing; target_v: m/s, >= 0). Parameters: a `SpeedFollowerParams` or keywords."""
    if params is None:
        params = SpeedFollowerParams(**kw)
    elif kw:
        params = SpeedFollowerParams(**{**asdict(params), **kw})
    if by not in ("time", "distance"):
        raise ValueError(f"speed follower target over {by!r}: use 'time' or 'distance'")
    x = np.array(target_x, dtype=np.float64).reshape(-1)
    v = np.array(target_v, dtype=np.float64).reshape(-1)
    if x.size == 0 or x.shape != v.shape:
        raise ValueError(f"speed follower target table: {x.size} {by} values and {v.size} speeds")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(v))):
        raise ValueError("speed follower target table has non-finite entries")
    if np.any(np.diff(x) <= 0.0):
        raise ValueError(f"speed follower target {by} values must be strictly increasing")
    if np.any(v < 0.0):
        raise ValueError("speed follower target speeds must be >= 0 (no reversing)")
    par = np.zeros(NPAR)
    for i, name in enumerate(_ORDER):
        par[i] = (1.0 if by == "distance" else 0.0) if name is None else getattr(params, name)
    return SpeedFollower(par, x, v, np.zeros(NST))


def reset(sf: SpeedFollower) -> None:
    sf.st[:] = 0.0


@inline_kernel
def _lookup(x, v, s):
    """Target value and slope of the piecewise-linear table at s (ends held, slope 0 outside)."""
    n = x.shape[0]
    if n == 1 or s <= x[0]:
        return v[0], 0.0
    if s >= x[n - 1]:
        return v[n - 1], 0.0
    lo = 0
    hi = n - 1
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if x[mid] <= s:
            lo = mid
        else:
            hi = mid
    slope = (v[hi] - v[lo]) / (x[hi] - x[lo])
    return v[lo] + slope * (s - x[lo]), slope


@kernel
def speed_follower_step(sf, t, state, out):
    """Write throttle (out[I_THROTTLE], rad) and brake (out[I_BRAKE], kPa) for time t and the
    measured state (state[DriverView.SPEED], m/s). Updates the controller state sf.st."""
    p = sf.par
    st = sf.st
    v = state[DriverView.SPEED]
    if st[SpeedState.INIT] == 0.0 or t < st[SpeedState.T]:
        st[SpeedState.INIT] = 1.0
        st[SpeedState.T] = t
        st[SpeedState.V] = v
        st[SpeedState.I] = 0.0
        st[SpeedState.SIDE] = 0.0
        st[SpeedState.DVF] = 0.0
        st[SpeedState.DIST] = 0.0
        st[SpeedState.HOLD] = 0.0
        st[SpeedState.BRK] = p[SpeedPar.HOLD_P]  # a car that starts held is held at once, not after a ramp
    dt = t - st[SpeedState.T]
    st[SpeedState.DIST] += 0.5 * (v + st[SpeedState.V]) * dt
    if dt > 0.0:
        raw = (v - st[SpeedState.V]) / dt
        st[SpeedState.DVF] += (raw - st[SpeedState.DVF]) * (dt / (p[SpeedPar.TAU_D] + dt))
    st[SpeedState.T] = t
    st[SpeedState.V] = v

    if p[SpeedPar.BY_DIST] != 0.0:
        v_ref, slope = _lookup(sf.tab_x, sf.tab_v, st[SpeedState.DIST])
        a_ref = slope * v_ref
    else:
        v_ref, slope = _lookup(sf.tab_x, sf.tab_v, t)
        a_ref = slope
    st[SpeedState.VREF] = v_ref
    st[SpeedState.AREF] = a_ref

    # standstill hold
    if v_ref <= p[SpeedPar.V_EPS]:
        if abs(v) <= p[SpeedPar.V_STOP]:
            st[SpeedState.HOLD] = 1.0
    else:
        st[SpeedState.HOLD] = 0.0
    if st[SpeedState.HOLD] != 0.0:
        brk = min(st[SpeedState.BRK] + p[SpeedPar.HOLD_RATE] * dt, p[SpeedPar.HOLD_P])
        if st[SpeedState.BRK] > p[SpeedPar.HOLD_P]:
            brk = max(st[SpeedState.BRK] - p[SpeedPar.HOLD_RATE] * dt, p[SpeedPar.HOLD_P])
        out[I_THROTTLE] = 0.0
        out[I_BRAKE] = brk
        st[SpeedState.BRK] = brk
        st[SpeedState.I] = 0.0
        st[SpeedState.SIDE] = -1.0
        st[SpeedState.U] = 0.0
        return

    e = v_ref - v
    sgn = 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)
    ff = p[SpeedPar.FF_GAIN] * (a_ref + p[SpeedPar.A_RES0] * sgn + p[SpeedPar.A_RES2] * v * abs(v))
    u = ff + p[SpeedPar.KP] * e + st[SpeedState.I] - p[SpeedPar.KD] * st[SpeedState.DVF]
    st[SpeedState.U] = u

    side = st[SpeedState.SIDE]
    if side == 0.0:
        side = 1.0 if u >= 0.0 else -1.0
    elif side > 0.0 and u < -p[SpeedPar.BAND]:
        side = -1.0
    elif side < 0.0 and u > p[SpeedPar.BAND]:
        side = 1.0
    st[SpeedState.SIDE] = side

    u_hi = p[SpeedPar.THR_MAX] / p[SpeedPar.THR_GAIN]
    u_lo = -p[SpeedPar.BRK_MAX] / p[SpeedPar.BRK_GAIN]
    if side > 0.0:
        thr = min(max(u, 0.0), u_hi) * p[SpeedPar.THR_GAIN]
        brk = 0.0
    else:
        thr = 0.0
        brk = min(max(-u, 0.0), -u_lo) * p[SpeedPar.BRK_GAIN]
    out[I_THROTTLE] = thr
    out[I_BRAKE] = brk
    st[SpeedState.BRK] = brk

    # anti-windup: conditional integration at the pedal limits, then clip
    saturated = (side > 0.0 and u >= u_hi and e > 0.0) or (side < 0.0 and u <= u_lo and e < 0.0)
    if not saturated:
        st[SpeedState.I] += p[SpeedPar.KI] * e * dt
    if st[SpeedState.I] > p[SpeedPar.I_MAX]:
        st[SpeedState.I] = p[SpeedPar.I_MAX]
    elif st[SpeedState.I] < -p[SpeedPar.I_MAX]:
        st[SpeedState.I] = -p[SpeedPar.I_MAX]
