"""The motorcycle's engine and transmission as one compiled kernel: throttle and rear-wheel speed in, the
torque at the rear wheel out (the step turns it into chain tension, rtsim.vehicle.motorcycle.step).

    torque = rear_wheel_torque(ep, es, throttle, wheel_speed, dt)      # N m at the rear wheel

- ep: float64 (EP_SIZE,), the parameters (`pack_engine` from the vehicle file's [powertrain]); read only.
- es: float64 (ES_SIZE,), the state, zeros before the first call; the kernel updates it and writes its
  outputs there: es[ES_GEAR] (1..n), es[ES_ENGINE_SPEED] (rad/s), es[ES_ENGINE_TORQUE] (N m at the
  crank), es[ES_CLUTCH_SLIP] (1 while the clutch slips), es[ES_WHEEL_TORQUE] (the returned value).
- throttle: 0..1 (clipped): the rider's twist grip read as a torque demand between the closed-throttle
  (engine-braking) torque and the full-load torque at the current engine speed.
- wheel_speed: rad/s, the rear wheel's spin rate relative to the frame (positive rolling forward).
- dt: s, the time since the previous call (the step): it advances the shift timers.

Pure: no allocation, no global state; the caller owns both arrays (the HIL service calls it inside its
compiled step, the offline runs from Python).

The model, per call:

1. Gear. Fixed (`gear` in the vehicle file, or `fixed_gear` at packing), or automatic: one gear up when
   the gearbox input speed omega_in = G omega_wheel passes upshift_rpm, one down below downshift_rpm
   (never into a gear that would put the engine past the rev limit), at most one shift per shift_hold_s.
   The first call picks the highest gear whose input speed is above the downshift speed. Every shift
   interrupts the drive for shift_time_s (the clutch, or a quick-shifter's ignition cut).
   G = primary_ratio gear_ratio[g] final_ratio, the final ratio the chain's sprocket radii (rear/front).
2. Clutch. Pulling away it slips: the rider holds the engine at omega_launch = idle + throttle
   (launch - idle) and the clutch passes the engine's torque at that speed, never negative (the engine
   turns faster than the gearbox: a slipping clutch only drives) and at most clutch_capacity_nm; at
   rest with the throttle shut it passes nothing (the clutch is pulled in). Once the gearbox input
   reaches omega_launch the clutch locks, omega_e = G omega_wheel, and stays locked until the engine
   would fall below idle (the rider declutches; the next pull-away slips again). So the engine neither
   stalls nor drops below idle, and the motorcycle starts from rest in any gear.
3. Engine torque at omega_e: T = f T_full(omega_e) - (1 - f) T_closed(omega_e), f = throttle times the
   rev limiter's fuel factor (1 below rev_limit - band, 0 at the limit, linear between); T_closed is the
   motoring (friction and pumping) torque, positive in the table: engine braking.
4. At the wheel: eta G T when driving, G T / eta when the wheel drives the engine (eta: the gearbox and
   chain efficiency).

Not modelled: the rotating inertia of crank, clutch and gearbox (it would add about I_e G^2 / r^2 to the
mass on the road: about 18 % in first gear, 4 % in top with I_e = 0.04 kg m^2), the engine's
own speed dynamics while the clutch slips, turbo/intake lags.
"""
from __future__ import annotations

import math

import numpy as np

from rtsim.jit import inline_kernel, kernel

from ..kit.layout import offsets
from ..kit.tables import TABLE_POINTS, table_1d, table_eval

RPM = 2.0 * math.pi / 60.0      # rad/s per rpm
MAX_GEARS = 8
_TAB = 1 + 2 * TABLE_POINTS

# Parameters (ep).
(EP_IDLE,            # rad/s, idle speed
 EP_LAUNCH,          # rad/s, clutch slip speed at full throttle
 EP_LIMIT,           # rad/s, rev limit (no fuel at and above)
 EP_BAND,            # rad/s, the limiter's fuel ramp below the limit
 EP_CLUTCH,          # N m, clutch capacity (crank side)
 EP_PRIMARY,         # -, crank to gearbox input
 EP_FINAL,           # -, rear / front sprocket radius
 EP_EFF,             # -, transmission efficiency
 EP_NGEARS,          # number of gears
 EP_FIXED,           # 0: automatic, else the fixed gear
 EP_UP,              # rad/s, engine speed of an automatic upshift
 EP_DOWN,            # rad/s, engine speed of an automatic downshift
 EP_SHIFT_TIME,      # s, drive interrupted per shift
 EP_HOLD,            # s, minimum time between automatic shifts
 EP_RATIOS,          # MAX_GEARS gear ratios
 EP_T_FULL,          # table: full-load torque (N m) against engine speed (rad/s)
 EP_T_CLOSED,        # table: closed-throttle (motoring) torque magnitude (N m) against engine speed
 EP_SIZE) = offsets(*(1,) * 14, MAX_GEARS, _TAB, _TAB)

# State and outputs (es).
(ES_GEAR,            # current gear 1..n (0 before the first call)
 ES_ENGINE_SPEED,    # rad/s
 ES_ENGINE_TORQUE,   # N m at the crank
 ES_WHEEL_TORQUE,    # N m at the rear wheel (the kernel's return value)
 ES_CLUTCH_SLIP,     # 1 while the clutch slips
 ES_SINCE_SHIFT,     # s since the last shift
 ES_CUT,             # s of drive interruption left
 ES_INIT,            # 1 after the first call
 ES_SIZE) = offsets(*(1,) * 8)


def pack_engine(pt, final_ratio: float, fixed_gear: int | None = None) -> np.ndarray:
    """The parameter array of a validated [powertrain] table (rtsim.vehicle.motorcycle.config.Powertrain);
    final_ratio: rear / front sprocket radius; fixed_gear overrides the file's `gear` (0: automatic)."""
    ep = np.zeros(EP_SIZE)
    ep[EP_IDLE] = pt.idle_rpm * RPM
    ep[EP_LAUNCH] = pt.launch_rpm * RPM
    ep[EP_LIMIT] = pt.rev_limit_rpm * RPM
    ep[EP_BAND] = pt.limiter_band_rpm * RPM
    ep[EP_CLUTCH] = pt.clutch_capacity_nm
    ep[EP_PRIMARY] = pt.primary_ratio
    ep[EP_FINAL] = final_ratio
    ep[EP_EFF] = pt.efficiency
    n = len(pt.gear_ratios)
    ep[EP_NGEARS] = n
    gear = pt.gear if fixed_gear is None else int(fixed_gear)
    if not 0 <= gear <= n:
        raise ValueError(f"gear {gear}: the gearbox has gears 1..{n} (0: automatic)")
    ep[EP_FIXED] = gear
    ep[EP_UP] = pt.upshift_rpm * RPM
    ep[EP_DOWN] = pt.downshift_rpm * RPM
    ep[EP_SHIFT_TIME] = pt.shift_time_s
    ep[EP_HOLD] = pt.shift_hold_s
    ep[EP_RATIOS:EP_RATIOS + n] = pt.gear_ratios
    w = np.asarray(pt.engine_speed_rpm) * RPM
    ep[EP_T_FULL:EP_T_FULL + _TAB] = table_1d(w, pt.full_load_torque_nm)
    ep[EP_T_CLOSED:EP_T_CLOSED + _TAB] = table_1d(w, pt.closed_throttle_torque_nm)
    return ep


def engine_state() -> np.ndarray:
    """A fresh state (gear chosen at the first call)."""
    return np.zeros(ES_SIZE)


@inline_kernel
def total_ratio(ep, gear):
    """Engine speed per rear-wheel speed in `gear` (1..n)."""
    return ep[EP_PRIMARY] * ep[EP_RATIOS + gear - 1] * ep[EP_FINAL]


@inline_kernel
def _curve(ep, at, w):
    """A torque table at engine speed w, held beyond its ends."""
    t = ep[at:at + _TAB]
    n = int(t[0])
    x = min(max(w, t[1]), t[n])
    return table_eval(t, x)[0]


@kernel
def engine_torque(ep, throttle, w):
    """Crank torque (N m) at engine speed w (rad/s) and throttle 0..1, the rev limiter included."""
    band = max(ep[EP_BAND], 1e-9)
    fuel = min(max(throttle, 0.0), 1.0) * min(max((ep[EP_LIMIT] - w) / band, 0.0), 1.0)
    return fuel * _curve(ep, EP_T_FULL, w) - (1.0 - fuel) * _curve(ep, EP_T_CLOSED, w)


@kernel
def rear_wheel_torque(ep, es, throttle, wheel_speed, dt):
    """Torque at the rear wheel, N m (see the module docstring); updates es."""
    thr = min(max(throttle, 0.0), 1.0)
    n = int(ep[EP_NGEARS])
    fixed = int(ep[EP_FIXED])
    ws = max(wheel_speed, 0.0)
    g = int(es[ES_GEAR])
    first = es[ES_INIT] == 0.0
    if fixed > 0:
        g = fixed
    elif first:                       # the highest gear above the downshift speed
        g = 1
        while g < n and ws * total_ratio(ep, g + 1) > ep[EP_DOWN]:
            g += 1
    elif es[ES_SINCE_SHIFT] >= ep[EP_HOLD]:
        w_in = ws * total_ratio(ep, g)
        if w_in > ep[EP_UP] and g < n:
            g += 1
            es[ES_SINCE_SHIFT] = 0.0
            es[ES_CUT] = ep[EP_SHIFT_TIME]
        elif w_in < ep[EP_DOWN] and g > 1 and ws * total_ratio(ep, g - 1) < ep[EP_LIMIT] - ep[EP_BAND]:
            g -= 1
            es[ES_SINCE_SHIFT] = 0.0
            es[ES_CUT] = ep[EP_SHIFT_TIME]
    if first:
        es[ES_SINCE_SHIFT] = ep[EP_HOLD]
    else:
        es[ES_SINCE_SHIFT] += dt
    es[ES_GEAR] = g
    ratio = total_ratio(ep, g)
    w_in = ws * ratio
    # clutch: slipping from a standstill until the gearbox input reaches the launch speed, then locked
    # until the engine would fall below idle (the rider pulls the clutch in)
    w_launch = ep[EP_IDLE] + thr * (ep[EP_LAUNCH] - ep[EP_IDLE])
    slip = es[ES_CLUTCH_SLIP] != 0.0
    if first:
        slip = w_in < ep[EP_IDLE]
    elif slip and w_in >= w_launch:
        slip = False
    elif not slip and w_in < ep[EP_IDLE]:
        slip = True
    if slip:
        w = max(w_launch, w_in)
        te = engine_torque(ep, thr, w)
        tc = min(max(te, 0.0), ep[EP_CLUTCH])
        es[ES_CLUTCH_SLIP] = 1.0
    else:
        w = w_in
        te = engine_torque(ep, thr, w)
        tc = min(max(te, -ep[EP_CLUTCH]), ep[EP_CLUTCH])
        es[ES_CLUTCH_SLIP] = 0.0
    es[ES_INIT] = 1.0
    if es[ES_CUT] > 0.0:
        es[ES_CUT] = max(es[ES_CUT] - dt, 0.0)
        tc = 0.0
    if tc >= 0.0:
        tw = ep[EP_EFF] * ratio * tc
    else:
        tw = ratio * tc / ep[EP_EFF]
    es[ES_ENGINE_SPEED] = w
    es[ES_ENGINE_TORQUE] = te
    es[ES_WHEEL_TORQUE] = tw
    return tw
