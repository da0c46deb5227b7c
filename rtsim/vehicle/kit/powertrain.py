"""Powertrain of the rear-wheel-drive prototype: throttle-by-wire, a small carburetted four-cylinder
engine, torque converter, automatic gearbox, final drive and open differential.

Chain, per 1 ms step (``powertrain_step``):

1. Throttle-by-wire: ``throttle_angle_cmd`` -> lag block (about 50 ms, rate limit, 0..1.4 rad) ->
   ``throttle_angle``.
2. Gearbox logic (selector D/N/R). In D, the gear follows a shift schedule: for gear k an upshift line
   v_up,k(throttle) and a downshift line v_down,k(throttle) < v_up,k in vehicle speed (m/s, from the
   mean rear wheel speed times the wheel radius). The gap between the lines is the hysteresis; a
   request must persist for ``shift_delay`` before it is executed, and the ratio then moves linearly
   from the old to the new gear's over ``shift_time`` (a crude inertia phase, keeps torques smooth).
3. Engine and converter. Engine brake torque T_e(throttle, omega_e) is a table, bilinear between nodes
   and held constant beyond its edges; its closed-throttle row is the friction and pumping torque. An
   idle-speed controller (PI on omega_idle - omega_e) adds an equivalent throttle opening (bypass air)
   in [0, idle_max_opening]; above idle it winds down to zero. Converter (capacity-factor model): with
   speed ratio SR = omega_t / omega_p, pump torque T_p = (omega_p / K(SR))^2 and turbine torque
   T_t = TR(SR) T_p; K(SR) and TR(SR) are tables, linear between nodes. Beyond the last K node the
   capacity 1/K^2 falls linearly to 0 at SR = 1. TR = 1 from the coupling point on. When the turbine
   overruns the pump (coasting, engine braking) the converter acts as a coupling with the roles
   swapped: T_p = T_t = -(omega_t / K(omega_p/omega_t))^2 times ``overrun_capacity_scale``. A turbine
   turning backwards (car rolling back in D) is treated as stall. Optional lock-up clutch: a slip
   damper c (omega_p - omega_t) limited to its torque capacity, engaged in the lock-up gear above the
   lock-up speed.
   The engine speed is the state: J_e d omega_e/dt = T_e - T_p - T_lockup, integrated by backward Euler
   (two Newton iterations on the exact nonlinear residual, including the idle controller's
   proportional path) with the turbine speed of the step's start. This is unconditionally stable for
   the stiff cases (converter at stall with the car held by the brake, lock-up clutch), where an
   explicit update would need far smaller steps.
4. Output: turbine shaft torque times gear ratio times final drive, times the efficiency eta when the
   engine drives (divided by eta when the wheels drive the engine), split equally between rl and rr
   (open differential, its inertia neglected). The converter's sensitivity to wheel speed at the new
   engine speed is returned as ``PO_DTDW`` = d T_rl / d omega_rl = d T_rl / d omega_rr (the same for
   the rr row), for the multibody tangent damping.

Initial states: ``powertrain_state`` (engine speed and gear as given) and ``powertrain_state_rolling``
(the steady state under wheels already turning: the schedule's gear, the engine where its torque
balances the converter at that turbine speed, the idle controller settled), which a car started at
speed uses (rtsim.vehicle.car.sim). In a panic stop from speed the converter does not hold the braked
wheels up: slipping, it passes the engine's spin-down as a few tens of N m per rear wheel, and at stall
with the engine idling only the creep torque 0.5 eta i_1 i_fd TR(0) (omega_idle / K(0))^2 (about
99 N m per wheel in 1st with the defaults), well below the rear brakes' torque.

``wheel_torque_source = "measured"`` replaces the drive torques by the inputs ``wheel_torque_rl/rr``
(the seed's validation inputs); the engine and gearbox still run and report their sensor channels.

Units: rad, rad/s, N*m, kg*m^2, m/s, s. Signs: ISO 8855, wheel speeds positive rolling forward.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Literal

import numpy as np

from rtsim.jit import inline_kernel, kernel

from .layout import offsets
from rtsim.configfile import Range, check_declared_ranges

from .actuators import (LAG_NPAR, LAG_Y, LagConfig, check, part_config, pydantic_config, lag_init,
                        lag_state_size, lag_step, saturate)

RPM = 2.0 * math.pi / 60.0   # rad/s per rpm

# ----------------------------------------------------------------------------- parameter layout
(PP_MEASURED,     # 1.0: drive torques are the measured inputs
 PP_J,            # kg m^2, engine + pump + converter fluid inertia
 PP_IDLE,         # rad/s, idle speed target
 PP_IDLE_KP,      # rad per rad/s, idle controller proportional gain
 PP_IDLE_KI,      # rad per rad, idle controller integral gain
 PP_IDLE_MAX,     # rad, largest idle bypass opening (equivalent throttle)
 PP_REV,          # rad/s, rev limiter: fuel cut complete here
 PP_REV_BAND,     # rad/s, throttle faded to 0 over [rev - band, rev]
 PP_TH_OFF,       # offset of the map's throttle nodes (rad)
 PP_TH_N,
 PP_W_OFF,        # offset of the map's speed nodes (rad/s)
 PP_W_N,
 PP_MAP_OFF,      # offset of the map, row-major [throttle][speed], N*m
 PP_SR_OFF,       # offset of the K-factor speed-ratio nodes
 PP_SR_N,
 PP_K_OFF,        # offset of the K factors, (rad/s)/sqrt(N*m)
 PP_TRN_OFF,      # offset of the torque-ratio speed-ratio nodes
 PP_TRN_N,
 PP_TR_OFF,       # offset of the torque ratios
 PP_OVERRUN,      # overrun capacity scale
 PP_LOCKUP,       # 1.0 if a lock-up clutch is fitted
 PP_LU_GEAR,      # gear number in which it may engage
 PP_LU_SPEED,     # m/s, vehicle speed above which it engages (disengages 10 % below)
 PP_LU_CAP,       # N*m, clutch torque capacity
 PP_LU_C,         # N*m*s/rad, slip damping
 PP_NGEAR,        # number of forward gears
 PP_RATIO_OFF,    # offset of the forward ratios
 PP_REV_RATIO,    # reverse ratio (positive number)
 PP_FD,           # final drive ratio
 PP_EFF,          # gearbox + final drive efficiency
 PP_RW,           # m, wheel radius used by the shift schedule
 PP_SCH_OFF,      # offset of the schedule's throttle nodes
 PP_SCH_N,
 PP_UP_OFF,       # offset of upshift speeds, row k-1 for k -> k+1, m/s
 PP_DN_OFF,       # offset of downshift speeds, row k-1 for k+1 -> k, m/s
 PP_SHIFT_DELAY,  # s
 PP_SHIFT_TIME,   # s
 PP_THR,          # lag block: throttle actuator, rad
 PP_HEADER) = offsets(*(1,) * 37, LAG_NPAR)

# --------------------------------------------------------------------------------- state layout
(PS_OMEGA_E,     # rad/s, engine speed
 PS_IDLE_I,      # rad, idle controller integral
 PS_GEAR,        # current gear: 1..n in D, 0 neutral, -1 reverse
 PS_RATIO_FROM,  # ratio at the start of the current shift
 PS_SHIFT_T,     # s since the current shift started
 PS_REQ,         # gear requested by the schedule
 PS_REQ_T,       # s the request has persisted
 PS_LOCKED,      # 1.0 lock-up engaged
 PS_THR,         # lag block state (3 + delay steps); LAG_Y is the throttle angle
 _) = offsets(*(1,) * 8, 3)

# ----------------------------------------------------------------------------------- inputs


class PtIn(IntEnum):
    """The powertrain's input array (powertrain_step's `inp`)."""
    (THROTTLE_CMD,  # rad
     OMEGA_LEFT,    # rad/s, spin rate of the driven axle's left wheel
     OMEGA_RIGHT,   # rad/s, and of its right wheel
     TORQUE_LEFT,   # N*m, measured drive torque (used in measured mode)
     TORQUE_RIGHT,  # N*m
     SELECTOR,      # +1 drive, 0 neutral, -1 reverse
     SIZE) = offsets(*(1,) * 6)


# ---------------------------------------------------------------------------------- outputs
(PO_TORQUE_LEFT,     # N*m, drive torque on the driven axle's left wheel
 PO_TORQUE_RIGHT,    # N*m, and on its right wheel
 PO_DTDW,            # N*m*s/rad, d T_left/d omega_left (= d T_left/d omega_right = the right row)
 PO_ENGINE_SPEED,    # rad/s
 PO_THROTTLE,        # rad, throttle plate angle
 PO_GEAR,            # gear number (0 N, -1 R)
 PO_RATIO,           # effective gearbox ratio (signed)
 PO_ENGINE_TORQUE,   # N*m, engine brake torque
 PO_PUMP_TORQUE,     # N*m
 PO_TURBINE_TORQUE,  # N*m (converter only, lock-up clutch excluded)
 PO_TURBINE_SPEED,   # rad/s
 PO_SPEED_RATIO,     # turbine / pump speed
 PO_IDLE_OPENING,    # rad, idle bypass opening
 PO_LOCKUP_TORQUE,   # N*m
 PO_SIZE) = offsets(*(1,) * 14)


# ------------------------------------------------------------------------------------------ config
def default_engine_map():
    """A plausible map for a 1.3 L carburetted four-cylinder (about 100 N*m at 3500 rpm, 46 kW at
    5500 rpm): brake torque = r (T_wot + T_fric) - T_fric, where T_fric(n) is the friction and pumping
    torque motored at closed throttle, T_wot the full-load curve, and r in (0, 1] the manifold filling
    set by the throttle's open area (plate closed at 7 deg, small leak) against the engine's demand.
    Returns (throttle nodes rad, speed nodes rad/s, table N*m [throttle][speed]), rounded to 0.1 N*m."""
    rpm = (0, 500, 800, 1000, 1500, 2000, 2500, 3000, 3500, 4000, 4500, 5000, 5500, 6000, 6500)
    wot = (58, 66, 74, 78, 86, 92, 96, 99, 100, 99, 96, 91, 80, 68, 52)
    throttle = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.65, 0.8, 1.0, 1.2, 1.4)
    th0 = math.radians(7.0)
    table = []
    for th in throttle:
        area = 6.3e-4 + 1.0 - math.cos(th + th0) / math.cos(th0)
        row = []
        for n, tw in zip(rpm, wot):
            ne = max(n, 480.0)
            fric = 8.0 + 2.4e-3 * ne + 3.0e-7 * ne * ne
            x = 2640.0 * area / (ne * RPM)
            r = x / (1.0 + x ** 4) ** 0.25
            row.append(round(r * (tw + fric) - fric, 1))
        table.append(tuple(row))
    return throttle, tuple(round(n * RPM, 4) for n in rpm), tuple(table)


_MAP = default_engine_map()


def _strictly_increasing(xs) -> bool:
    return all(b > a for a, b in zip(xs, xs[1:]))


MAX_ENGINE_SPEED = 2000.0     # rad/s (19 000 rpm)
MAX_GEARS = 6
ThrottleAngle = Range(0.0, 1.6, "rad")                      # throttle plate: closed 0 .. wide open ~pi/2
EngineSpeed = Range(0.0, MAX_ENGINE_SPEED, "rad/s")
Ratio = Range(0.0, 20.0, lo_open=True)                      # a gear's or the final drive's speed ratio
ShiftSpeed = Range(0.0, 100.0, "m/s")


@pydantic_config
@dataclass(frozen=True)
class EngineConfig:
    throttle_nodes: tuple[ThrottleAngle, ...] = _MAP[0]
    speed_nodes: tuple[EngineSpeed, ...] = _MAP[1]
    torque_table: tuple[tuple[Range(-2000.0, 5000.0, "N m at the crank"), ...], ...] = _MAP[2]   # [throttle][speed]
    inertia: Range(0.0, 10.0, "kg m^2", lo_open=True, hi_open=True) = 0.15   # crank + flywheel + pump and fluid
    idle_speed: Range(0.0, MAX_ENGINE_SPEED, "rad/s", lo_open=True) = 800.0 * RPM
    idle_kp: Range(0.0, 10.0, "rad per rad/s") = 0.002       # bypass opening per rad/s of speed error
    idle_ki: Range(0.0, 10.0, "rad per rad/s s") = 0.005
    idle_max_opening: ThrottleAngle = 0.12     # equivalent throttle angle of the bypass at full opening
    rev_limit: Range(0.0, MAX_ENGINE_SPEED, "rad/s", lo_open=True) = 6500.0 * RPM   # fuel cut
    rev_limit_band: Range(0.0, 200.0, "rad/s", lo_open=True) = 100.0 * RPM

    def __post_init__(self) -> None:
        check_declared_ranges(self)
        th, w, tab = self.throttle_nodes, self.speed_nodes, self.torque_table
        check(len(th) >= 2 and _strictly_increasing(th), "throttle_nodes", th,
              "expected >= 2 strictly increasing angles")
        check(len(w) >= 2 and _strictly_increasing(w), "speed_nodes", w, "expected >= 2 strictly increasing speeds")
        check(len(tab) == len(th) and all(len(r) == len(w) for r in tab), "torque_table",
              f"{len(tab)} rows", f"expected {len(th)} rows (throttle) of {len(w)} values (speed)")
        check(self.idle_speed < self.rev_limit, "idle_speed", self.idle_speed,
              "expected 0 < idle speed < rev limit (rad/s)")
        check(self.idle_max_opening <= th[-1], "idle_max_opening", self.idle_max_opening,
              f"expected 0..{th[-1]} rad")


@pydantic_config
@dataclass(frozen=True)
class ConverterConfig:
    speed_ratio_nodes: tuple[Range(0.0, 1.0, "turbine/pump speed", hi_open=True), ...] = (
        0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.85, 0.9, 0.95)
    k_factor: tuple[Range(0.0, 1e4, "(rad/s)/sqrt(N m)", lo_open=True, hi_open=True), ...] = (
        26.0, 26.2, 26.8, 28.4, 30.0, 33.0, 35.8, 41.5, 57.0)
    torque_ratio_nodes: tuple[Range(0.0, 1.0, "turbine/pump speed"), ...] = (0.0, 0.2, 0.4, 0.6, 0.7, 0.8, 0.85, 1.0)
    torque_ratio: tuple[Range(1.0, 5.0, "turbine/pump torque"), ...] = (2.1, 1.86, 1.62, 1.38, 1.25, 1.12, 1.0, 1.0)
    overrun_capacity_scale: Range(0.0, 10.0, lo_open=True) = 1.0   # capacity multiplier, turbine driving the pump
    lockup: bool = False                  # lock-up clutch fitted
    lockup_gear: Range(1, MAX_GEARS, integer=True) = 3   # engages only in this gear
    lockup_speed: Range(0.0, 100.0, "m/s") = 18.0        # engages above (releases 10 % below)
    lockup_capacity: Range(0.0, 5000.0, "N m", lo_open=True) = 250.0
    lockup_damping: Range(0.0, 1e4, "N m s/rad", lo_open=True) = 30.0   # slip damping of the engaged clutch

    def __post_init__(self) -> None:
        check_declared_ranges(self)
        sr, k = self.speed_ratio_nodes, self.k_factor
        check(len(sr) >= 2 and sr[0] == 0.0 and _strictly_increasing(sr), "speed_ratio_nodes", sr,
              "expected >= 2 strictly increasing ratios from 0 to below 1")
        check(len(k) == len(sr), "k_factor", k, f"expected {len(sr)} K factors, one per speed ratio node")
        tn, tr = self.torque_ratio_nodes, self.torque_ratio
        check(len(tn) >= 2 and tn[0] == 0.0 and _strictly_increasing(tn), "torque_ratio_nodes", tn,
              "expected >= 2 strictly increasing ratios from 0 up to 1")
        check(len(tr) == len(tn), "torque_ratio", tr, f"expected {len(tn)} torque ratios, one per node")
        check(tr[-1] == 1.0, "torque_ratio", tr, "expected the last torque ratio (coupling) = 1")

    def coupling_point(self) -> float:
        """Speed ratio from which the torque ratio is 1."""
        for x, t in zip(self.torque_ratio_nodes, self.torque_ratio):
            if t == 1.0:
                return x
        return 1.0


@pydantic_config
@dataclass(frozen=True)
class GearboxConfig:
    ratios: tuple[Ratio, ...] = (2.45, 1.45, 1.00)   # forward gears, a small 3-speed automatic
    reverse_ratio: Ratio = 2.18
    final_drive: Ratio = 3.9
    efficiency: Range(0.5, 1.0) = 0.95    # gearbox and final drive together
    wheel_radius: Range(0.05, 2.0, "m", lo_open=True, hi_open=True) = 0.28   # wheel speed to vehicle speed
    schedule_throttle: tuple[ThrottleAngle, ...] = (0.0, 0.3, 0.7, 1.4)
    upshift_speeds: tuple[tuple[ShiftSpeed, ...], ...] = ((3.5, 6.0, 10.0, 15.0), (6.5, 11.0, 17.0, 25.0))
    downshift_speeds: tuple[tuple[ShiftSpeed, ...], ...] = ((2.0, 3.5, 6.0, 10.0), (4.5, 7.5, 11.0, 19.0))
    shift_delay: Range(0.0, 5.0, "s") = 0.2   # a shift request must persist
    shift_time: Range(0.0, 5.0, "s") = 0.25   # for the ratio change

    def __post_init__(self) -> None:
        check_declared_ranges(self)
        r = self.ratios
        check(2 <= len(r) <= MAX_GEARS and all(b < a for a, b in zip(r, r[1:])),
              "ratios", r, f"expected 2..{MAX_GEARS} decreasing ratios")
        st = self.schedule_throttle
        check(len(st) >= 1 and _strictly_increasing(st), "schedule_throttle", st,
              "expected strictly increasing throttle angles (rad)")
        for key, rows in (("upshift_speeds", self.upshift_speeds), ("downshift_speeds", self.downshift_speeds)):
            check(len(rows) == len(r) - 1 and all(len(row) == len(st) for row in rows), key,
                  rows, f"expected {len(r) - 1} rows (one per shift) of {len(st)} speeds (m/s)")
        for k, (up, dn) in enumerate(zip(self.upshift_speeds, self.downshift_speeds)):
            check(all(0.0 <= d < u for u, d in zip(up, dn)), f"downshift_speeds[{k}]", dn,
                  f"expected 0 <= downshift < upshift speed {up} at each throttle (hysteresis)")


def _default_throttle() -> LagConfig:
    return LagConfig(time_constant=0.05, rate_limit=5.0, delay=0.0, min=0.0, max=1.4)


@pydantic_config
@dataclass(frozen=True)
class PowertrainConfig:
    engine: EngineConfig = field(default_factory=EngineConfig)
    converter: ConverterConfig = field(default_factory=ConverterConfig)
    gearbox: GearboxConfig = field(default_factory=GearboxConfig)
    throttle: LagConfig = field(default_factory=_default_throttle)   # rad, rad/s
    wheel_torque_source: Literal["model", "measured"] = "model"

    def __post_init__(self) -> None:
        check(self.throttle.min >= 0.0, "throttle.min", self.throttle.min, "expected >= 0 rad")
        check(self.throttle.max <= 1.6, "throttle.max", self.throttle.max, "expected <= 1.6 rad")
        check(self.wheel_torque_source in ("model", "measured"), "wheel_torque_source",
              self.wheel_torque_source, "expected 'model' or 'measured'")
        check(1 <= self.converter.lockup_gear <= len(self.gearbox.ratios), "converter.lockup_gear",
              self.converter.lockup_gear, f"expected 1..{len(self.gearbox.ratios)}")


def powertrain_config(data=None, where: str = "powertrain") -> PowertrainConfig:
    """Validated PowertrainConfig from a mapping (a TOML table), an instance, or None (defaults)."""
    return part_config(PowertrainConfig, data, where)


def powertrain_params(cfg: PowertrainConfig | None = None) -> np.ndarray:
    cfg = powertrain_config(cfg)
    e, c, g = cfg.engine, cfg.converter, cfg.gearbox
    head = np.zeros(PP_HEADER)
    blocks = []
    pos = PP_HEADER

    def put(values) -> int:
        nonlocal pos
        arr = np.asarray(values, dtype=float).ravel()
        off = pos
        blocks.append(arr)
        pos += arr.size
        return off

    head[PP_MEASURED] = 1.0 if cfg.wheel_torque_source == "measured" else 0.0
    head[PP_J] = e.inertia
    head[PP_IDLE] = e.idle_speed
    head[PP_IDLE_KP] = e.idle_kp
    head[PP_IDLE_KI] = e.idle_ki
    head[PP_IDLE_MAX] = e.idle_max_opening
    head[PP_REV] = e.rev_limit
    head[PP_REV_BAND] = e.rev_limit_band
    head[PP_TH_OFF], head[PP_TH_N] = put(e.throttle_nodes), len(e.throttle_nodes)
    head[PP_W_OFF], head[PP_W_N] = put(e.speed_nodes), len(e.speed_nodes)
    head[PP_MAP_OFF] = put(e.torque_table)
    head[PP_SR_OFF], head[PP_SR_N] = put(c.speed_ratio_nodes), len(c.speed_ratio_nodes)
    head[PP_K_OFF] = put(c.k_factor)
    head[PP_TRN_OFF], head[PP_TRN_N] = put(c.torque_ratio_nodes), len(c.torque_ratio_nodes)
    head[PP_TR_OFF] = put(c.torque_ratio)
    head[PP_OVERRUN] = c.overrun_capacity_scale
    head[PP_LOCKUP] = 1.0 if c.lockup else 0.0
    head[PP_LU_GEAR] = c.lockup_gear
    head[PP_LU_SPEED] = c.lockup_speed
    head[PP_LU_CAP] = c.lockup_capacity
    head[PP_LU_C] = c.lockup_damping
    head[PP_NGEAR] = len(g.ratios)
    head[PP_RATIO_OFF] = put(g.ratios)
    head[PP_REV_RATIO] = g.reverse_ratio
    head[PP_FD] = g.final_drive
    head[PP_EFF] = g.efficiency
    head[PP_RW] = g.wheel_radius
    head[PP_SCH_OFF], head[PP_SCH_N] = put(g.schedule_throttle), len(g.schedule_throttle)
    head[PP_UP_OFF] = put(g.upshift_speeds)
    head[PP_DN_OFF] = put(g.downshift_speeds)
    head[PP_SHIFT_DELAY] = g.shift_delay
    head[PP_SHIFT_TIME] = g.shift_time
    head[PP_THR:PP_THR + LAG_NPAR] = cfg.throttle.params()
    return np.concatenate([head] + blocks)


def powertrain_state(params: np.ndarray, dt: float, engine_speed: float | None = None,
                     throttle: float = 0.0, gear: int = 1) -> np.ndarray:
    """Initial state: engine at `engine_speed` (default: idle), throttle settled at `throttle`, in
    `gear` (1..n in D, 0 for N, -1 for R) with no shift under way."""
    s = np.zeros(PS_THR + lag_state_size(params, PP_THR, dt))
    s[PS_OMEGA_E] = params[PP_IDLE] if engine_speed is None else engine_speed
    s[PS_GEAR] = gear
    s[PS_REQ] = gear
    s[PS_SHIFT_T] = 1e9
    if gear >= 1:
        s[PS_RATIO_FROM] = params[int(params[PP_RATIO_OFF]) + gear - 1]
    elif gear < 0:
        s[PS_RATIO_FROM] = -params[PP_REV_RATIO]
    lag_init(params, PP_THR, s, PS_THR, dt, throttle)
    return s


def schedule_gear(params: np.ndarray, speed: float, throttle: float = 0.0) -> int:
    """The gear the shift schedule holds in D at vehicle speed `speed` (m/s) and throttle (rad) when
    the car got there accelerating: 1 + the number of upshift lines below the speed (the first step
    neither up- nor downshifts, as every downshift line lies below its upshift line)."""
    gear = 1
    while gear < int(params[PP_NGEAR]) and speed > shift_speeds(params, gear, throttle)[0]:
        gear += 1
    return gear


def _stable_root(f, lo: float, hi: float, near: float, n: int = 400, f_grid=None) -> float:
    """The zero of f in [lo, hi] where f falls through 0 (a stable equilibrium of J dw/dt = f) nearest
    `near`; without one, the grid point of smallest |f|. ``f_grid(xs)``: f at each of the points xs in
    one call (the same values as f's)."""
    from scipy.optimize import brentq
    xs = np.linspace(lo, hi, n)
    fs = np.array([f(x) for x in xs]) if f_grid is None else f_grid(xs)
    roots = [brentq(f, xs[i], xs[i + 1], xtol=1e-12) for i in range(n - 1)
             if fs[i] > 0.0 >= fs[i + 1]]
    if not roots:
        return float(xs[int(np.argmin(np.abs(fs)))])
    return float(min(roots, key=lambda r: abs(r - near)))


_ROLLING: dict = {}          # powertrain_state_rolling's states by its arguments (this process's)


def powertrain_state_rolling(params: np.ndarray, dt: float, wheel_speed: float, throttle: float = 0.0,
                             selector: float = 1.0) -> np.ndarray:
    """``_rolling_state`` (below), kept per process for the same arguments (a copy each call): every run
    of a batch starts its car from the same speed, and the root search takes milliseconds."""
    key = (np.asarray(params, dtype=float).tobytes(), float(dt), float(wheel_speed), float(throttle), float(selector))
    s = _ROLLING.get(key)
    if s is None:
        s = _rolling_state(params, dt, wheel_speed, throttle, selector)
        if len(_ROLLING) >= 64:
            _ROLLING.clear()
        _ROLLING[key] = s
    return s.copy()


def _rolling_state(params: np.ndarray, dt: float, wheel_speed: float, throttle: float = 0.0,
                  selector: float = 1.0, compiled_scan: bool = True) -> np.ndarray:
    """Initial state of a car already rolling with its driven wheels at `wheel_speed` (rad/s, mean of
    rl and rr) and the throttle settled at `throttle` (rad): the state powertrain_step keeps, so a
    scenario started at speed has no start-up transient. In D the gear is the schedule's
    (schedule_gear), the turbine turns at wheel speed x gear ratio x final drive, the lock-up clutch is
    engaged if its gear and speed say so, and the engine runs at the speed where its map torque
    balances the converter (and clutch) torque at that turbine speed. Closed throttle while coasting
    (turbine above idle) that is the overrun equilibrium a little below the turbine speed, with the
    idle controller wound down to zero; at low turbine speed the engine idles at the set speed with the
    controller's integral holding the bypass opening that carries the converter's load."""
    s = powertrain_state(params, dt, throttle=throttle, gear=0)
    thr = float(s[PS_THR + LAG_Y])          # the settled plate angle (the command within its travel)
    v = params[PP_RW] * wheel_speed
    if selector > 0.5:
        gear = schedule_gear(params, v, thr)
    elif selector < -0.5:
        gear = -1
    else:
        gear = 0
    ratio = _gear_ratio(params, gear)
    s[PS_GEAR] = s[PS_REQ] = gear
    s[PS_RATIO_FROM] = ratio
    wt = ratio * params[PP_FD] * wheel_speed
    coupled = gear != 0
    locked = (params[PP_LOCKUP] > 0.5 and gear == int(params[PP_LU_GEAR]) and v > params[PP_LU_SPEED])
    s[PS_LOCKED] = 1.0 if locked else 0.0

    def net(w, idle_i):
        return _engine_net(params, thr, idle_i, w, wt, coupled, locked)[0]

    def grid(idle_i):           # net over a scan's points in one compiled call (compiled_scan)
        if not compiled_scan:
            return None
        return lambda xs: _net_grid(params, thr, idle_i, xs, wt, coupled, locked, np.empty(xs.size))

    idle = params[PP_IDLE]
    top = 1.05 * max(params[PP_REV], abs(wt))     # an overrunning turbine may drag it past the limiter
    # above idle the integral winds down to zero (clamped); the engine settles where net(w, 0) = 0
    w = _stable_root(lambda x: net(x, 0.0), 0.0, top, max(abs(wt), idle), f_grid=grid(0.0))
    idle_i = 0.0
    if w < idle:
        # below idle the integral winds up until the engine idles: net(idle, I) = 0, net rising in I
        imax = params[PP_IDLE_MAX]
        if net(idle, imax) <= 0.0:
            idle_i = imax                      # the bypass cannot carry the load: engine below idle
            w = _stable_root(lambda x: net(x, imax), 0.0, top, idle, f_grid=grid(imax))
        elif net(idle, 0.0) < 0.0:
            from scipy.optimize import brentq
            idle_i = brentq(lambda i: net(idle, i), 0.0, imax, xtol=1e-14)
            w = idle
    s[PS_OMEGA_E] = w
    s[PS_IDLE_I] = idle_i
    return s


def describe(cfg: PowertrainConfig | None = None) -> dict:
    """Key figures: peak torque and power of the map at full throttle, idle speed, ratios."""
    cfg = powertrain_config(cfg)
    e = cfg.engine
    wot = e.torque_table[-1]
    powers = [t * w for t, w in zip(wot, e.speed_nodes)]
    k = int(np.argmax(powers))
    return {
        "peak_torque_Nm": max(wot),
        "peak_torque_rpm": e.speed_nodes[int(np.argmax(wot))] / RPM,
        "peak_power_kW": powers[k] / 1e3,
        "peak_power_rpm": e.speed_nodes[k] / RPM,
        "idle_rpm": e.idle_speed / RPM,
        "stall_k_factor": cfg.converter.k_factor[0],
        "stall_torque_ratio": cfg.converter.torque_ratio[0],
        "coupling_point": cfg.converter.coupling_point(),
        "gear_ratios": cfg.gearbox.ratios,
        "final_drive": cfg.gearbox.final_drive,
        "wheel_torque_source": cfg.wheel_torque_source,
    }


# ----------------------------------------------------------------------------------------- kernels
@inline_kernel
def _segment(p, xo, n, x):
    """Interval i of the nodes p[xo:xo+n] holding x, the fraction t in it, and whether x is inside
    (outside, x is clamped to the end node; the end nodes themselves count as inside)."""
    if x < p[xo]:
        return 0, 0.0, False
    if x > p[xo + n - 1]:
        return n - 2, 1.0, False
    i = 0
    while i < n - 2 and x >= p[xo + i + 1]:
        i += 1
    return i, (x - p[xo + i]) / (p[xo + i + 1] - p[xo + i]), True


@kernel
def interp1(p, xo, yo, n, x):
    """Linear interpolation in the table (p[xo:xo+n], p[yo:yo+n]), held constant outside. Returns
    (y, dy/dx)."""
    i, t, inside = _segment(p, xo, n, x)
    y0 = p[yo + i]
    y1 = p[yo + i + 1]
    d = (y1 - y0) / (p[xo + i + 1] - p[xo + i]) if inside else 0.0
    return y0 + t * (y1 - y0), d


@kernel
def bilinear(p, xo, nx, yo, ny, zo, x, y):
    """Bilinear interpolation of z[i*ny + j] (p[zo:]) over nodes x_i (p[xo:]) and y_j (p[yo:]), held
    constant beyond the edges. Returns (z, dz/dx, dz/dy)."""
    i, u, in_x = _segment(p, xo, nx, x)
    j, v, in_y = _segment(p, yo, ny, y)
    z00 = p[zo + i * ny + j]
    z01 = p[zo + i * ny + j + 1]
    z10 = p[zo + (i + 1) * ny + j]
    z11 = p[zo + (i + 1) * ny + j + 1]
    z = (1 - u) * (1 - v) * z00 + (1 - u) * v * z01 + u * (1 - v) * z10 + u * v * z11
    dzdx = 0.0
    dzdy = 0.0
    if in_x:
        dzdx = ((1 - v) * (z10 - z00) + v * (z11 - z01)) / (p[xo + i + 1] - p[xo + i])
    if in_y:
        dzdy = ((1 - u) * (z01 - z00) + u * (z11 - z10)) / (p[yo + j + 1] - p[yo + j])
    return z, dzdx, dzdy


@kernel
def engine_map_torque(p, throttle, omega):
    """Engine brake torque from the map (N*m) at throttle angle (rad) and speed (rad/s). Returns
    (T, dT/d throttle, dT/d omega)."""
    return bilinear(p, int(p[PP_TH_OFF]), int(p[PP_TH_N]), int(p[PP_W_OFF]), int(p[PP_W_N]),
                    int(p[PP_MAP_OFF]), throttle, omega)


@kernel
def converter_capacity(p, sr):
    """Capacity C = 1/K(SR)^2 (N*m/(rad/s)^2) for 0 <= SR <= 1 and dC/dSR: K linear between its
    nodes, C linear from the last node to 0 at SR = 1."""
    so = int(p[PP_SR_OFF])
    n = int(p[PP_SR_N])
    ko = int(p[PP_K_OFF])
    last = p[so + n - 1]
    if sr <= last:
        k, dk = interp1(p, so, ko, n, sr)
        c = 1.0 / (k * k)
        return c, -2.0 * c * dk / k
    c_last = 1.0 / (p[ko + n - 1] * p[ko + n - 1])
    if sr >= 1.0:
        return 0.0, 0.0
    return c_last * (1.0 - sr) / (1.0 - last), -c_last / (1.0 - last)


@kernel
def converter_torques(p, wp, wt):
    """Torque converter: pump speed wp >= 0, turbine speed wt (rad/s). Returns (T_p, T_t, dT_p/d wp,
    dT_p/d wt, dT_t/d wp, dT_t/d wt); T_p loads the engine, T_t drives the turbine shaft."""
    if wp <= 0.0 and wt <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if wp >= wt:
        # pump drives: speed ratio in [0, 1); a backwards turbine counts as stall
        if wt >= 0.0:
            sr = wt / wp
            dsr_dwp = -sr / wp
            dsr_dwt = 1.0 / wp
        else:
            sr = 0.0
            dsr_dwp = 0.0
            dsr_dwt = 0.0
        c, dc = converter_capacity(p, sr)
        tr, dtr = interp1(p, int(p[PP_TRN_OFF]), int(p[PP_TR_OFF]), int(p[PP_TRN_N]), sr)
        tp = c * wp * wp
        dtp_dsr = dc * wp * wp
        dtp_dwp = 2.0 * c * wp + dtp_dsr * dsr_dwp
        dtp_dwt = dtp_dsr * dsr_dwt
        tt = tr * tp
        return (tp, tt, dtp_dwp, dtp_dwt,
                tr * dtp_dwp + dtr * dsr_dwp * tp, tr * dtp_dwt + dtr * dsr_dwt * tp)
    # overrun: turbine drives the pump, coupling (torque ratio 1) with swapped roles
    sr = wp / wt if wp > 0.0 else 0.0
    c, dc = converter_capacity(p, sr)
    c *= p[PP_OVERRUN]
    dc *= p[PP_OVERRUN]
    t = -c * wt * wt
    dt_dwp = -dc * wt                  # d sr/d wp = 1/wt
    dt_dwt = -2.0 * c * wt + dc * wp   # d sr/d wt = -wp/wt^2
    if wp <= 0.0:
        dt_dwp = 0.0
    return t, t, dt_dwp, dt_dwt, dt_dwp, dt_dwt


@kernel
def _net_grid(p, thr, idle_i, ws, wt, coupled, locked, out):
    """out[i] = _engine_net(...)[0] at each engine speed ws[i] (a root scan's points); returns out."""
    for i in range(ws.size):
        out[i] = _engine_net(p, thr, idle_i, ws[i], wt, coupled, locked)[0]
    return out


@kernel
def _engine_net(p, thr, idle_i, w, wt, coupled, locked):
    """Net torque on the engine shaft at speed w with the idle controller's integral idle_i and the
    turbine at wt. Returns (net, d net/d w, T_e, T_p, T_t, T_lu, d T_t/d wt + d T_lu/d wt, idle_opening)."""
    # idle bypass: PI, proportional part on the current speed, clamped
    u = p[PP_IDLE_KP] * (p[PP_IDLE] - w) + idle_i
    du = -p[PP_IDLE_KP]
    if u <= 0.0:
        u = 0.0
        du = 0.0
    elif u >= p[PP_IDLE_MAX]:
        u = p[PP_IDLE_MAX]
        du = 0.0
    th = thr + u
    dth = du
    # rev limiter: the throttle fades to zero over the band below the limit
    f = (p[PP_REV] - w) / p[PP_REV_BAND]
    if f >= 1.0:
        f = 1.0
        df = 0.0
    elif f <= 0.0:
        f = 0.0
        df = 0.0
    else:
        df = -1.0 / p[PP_REV_BAND]
    dth = dth * f + th * df
    th = th * f
    te, dte_dth, dte_dw = engine_map_torque(p, th, w)
    dnet = dte_dw + dte_dth * dth
    tp = 0.0
    tt = 0.0
    dtt_dwt = 0.0
    if coupled:
        tp, tt, dtp_dwp, dtp_dwt, dtt_dwp, dtt_dwt = converter_torques(p, w, wt)
        dnet -= dtp_dwp
    tlu = 0.0
    if locked:
        cap = p[PP_LU_CAP]
        cl = p[PP_LU_C]
        tlu = cl * (w - wt)
        if tlu > cap:
            tlu = cap
        elif tlu < -cap:
            tlu = -cap
        else:
            dnet -= cl
            dtt_dwt -= cl
    return te - tp - tlu, dnet, te, tp, tt, tlu, dtt_dwt, u


@kernel
def _gear_ratio(p, gear):
    if gear >= 1:
        return p[int(p[PP_RATIO_OFF]) + gear - 1]
    if gear <= -1:
        return -p[PP_REV_RATIO]
    return 0.0


@kernel
def shift_speeds(p, shift, throttle):
    """Upshift speed of gear `shift` -> shift+1 and downshift speed of shift+1 -> shift (m/s) at the
    throttle angle, linear in the schedule's throttle nodes and held beyond them."""
    so = int(p[PP_SCH_OFF])
    n = int(p[PP_SCH_N])
    row = (shift - 1) * n
    if n == 1:
        return p[int(p[PP_UP_OFF]) + row], p[int(p[PP_DN_OFF]) + row]
    up, _ = interp1(p, so, int(p[PP_UP_OFF]) + row, n, throttle)
    dn, _ = interp1(p, so, int(p[PP_DN_OFF]) + row, n, throttle)
    return up, dn


@kernel
def _gearbox(p, s, selector, v, thr, dt):
    """Gear selection and ratio (signed, blended during a shift). Returns the effective ratio."""
    gear = int(s[PS_GEAR])
    if selector > 0.5:
        if gear < 1:                       # engaging D: first gear at once
            gear = 1
            s[PS_GEAR] = 1.0
            s[PS_REQ] = 1.0
            s[PS_REQ_T] = 0.0
            s[PS_SHIFT_T] = 1e9
            s[PS_RATIO_FROM] = _gear_ratio(p, 1)
        n = int(p[PP_NGEAR])
        want = gear
        if gear < n:
            up, _ = shift_speeds(p, gear, thr)
            if v > up:
                want = gear + 1
        if want == gear and gear > 1:
            _, dn = shift_speeds(p, gear - 1, thr)
            if v < dn:
                want = gear - 1
        shifting = s[PS_SHIFT_T] < p[PP_SHIFT_TIME]
        if want != gear and not shifting:
            if int(s[PS_REQ]) == want:
                s[PS_REQ_T] += dt
            else:
                s[PS_REQ] = want
                s[PS_REQ_T] = dt
            if s[PS_REQ_T] >= p[PP_SHIFT_DELAY] - 1e-9:
                s[PS_RATIO_FROM] = _effective_ratio(p, s)
                s[PS_GEAR] = want
                s[PS_SHIFT_T] = 0.0
                s[PS_REQ_T] = 0.0
        else:
            if not shifting:
                s[PS_REQ] = gear
            s[PS_REQ_T] = 0.0
        s[PS_SHIFT_T] += dt
    elif selector < -0.5:
        s[PS_GEAR] = -1.0
        s[PS_SHIFT_T] = 1e9
        s[PS_RATIO_FROM] = _gear_ratio(p, -1)
    else:
        s[PS_GEAR] = 0.0
        s[PS_SHIFT_T] = 1e9
        s[PS_RATIO_FROM] = 0.0
    return _effective_ratio(p, s)


@kernel
def _effective_ratio(p, s):
    target = _gear_ratio(p, int(s[PS_GEAR]))
    ts = p[PP_SHIFT_TIME]
    t = s[PS_SHIFT_T]
    if ts <= 0.0 or t >= ts:
        return target
    return s[PS_RATIO_FROM] + (target - s[PS_RATIO_FROM]) * (t / ts)


@kernel
def powertrain_step(p, s, inp, dt, out):
    """Advance throttle actuator, gearbox logic and engine speed by one step; write drive torques and
    sensor values into out (PO_*). Returns the engine speed (rad/s)."""
    thr = lag_step(p, PP_THR, s, PS_THR, inp[PtIn.THROTTLE_CMD], dt)
    w_carrier = 0.5 * (inp[PtIn.OMEGA_LEFT] + inp[PtIn.OMEGA_RIGHT])
    v = p[PP_RW] * w_carrier
    ratio = _gearbox(p, s, inp[PtIn.SELECTOR], v, thr, dt)
    gear = int(s[PS_GEAR])
    rtot = ratio * p[PP_FD]
    wt = rtot * w_carrier
    coupled = gear != 0
    # lock-up clutch: in its gear above its speed (10 % hysteresis), never during a shift
    locked = False
    if p[PP_LOCKUP] > 0.5 and gear == int(p[PP_LU_GEAR]) and s[PS_SHIFT_T] >= p[PP_SHIFT_TIME]:
        if s[PS_LOCKED] > 0.5:
            locked = v > 0.9 * p[PP_LU_SPEED]
        else:
            locked = v > p[PP_LU_SPEED]
    s[PS_LOCKED] = 1.0 if locked else 0.0
    # backward Euler on J dw/dt = net(w): two Newton iterations from the current speed
    j = p[PP_J]
    w0 = s[PS_OMEGA_E]
    idle_i = s[PS_IDLE_I]
    w = w0
    for _ in range(2):
        net, dnet, te, tp, tt, tlu, dtt, u = _engine_net(p, thr, idle_i, w, wt, coupled, locked)
        g = j * (w - w0) - dt * net
        dg = j - dt * (dnet if dnet < 0.0 else 0.0)
        w = w - g / dg
        if w < 0.0:
            w = 0.0
    net, dnet, te, tp, tt, tlu, dtt, u = _engine_net(p, thr, idle_i, w, wt, coupled, locked)
    s[PS_OMEGA_E] = w
    # idle controller integral (clamped: anti-windup)
    idle_i += p[PP_IDLE_KI] * (p[PP_IDLE] - w) * dt
    s[PS_IDLE_I] = saturate(idle_i, 0.0, p[PP_IDLE_MAX])
    # drive torques through gearbox, final drive and open differential
    shaft = tt + tlu
    eff = p[PP_EFF] if shaft >= 0.0 else 1.0 / p[PP_EFF]
    t_wheel = 0.5 * eff * rtot * shaft
    dtdw = 0.25 * eff * rtot * rtot * dtt if coupled else 0.0
    if p[PP_MEASURED] > 0.5:
        out[PO_TORQUE_LEFT] = inp[PtIn.TORQUE_LEFT]
        out[PO_TORQUE_RIGHT] = inp[PtIn.TORQUE_RIGHT]
        out[PO_DTDW] = 0.0
    else:
        out[PO_TORQUE_LEFT] = t_wheel
        out[PO_TORQUE_RIGHT] = t_wheel
        out[PO_DTDW] = dtdw
    out[PO_ENGINE_SPEED] = w
    out[PO_THROTTLE] = thr
    out[PO_GEAR] = gear
    out[PO_RATIO] = ratio
    out[PO_ENGINE_TORQUE] = te
    out[PO_PUMP_TORQUE] = tp
    out[PO_TURBINE_TORQUE] = tt
    out[PO_TURBINE_SPEED] = wt
    out[PO_SPEED_RATIO] = wt / w if w > 0.0 else 0.0
    out[PO_IDLE_OPENING] = u
    out[PO_LOCKUP_TORQUE] = tlu
    return w
