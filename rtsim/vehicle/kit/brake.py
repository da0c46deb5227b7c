"""Brake-by-wire: hydraulic pressure actuator, front/rear proportioning and per-wheel friction brakes
with stiction.

Sliding torque (seed eq. 5): each caliper of n pads with friction coefficient mu, piston area A (m^2)
and effective pad radius R (m), at wheel-cylinder pressure p (Pa), gives tau = n mu p A R. Pressures
are carried in kPa, so the per-wheel *gain* n mu A R * 1000 is in N*m/kPa.

Pressure path: ``brake_pressure_cmd`` (kPa) -> lag block (transport delay, first-order lag of
30-60 ms, rate limit in kPa/s, bounds) -> line pressure (the ``brake_pressure`` sensor) -> front
wheels at line pressure, rear wheels through a proportioning valve: p_rear = p below the knee pressure,
knee + ratio (p - knee) above it.

Stiction, written for an implicit multibody step. Each wheel is in one of two modes, changed only
between steps (``brake_commit``); within a step the torque is a continuous, piecewise-linear function
of the wheel angle theta and angular velocity omega, with its derivatives for the tangent matrix
(``brake_wheel_torque`` returns tau, d tau/d omega, d tau/d theta):

- slide: tau = -tau_s sat(omega / omega_eps), tau_s = n mu p A R, a Coulomb law regularised over the
  band |omega| < omega_eps (slope -tau_s / omega_eps there, 0 outside);
- stick: a torsional spring-damper to an anchor angle theta_a captured when the wheel stuck,
  tau = -k (theta - theta_a) - c omega, clipped to the breakaway torque tau_b = (mu_s / mu) tau_s.
  Under a steady load the wheel settles at a fixed angle (the spring's static deflection), so there is
  no creep at all and no chatter, and the torque is whatever the load needs up to tau_b.

Transitions (checked after the step with the converged theta, omega):

- stick -> slide when the unclipped spring-damper torque exceeds tau_b (the load beats static
  friction, or the pressure fell); the anchor slips to where the spring carries exactly tau_b;
- slide -> stick when the brake is applied (tau_b > 0), |omega| <= omega_stick and the wheel is not
  speeding up (|omega| <= |omega_prev|, or omega changed sign). The anchor is placed so that the
  spring-damper torque equals the regularised torque at that instant (no torque jump). A wheel that
  just broke away is accelerating, so it is not caught again.

A wheel that starts at rest with the brake applied should start stuck (``brake_state(stuck=True)``).

Per step: ``brake_step`` (pressure to t_n+1 and the torque limits), then any number of
``brake_wheel_torque`` calls inside the multibody Newton iteration, then ``brake_commit`` with the
converged wheel angles and speeds. ``brake_torques`` evaluates all four wheels at once. Signs: omega
positive rolling forward (channels.py), torques act on the wheel about the same axis.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rtsim.jit import kernel

from .layout import offsets
from rtsim.configfile import Range, check_declared_ranges

from .actuators import (LAG_NPAR, LAG_Y, LagConfig, check, part_config, pydantic_config, lag_init, lag_state_size,
                        lag_step)

NWHEEL = 4          # fl, fr, rl, rr (rtsim.channels.WHEELS)
FRONT = (0, 1)
REAR = (2, 3)

# Parameter layout (float64 array).
(BP_GAIN,         # [4] N*m per kPa of wheel-cylinder pressure, n mu A R * 1000
 BP_BREAK_RATIO,  # [4] mu_s / mu
 BP_KNEE,         # kPa, proportioning valve knee pressure
 BP_RATIO,        # -, proportioning valve slope above the knee
 BP_K,            # N*m/rad, stick anchor stiffness
 BP_C,            # N*m*s/rad, stick anchor damping
 BP_EPS,          # rad/s, regularisation band of the sliding law
 BP_STICK,        # rad/s, speed below which a slowing wheel sticks
 BP_ACT,          # lag block (LAG_NPAR floats): pressure actuator, kPa
 BP_STUCK,        # [4] 1.0: the wheel's caliper is stuck (a fault, rtsim.faults): its torques stay as they are
 BP_SIZE) = offsets(NWHEEL, NWHEEL, *(1,) * 6, LAG_NPAR, NWHEEL)

# State layout.
(BS_MODE,        # [4] 1.0 stick, 0.0 slide
 BS_ANCHOR,      # [4] rad, anchor angle (meaningful in stick)
 BS_OMEGA_PREV,  # [4] rad/s, wheel speed at the last commit
 BS_TAU_SLIDE,   # [4] N*m, sliding torque tau_s at the current pressure
 BS_TAU_BREAK,   # [4] N*m, breakaway torque tau_b
 BS_P_FRONT,     # kPa, front wheel-cylinder pressure
 BS_P_REAR,      # kPa, rear wheel-cylinder pressure
 BS_ACT,         # lag block state (3 + delay steps); its LAG_Y is the line pressure, kPa
 _) = offsets(NWHEEL, NWHEEL, NWHEEL, NWHEEL, NWHEEL, 1, 1, 3)

# Inputs.
(BI_PRESSURE_CMD,  # kPa, brake_pressure_cmd
 BI_SIZE) = offsets(1)

# Outputs.
(BO_LINE,       # kPa, line pressure (the brake_pressure sensor)
 BO_FRONT,      # kPa
 BO_REAR,       # kPa
 BO_TAU_SLIDE,  # [4] N*m
 BO_TAU_BREAK,  # [4] N*m
 BO_TORQUE,     # [4] N*m, brake torque on each wheel (brake_torques)
 BO_DTDW,       # [4] N*m*s/rad, d torque / d omega
 BO_DTDTH,      # [4] N*m/rad, d torque / d theta
 BO_SIZE) = offsets(1, 1, 1, NWHEEL, NWHEEL, NWHEEL, NWHEEL, NWHEEL)

STICK = 1.0
SLIDE = 0.0


# ------------------------------------------------------------------------------------------ config
@pydantic_config
@dataclass(frozen=True)
class BrakeAxleConfig:
    """One axle's calipers (seed eq. 5)."""
    pads: Range(1, 16, "pads", integer=True) = 2                  # n, friction pads per caliper
    mu: Range(0.0, 2.0, lo_open=True) = 0.38                       # sliding pad/disc friction coefficient
    mu_static: Range(0.0, 3.0, lo_open=True) = 0.45                # static friction coefficient (>= mu)
    piston_area: Range(0.0, 0.1, "m^2", lo_open=True, hi_open=True) = 1.81e-3   # A (48 mm piston)
    effective_radius: Range(0.0, 1.0, "m", lo_open=True, hi_open=True) = 0.095  # R, disc centre to pads

    def __post_init__(self) -> None:
        check_declared_ranges(self)
        check(self.mu <= self.mu_static, "mu_static", self.mu_static, f"expected mu ({self.mu}) <= mu_static <= 3")

    def gain(self) -> float:
        """N*m per kPa: n mu A R * 1000."""
        return self.pads * self.mu * self.piston_area * self.effective_radius * 1000.0


def _default_rear() -> BrakeAxleConfig:
    return BrakeAxleConfig(pads=2, mu=0.35, mu_static=0.42, piston_area=1.13e-3, effective_radius=0.085)


def _default_actuator() -> LagConfig:
    return LagConfig(time_constant=0.045, rate_limit=40000.0, delay=0.0, min=0.0, max=12000.0)


@pydantic_config
@dataclass(frozen=True)
class BrakeConfig:
    front: BrakeAxleConfig = field(default_factory=BrakeAxleConfig)
    rear: BrakeAxleConfig = field(default_factory=_default_rear)
    proportioning_knee: Range(0.0, math.inf, "kPa", hi_open=True) = 2500.0   # rear = line pressure up to here
    proportioning_ratio: Range(0.0, 1.0) = 0.4                             # rear pressure slope above the knee
    actuator: LagConfig = field(default_factory=_default_actuator)   # kPa, kPa/s
    # stick spring: stands for the pads' and caliper's shear compliance. 1e5 N*m/rad is ~4x the tyre's
    # contact spring seen at the wheel (Kx / sigma r^2 ~ 2.6e4), so a held wheel adds little compliance
    # of its own to the car rocking on its tyres after a stop (3e4 doubled it); 3e5 stalls Newton at
    # the validation's 2 ms fitting step. Damping ratio ~0.8 with the wheel's spin inertia.
    anchor_stiffness: Range(0.0, 1e9, "N m/rad", lo_open=True, hi_open=True) = 1.0e5
    anchor_damping: Range(0.0, 1e7, "N m s/rad", hi_open=True) = 450.0
    omega_eps: Range(0.0, 10.0, "rad/s", lo_open=True) = 0.05     # sliding-law regularisation band
    omega_stick: Range(0.0, 10.0, "rad/s", lo_open=True) = 0.05   # a slowing wheel sticks below this speed

    def __post_init__(self) -> None:
        check_declared_ranges(self)
        check(self.actuator.min >= 0.0, "actuator.min", self.actuator.min,
              "expected a pressure >= 0 kPa")
        check(math.isfinite(self.actuator.max), "actuator.max", self.actuator.max,
              "expected a finite maximum pressure in kPa")


def brake_config(data=None, where: str = "brake") -> BrakeConfig:
    """Validated BrakeConfig from a mapping (a TOML table), an instance, or None (defaults)."""
    return part_config(BrakeConfig, data, where)


def rear_pressure(cfg: BrakeConfig, p_line: float) -> float:
    """Proportioning valve, kPa -> kPa (Python mirror of the kernel)."""
    if p_line <= cfg.proportioning_knee:
        return p_line
    return cfg.proportioning_knee + cfg.proportioning_ratio * (p_line - cfg.proportioning_knee)


def brake_gains(cfg: BrakeConfig | None = None) -> dict:
    """Per-wheel brake gains for `describe`: brake torque per kPa, front and rear (per kPa of rear
    wheel-cylinder pressure, which equals line pressure below the knee), and the rear gain per kPa of
    line pressure above the knee."""
    cfg = brake_config(cfg)
    return {
        "front_Nm_per_kPa": cfg.front.gain(),
        "rear_Nm_per_kPa": cfg.rear.gain(),
        "rear_above_knee_Nm_per_kPa_line": cfg.rear.gain() * cfg.proportioning_ratio,
        "proportioning_knee_kPa": cfg.proportioning_knee,
        "breakaway_over_sliding_front": cfg.front.mu_static / cfg.front.mu,
        "breakaway_over_sliding_rear": cfg.rear.mu_static / cfg.rear.mu,
    }


def describe(cfg: BrakeConfig | None = None) -> dict:
    """Key figures for `rtsim describe` (the brake gains)."""
    return brake_gains(cfg)


def brake_params(cfg: BrakeConfig | None = None) -> np.ndarray:
    cfg = brake_config(cfg)
    p = np.zeros(BP_SIZE)
    for i in range(NWHEEL):
        axle = cfg.front if i in FRONT else cfg.rear
        p[BP_GAIN + i] = axle.gain()
        p[BP_BREAK_RATIO + i] = axle.mu_static / axle.mu
    p[BP_KNEE] = cfg.proportioning_knee
    p[BP_RATIO] = cfg.proportioning_ratio
    p[BP_K] = cfg.anchor_stiffness
    p[BP_C] = cfg.anchor_damping
    p[BP_EPS] = cfg.omega_eps
    p[BP_STICK] = cfg.omega_stick
    p[BP_ACT:BP_ACT + LAG_NPAR] = cfg.actuator.params()
    return p


def brake_state(params: np.ndarray, dt: float, pressure: float = 0.0, wheel_angles=(0.0,) * 4,
                stuck: bool = False) -> np.ndarray:
    """Initial state: line pressure settled at `pressure` kPa (and a pressure command equal to it in the
    delay buffer); wheels stuck at `wheel_angles` (anchors unloaded) if `stuck`, else sliding."""
    s = np.zeros(BS_ACT + lag_state_size(params, BP_ACT, dt))
    lag_init(params, BP_ACT, s, BS_ACT, dt, pressure)
    for i in range(NWHEEL):
        s[BS_MODE + i] = STICK if stuck else SLIDE
        s[BS_ANCHOR + i] = wheel_angles[i]
    _update_limits(params, s, s[BS_ACT + LAG_Y])
    return s


# ----------------------------------------------------------------------------------------- kernels
@kernel
def _update_limits(p, s, p_line):
    knee = p[BP_KNEE]
    p_rear = p_line if p_line <= knee else knee + p[BP_RATIO] * (p_line - knee)
    s[BS_P_FRONT] = p_line
    s[BS_P_REAR] = p_rear
    for i in range(NWHEEL):
        if p[BP_STUCK + i] > 0.5:           # a stuck caliper: its torques do not follow the pressure
            continue
        pw = p_line if i < 2 else p_rear
        ts = p[BP_GAIN + i] * pw
        s[BS_TAU_SLIDE + i] = ts
        s[BS_TAU_BREAK + i] = ts * p[BP_BREAK_RATIO + i]


@kernel
def brake_step(p, s, inp, dt, out):
    """Advance the pressure actuator to the end of the step and set each wheel's sliding and breakaway
    torques. Writes out[BO_LINE..BO_TAU_BREAK+3]; returns the line pressure (kPa)."""
    p_line = lag_step(p, BP_ACT, s, BS_ACT, inp[BI_PRESSURE_CMD], dt)
    _update_limits(p, s, p_line)
    out[BO_LINE] = p_line
    out[BO_FRONT] = s[BS_P_FRONT]
    out[BO_REAR] = s[BS_P_REAR]
    for i in range(NWHEEL):
        out[BO_TAU_SLIDE + i] = s[BS_TAU_SLIDE + i]
        out[BO_TAU_BREAK + i] = s[BS_TAU_BREAK + i]
    return p_line


@kernel
def brake_wheel_torque(p, s, i, theta, omega):
    """Brake torque on wheel i at angle theta (rad) and speed omega (rad/s), for the current mode and
    limits; pure (the state is not changed). Returns (tau, d tau/d omega, d tau/d theta)."""
    if s[BS_MODE + i] > 0.5:
        tb = s[BS_TAU_BREAK + i]
        k = p[BP_K]
        c = p[BP_C]
        t = -k * (theta - s[BS_ANCHOR + i]) - c * omega
        if t > tb:
            return tb, 0.0, 0.0
        if t < -tb:
            return -tb, 0.0, 0.0
        return t, -c, -k
    ts = s[BS_TAU_SLIDE + i]
    eps = p[BP_EPS]
    x = omega / eps
    if x >= 1.0:
        return -ts, 0.0, 0.0
    if x <= -1.0:
        return ts, 0.0, 0.0
    return -ts * x, -ts / eps, 0.0


@kernel
def brake_commit_wheel(p, s, i, theta, omega):
    """Mode transitions of wheel i after a converged step ending at (theta, omega). Returns the new
    mode (1.0 stick, 0.0 slide)."""
    k = p[BP_K]
    c = p[BP_C]
    tb = s[BS_TAU_BREAK + i]
    w_prev = s[BS_OMEGA_PREV + i]
    if s[BS_MODE + i] > 0.5:
        t = -k * (theta - s[BS_ANCHOR + i]) - c * omega
        if t > tb or t < -tb or tb <= 0.0:
            sgn = 1.0 if t >= 0.0 else -1.0
            s[BS_ANCHOR + i] = theta + sgn * tb / k     # spring carries exactly tau_b
            s[BS_MODE + i] = SLIDE
    else:
        slowing = abs(omega) <= abs(w_prev) or omega * w_prev < 0.0
        if tb > 0.0 and abs(omega) <= p[BP_STICK] and slowing:
            ts = s[BS_TAU_SLIDE + i]
            x = omega / p[BP_EPS]
            if x > 1.0:
                x = 1.0
            elif x < -1.0:
                x = -1.0
            t_now = -ts * x
            s[BS_ANCHOR + i] = theta + (t_now + c * omega) / k
            s[BS_MODE + i] = STICK
    s[BS_OMEGA_PREV + i] = omega
    return s[BS_MODE + i]


@kernel
def brake_commit(p, s, theta, omega):
    """brake_commit_wheel for the four wheels; theta, omega are arrays of 4 (fl, fr, rl, rr)."""
    for i in range(NWHEEL):
        brake_commit_wheel(p, s, i, theta[i], omega[i])


@kernel
def brake_torques(p, s, theta, omega, out):
    """brake_wheel_torque for the four wheels into out[BO_TORQUE+i], out[BO_DTDW+i], out[BO_DTDTH+i]."""
    for i in range(NWHEEL):
        t, dw, dth = brake_wheel_torque(p, s, i, theta[i], omega[i])
        out[BO_TORQUE + i] = t
        out[BO_DTDW + i] = dw
        out[BO_DTDTH + i] = dth
