"""Steering system with a steer-by-wire actuator, as part of the multibody model: the column and the rack
are coordinates of the implicit step, so the linkage, the tyres and the steering are solved together.

Chain (after the seed on electric power steering, section 3.4, with the driver's hands replaced by the
motor): ``steering_wheel_angle_cmd`` -> optional command lag block (transport delay, lag, lock-to-lock
bounds) -> PID on the column angle (derivative on the measured column speed, integral clamped and
frozen while the motor saturates), output as a column torque -> motor torque demand through the
reduction (ratio N, efficiency eta) -> motor torque lag block (current-loop time constant, slew rate,
+-torque limit) -> column. The controller and the motor are discrete at the step (the motor torque is
held over it, as a digital drive does); the mechanics are inside the multibody step.

End stops: the rack's travel ends at two stops (rtsim.vehicle.kit.end_stop: contact stiffness and
damping, the config's rack_travel, rack_stop_stiffness, rack_stop_damping); a command past the lock
(the DBC allows +-11 rad at the steering wheel) leaves the motor holding the rack on its stop.

Mechanics: two coordinates of the multibody model, the column angle theta_c (rad, the steering-wheel
angle) and the rack travel x (m, positive steering left). The pinion is geared rigidly to the rack,
theta_p = x / r_p (r_p: rack travel per pinion radian, m/rad), so its inertia sits on the rack:

    J_c theta_c'' = N eta T_m - T_tb - c_c theta_c'
    m_r x''       = T_tb / r_p - c_r x' - (the linkage's reaction, through the multibody constraints)
    T_tb = k_tb (theta_c - x / r_p) + c_tb (theta_c' - x' / r_p)

J_c = steering wheel + column + N^2 J_motor; m_r = rack + J_pinion / r_p^2. The linkage (tie rods,
knuckles, wheels) is the vehicle's: the rack coordinate enters its wheels' kinematic paths, so the
aligning moments of the tyres and the steered masses load the rack exactly, in the same Newton
iteration. The steering torque sensor reads the torsion bar's elastic torque k_tb (theta_c - x / r_p).

An assembly fits the part with ``add_steering`` (coordinates, inertias, tangent pattern), calls
``steering_control`` once per step before the multibody step, ``steering_forces`` (and with a tangent
``steering_tangent``) in its force evaluation, and ``steering_outputs`` after the step.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from rtsim.configfile import NonNegative, Positive, Range, check_declared_ranges
from rtsim.jit import inline_kernel, kernel
from rtsim.mbs.envelope import add_entry

from .actuators import LAG_NPAR, LagConfig, part_config, pydantic_config, lag_init, lag_state_size, lag_step
from .layout import offsets
from .rack import (RK_DAMPING, RK_MASS, RK_RP, RK_SIZE, RK_STOP_C, RK_STOP_K, RK_TRAVEL, rack_and_pinion, rack_force,
                   rack_stops)



class SbwPar(IntEnum):
    """The steer-by-wire system's parameter array (steering_params): offsets of its blocks, then SIZE."""
    (J_COL,           # kg m^2, column side: steering wheel + column + N^2 J_motor
     C_COL,           # N m s/rad, column viscous friction
     K_TB,            # N m/rad, torsion bar
     C_TB,            # N m s/rad, torsion bar damping
     RACK,            # the rack and pinion (rtsim.vehicle.kit.rack, RK_SIZE floats: no geared inertia here)
     N,               # motor-to-column reduction ratio
     ETA,             # reduction efficiency
     KP,              # N m/rad (column torque per rad of angle error)
     KI,              # N m/(rad s)
     KD,              # N m s/rad
     I_MAX,           # N m, integral clamp
     TM_MAX,          # N m, motor torque limit
     MOTOR,           # lag block: motor torque (N m at the motor)
     CMD,             # lag block: steering-wheel angle command (rad)
     SIZE) = offsets(1, 1, 1, 1, RK_SIZE, *(1,) * 7, LAG_NPAR, LAG_NPAR)
    # inside the rack and pinion block:
    RP = RACK + RK_RP                  # m/rad, rack travel per pinion radian
    M_RACK = RACK + RK_MASS            # kg, rack side: rack + J_pinion / r_p^2
    C_RACK = RACK + RK_DAMPING         # N s/m, rack viscous friction
    RACK_TRAVEL = RACK + RK_TRAVEL     # m, rack travel from centre to either end stop
    STOP_K = RACK + RK_STOP_K          # N/m, end-stop stiffness
    STOP_C = RACK + RK_STOP_C          # N s/m, end-stop damping


# State layout (the command lag block last: its delay buffer has a variable length).
(SS_I,               # N m, controller integral
 SS_T_COL,           # N m, column torque of the motor held over the step (N eta T_m)
 SS_CMD_OUT,         # rad, command after the command lag block
 SS_MOTOR,           # motor lag block (no delay: 3 floats); LAG_Y is the motor torque
 SS_CMD,             # command lag block (3 + delay steps)
 _) = offsets(1, 1, 1, 3, 3)

# Outputs (steering_outputs).
(SO_SW_ANGLE,        # rad, steering_wheel_angle
 SO_RACK_POS,        # m
 SO_TORQUE,          # N m, steering_torque (torsion bar)
 SO_MOTOR_TORQUE,    # N m, at the motor shaft
 SO_PINION_ANGLE,    # rad
 SO_CMD,             # rad, command after the command lag block
 SO_SIZE) = offsets(*(1,) * 6)


# ------------------------------------------------------------------------------------------ config
def _default_command() -> LagConfig:
    return LagConfig(time_constant=0.0, rate_limit=math.inf, delay=0.0, min=-11.0, max=11.0)


@pydantic_config
@dataclass(frozen=True)
class SteeringConfig:
    """The steer-by-wire system's section; each number's range declared on its field (rtsim.configfile
    Range: a file's value and one built in code get the same check)."""
    steering_wheel_inertia: Positive("kg m^2") = 0.03
    column_inertia: Positive("kg m^2") = 0.005
    column_damping: NonNegative("N m s/rad") = 0.05
    torsion_bar_stiffness: Positive("N m/rad") = 1.5 * 180.0 / math.pi   # 1.5 N m/deg
    torsion_bar_damping: NonNegative("N m s/rad") = 0.02
    pinion_inertia: Positive("kg m^2") = 1.0e-4
    rack_mass: Positive("kg") = 2.5
    rack_damping: NonNegative("N s/m") = 200.0
    rack_travel_per_rad: Range(0.0, 0.1, "m/rad", lo_open=True, hi_open=True) = 6.4e-3   # 40 mm per pinion turn
    motor_inertia: NonNegative("kg m^2") = 4.0e-5
    reduction_ratio: Positive("motor turns per column turn") = 16.0
    reduction_efficiency: Range(0.0, 1.0, lo_open=True) = 0.9
    motor_torque_limit: Positive("N m at the motor shaft") = 3.0
    motor_time_constant: NonNegative("s") = 0.002               # torque (current) loop
    motor_torque_rate: Range(0.0, math.inf, "N m/s at the motor shaft (inf: none)", lo_open=True) = math.inf
    kp: NonNegative("N m/rad") = 180.0
    ki: NonNegative("N m/(rad s)") = 600.0
    kd: NonNegative("N m s/rad") = 5.0
    integral_limit: NonNegative("N m") = 40.0
    command: LagConfig = field(default_factory=_default_command)   # rad, rad/s
    # Rack end stops (rtsim.vehicle.kit.end_stop): the rack's travel either side of centre and the
    # stops' contact stiffness and damping (steel stop with a polyurethane ring). At the motor's full
    # column torque the rack force is ~6.8 kN: 1.4 mm of static deflection at 5 MN/m. The travel lies
    # inside the linkage fit's rack range.
    rack_travel: Range(0.005, 0.2, "m") = 0.062
    rack_stop_stiffness: Range(1e5, 1e8, "N/m") = 5.0e6
    rack_stop_damping: Range(0.0, 1e6, "N s/m") = 2.0e4

    def __post_init__(self) -> None:
        check_declared_ranges(self)


def steering_config(data=None, where: str = "steering") -> SteeringConfig:
    """Validated SteeringConfig from a mapping (a TOML table), an instance, or None (defaults)."""
    return part_config(SteeringConfig, data, where)


def steering_params(cfg: SteeringConfig | None = None) -> np.ndarray:
    c = steering_config(cfg)
    p = np.zeros(SbwPar.SIZE)
    p[SbwPar.J_COL] = c.steering_wheel_inertia + c.column_inertia + c.reduction_ratio ** 2 * c.motor_inertia
    p[SbwPar.C_COL] = c.column_damping
    p[SbwPar.K_TB] = c.torsion_bar_stiffness
    p[SbwPar.C_TB] = c.torsion_bar_damping
    rack_and_pinion(p, SbwPar.RACK, travel_per_rad=c.rack_travel_per_rad, rack_mass=c.rack_mass,
                    pinion_inertia=c.pinion_inertia, damping=c.rack_damping, travel=c.rack_travel,
                    stop_stiffness=c.rack_stop_stiffness, stop_damping=c.rack_stop_damping)
    p[SbwPar.N] = c.reduction_ratio
    p[SbwPar.ETA] = c.reduction_efficiency
    p[SbwPar.KP] = c.kp
    p[SbwPar.KI] = c.ki
    p[SbwPar.KD] = c.kd
    p[SbwPar.I_MAX] = c.integral_limit
    p[SbwPar.TM_MAX] = c.motor_torque_limit
    p[SbwPar.MOTOR:SbwPar.MOTOR + LAG_NPAR] = LagConfig(
        time_constant=c.motor_time_constant, rate_limit=c.motor_torque_rate,
        min=-c.motor_torque_limit, max=c.motor_torque_limit).params()
    p[SbwPar.CMD:SbwPar.CMD + LAG_NPAR] = c.command.params()
    return p


def steering_state(params: np.ndarray, dt: float, angle: float = 0.0) -> np.ndarray:
    """Controller and actuator state at rest, unloaded, commanded to `angle` rad."""
    s = np.zeros(SS_CMD + lag_state_size(params, SbwPar.CMD, dt))
    s[SS_CMD_OUT] = angle
    lag_init(params, SbwPar.MOTOR, s, SS_MOTOR, dt, 0.0)
    lag_init(params, SbwPar.CMD, s, SS_CMD, dt, angle)
    return s


def add_steering(b, params: np.ndarray, rack, angle: float = 0.0):
    """Fit the steering to a multibody builder whose linkage hangs on the rack coordinate `rack` (a
    length, m): adds the column angle coordinate (rad, at `angle`), the column and rack inertias and the
    tangent pattern of the torsion bar. Returns the column coordinate."""
    col = b.angle("steering_column", angle, velocity=0.0)
    b.scalar_inertia(col, float(params[SbwPar.J_COL]))
    b.scalar_inertia(rack, float(params[SbwPar.M_RACK]))
    b.couple(col, rack)
    return col


def describe(cfg: SteeringConfig | None = None) -> dict:
    c = steering_config(cfg)
    return {
        "rack_travel_per_steering_wheel_turn_m": 2.0 * math.pi * c.rack_travel_per_rad,
        "column_torque_capacity_Nm": c.motor_torque_limit * c.reduction_ratio * c.reduction_efficiency,
        "rack_force_capacity_N": c.motor_torque_limit * c.reduction_ratio * c.reduction_efficiency
        / c.rack_travel_per_rad,
        "torsion_bar_Nm_per_deg": c.torsion_bar_stiffness * math.pi / 180.0,
    }


# ----------------------------------------------------------------------------------------- kernels
@kernel
def steering_control(p, s, cmd_in, th_c, w_c, dt):
    """Controller and motor over the coming step from the command (rad) and the column angle (rad) and
    rate (rad/s) at its start: stores the column torque the motor holds over the step (SS_T_COL)."""
    cmd = lag_step(p, SbwPar.CMD, s, SS_CMD, cmd_in, dt)
    s[SS_CMD_OUT] = cmd
    n_eta = p[SbwPar.N] * p[SbwPar.ETA]
    err = cmd - th_c
    t_col = p[SbwPar.KP] * err + s[SS_I] - p[SbwPar.KD] * w_c
    tm_dem = t_col / n_eta
    tmax = p[SbwPar.TM_MAX]
    saturated = (tm_dem > tmax and err > 0.0) or (tm_dem < -tmax and err < 0.0)
    if not saturated:
        i_new = s[SS_I] + p[SbwPar.KI] * err * dt
        imax = p[SbwPar.I_MAX]
        if i_new > imax:
            i_new = imax
        elif i_new < -imax:
            i_new = -imax
        s[SS_I] = i_new
    tm = lag_step(p, SbwPar.MOTOR, s, SS_MOTOR, tm_dem, dt)
    s[SS_T_COL] = n_eta * tm


@inline_kernel
def steering_forces(p, s, q, qd, f, ic, ir):
    """Add the motor torque, the torsion bar and the viscous frictions to the generalized forces of the
    column (index ic, N m) and the rack (index ir, N)."""
    rp = p[SbwPar.RP]
    t_tb = p[SbwPar.K_TB] * (q[ic] - q[ir] / rp) + p[SbwPar.C_TB] * (qd[ic] - qd[ir] / rp)
    f[ic] += s[SS_T_COL] - t_tb - p[SbwPar.C_COL] * qd[ic]
    f[ir] += rack_force(p, SbwPar.RACK, q[ir], qd[ir], t_tb / rp, 0.0)[0]


@inline_kernel
def steering_tangent(m, w_env, p, ic, ir, bq, hc):
    """Stiffness (scaled by bq) and damping (by hc) of steering_forces into the tangent W (the end
    stops' in rack_stop_tangent, which needs the state)."""
    rp = p[SbwPar.RP]
    kc = bq * p[SbwPar.K_TB] + hc * p[SbwPar.C_TB]
    add_entry(w_env, m.first, m.ptr, m.pinv, ic, ic, kc + hc * p[SbwPar.C_COL])
    add_entry(w_env, m.first, m.ptr, m.pinv, ir, ir, kc / (rp * rp) + hc * p[SbwPar.C_RACK])
    add_entry(w_env, m.first, m.ptr, m.pinv, ic, ir, -kc / rp)


@inline_kernel
def rack_stop_tangent(m, w_env, p, q, qd, ir, bq, hc):
    """The rack end stops' stiffness (scaled by bq) and damping (by hc) at (q, qd) into the tangent W."""
    _f, k_stop, c_stop = rack_stops(p, SbwPar.RACK, q[ir], qd[ir])
    if k_stop != 0.0:
        add_entry(w_env, m.first, m.ptr, m.pinv, ir, ir, bq * k_stop + hc * c_stop)


@inline_kernel
def steering_outputs(p, s, q, ic, ir, out):
    """The steering's outputs (SO_*) at the state q."""
    rp = p[SbwPar.RP]
    out[SO_SW_ANGLE] = q[ic]
    out[SO_RACK_POS] = q[ir]
    out[SO_TORQUE] = p[SbwPar.K_TB] * (q[ic] - q[ir] / rp)
    out[SO_MOTOR_TORQUE] = s[SS_T_COL] / (p[SbwPar.N] * p[SbwPar.ETA])
    out[SO_PINION_ANGLE] = q[ir] / rp
    out[SO_CMD] = s[SS_CMD_OUT]
