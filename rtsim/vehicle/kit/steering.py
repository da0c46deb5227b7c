"""Steer-by-wire: a position-controlled motor turning the steering column, a torsion bar with the
inline torque sensor, pinion and rack. The rack's motion is what the multibody model imposes on the
steering linkage as a rheonomic constraint (an external driver: position, velocity, acceleration per
step); the force the rack needs to move the linkage comes back as an input and loads the pinion, so the
torque sensor sees the tyres' aligning moments.

Chain (after the seed on electric power steering, section 3.4, with the driver's hands replaced by the
motor): ``steering_wheel_angle_cmd`` -> optional command lag block (transport delay, lag, lock-to-lock
bounds) -> PID on the column angle (derivative on the measured column speed, integral clamped and
frozen while the motor saturates), output as a column torque -> motor torque demand through the
reduction (ratio N, efficiency eta) -> motor torque lag block (current-loop time constant, slew rate,
+-torque limit) -> column.

Mechanics, two rotational degrees of freedom (column angle theta_c, pinion angle theta_p):

    J_c theta_c'' = N eta T_m - T_tb - c_c theta_c'
    J_p theta_p'' = T_tb - r_p (F_rack - m_l a_prev)
    T_tb = k_tb (theta_c - theta_p) + c_tb (theta_c' - theta_p')

J_c = steering wheel + column + motor inertia N^2 J_m; J_p = pinion + (rack mass + m_l) r_p^2 with r_p
the rack travel per pinion radian (m/rad); c_p adds the rack's viscous friction r_p^2 c_rack. The
steering torque sensor reads the torsion bar's elastic torque k_tb (theta_c - theta_p); in static
equilibrium it equals r_p F_rack.

``F_rack`` (N) is the force the rack exerts on the linkage along +x (rack travel positive = steering
left), i.e. the driving force of the multibody rack constraint; the linkage pushes back with -F_rack.
Self-aligning moments while steering left make F_rack > 0 and the steering torque positive.

Co-simulation stability: F_rack arrives one step late and contains the linkage's inertia (steered
wheels about their kingpins, seen at the rack: about 100 kg), which is far heavier than the rack. Fed
back explicitly that is the classic added-mass instability. The kernel therefore carries an estimate m_l
(``linkage_mass``) of that inertia inside J_p and removes m_l a_prev (the rack acceleration it imposed
the step before) from the incoming force. The estimate must be near the truth: with the default gains
and m_l = 100 kg, a linkage of 50 to 200 kg coupled stably and 0, 10 or 300 kg diverged (measured with
a mass-spring linkage fed back one step late); with m_l = 0 any linkage heavier than a few kg diverges.
Set m_l = 0 exactly when F_rack carries no inertial part (a prescribed or quasi-static force).

Integration: backward Euler on the 2-DOF linear mechanics (a 2x2 solve per step), A-stable for the stiff
torsion-bar mode, exact static equilibria; the controller and the motor lag are discrete at the step.
Rack outputs are consistent with it: x_n+1 = x_n + dt v_n+1, a_n+1 = (v_n+1 - v_n) / dt.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rtsim.jit import kernel

from .actuators import LAG_NPAR, LagConfig, check, from_mapping, lag_init, lag_state_size, lag_step

# Parameter layout.
SP_J_COL = 0         # kg m^2, column side: steering wheel + column + N^2 J_motor
SP_C_COL = 1         # N m s/rad, column viscous friction
SP_K_TB = 2          # N m/rad, torsion bar
SP_C_TB = 3          # N m s/rad, torsion bar damping
SP_J_PIN = 4         # kg m^2, pinion side: pinion + (rack + linkage estimate) r_p^2
SP_C_PIN = 5         # N m s/rad, pinion side: rack viscous friction r_p^2
SP_RP = 6            # m/rad, rack travel per pinion radian
SP_N = 7             # motor-to-column reduction ratio
SP_ETA = 8           # reduction efficiency
SP_KP = 9            # N m/rad (column torque per rad of angle error)
SP_KI = 10           # N m/(rad s)
SP_KD = 11           # N m s/rad
SP_I_MAX = 12        # N m, integral clamp
SP_TM_MAX = 13       # N m, motor torque limit
SP_LINK_M = 14       # kg, linkage inertia estimate at the rack
SP_MOTOR = 15        # lag block: motor torque (N m at the motor)
SP_CMD = SP_MOTOR + LAG_NPAR   # lag block: steering-wheel angle command (rad)
SP_SIZE = SP_CMD + LAG_NPAR

# State layout.
SS_TH_C = 0          # rad, column (steering-wheel) angle
SS_W_C = 1           # rad/s
SS_TH_P = 2          # rad, pinion angle
SS_W_P = 3           # rad/s
SS_I = 4             # N m, controller integral
SS_A_RACK = 5        # m/s^2, rack acceleration imposed at the last step
SS_MOTOR = 6         # motor lag block (no delay: 3 floats); LAG_Y is the motor torque
SS_CMD = 9           # command lag block (3 + delay steps)

# Inputs.
SI_CMD = 0           # rad, steering_wheel_angle_cmd
SI_RACK_FORCE = 1    # N, force of the rack on the linkage along +x
SI_SIZE = 2

# Outputs.
SO_SW_ANGLE = 0      # rad, steering_wheel_angle
SO_RACK_POS = 1      # m
SO_RACK_VEL = 2      # m/s
SO_RACK_ACC = 3      # m/s^2
SO_TORQUE = 4        # N m, steering_torque (torsion bar)
SO_MOTOR_TORQUE = 5  # N m, at the motor shaft
SO_PINION_ANGLE = 6  # rad
SO_CMD = 7           # rad, command after the command lag block
SO_SIZE = 8


# ------------------------------------------------------------------------------------------ config
def _default_command() -> LagConfig:
    return LagConfig(time_constant=0.0, rate_limit=math.inf, delay=0.0, min=-11.0, max=11.0)


@dataclass(frozen=True)
class SteeringConfig:
    steering_wheel_inertia: float = 0.03       # kg m^2
    column_inertia: float = 0.005              # kg m^2
    column_damping: float = 0.05               # N m s/rad
    torsion_bar_stiffness: float = 1.5 * 180.0 / math.pi   # N m/rad (1.5 N m/deg)
    torsion_bar_damping: float = 0.02          # N m s/rad
    pinion_inertia: float = 1.0e-4             # kg m^2
    rack_mass: float = 2.5                     # kg
    rack_damping: float = 200.0                # N s/m
    rack_travel_per_rad: float = 6.4e-3        # m/rad (40 mm of rack per pinion turn)
    linkage_mass: float = 100.0                # kg, estimate of the linkage inertia seen at the rack
    motor_inertia: float = 4.0e-5              # kg m^2
    reduction_ratio: float = 16.0              # motor turns per column turn
    reduction_efficiency: float = 0.9
    motor_torque_limit: float = 3.0            # N m at the motor shaft
    motor_time_constant: float = 0.002         # s, torque (current) loop
    motor_torque_rate: float = math.inf        # N m/s at the motor shaft
    kp: float = 180.0                          # N m/rad
    ki: float = 600.0                          # N m/(rad s)
    kd: float = 5.0                            # N m s/rad
    integral_limit: float = 40.0               # N m
    command: LagConfig = field(default_factory=_default_command)   # rad, rad/s

    def validate(self, where: str) -> None:
        for key in ("steering_wheel_inertia", "column_inertia", "pinion_inertia", "rack_mass",
                    "torsion_bar_stiffness", "rack_travel_per_rad", "reduction_ratio",
                    "motor_torque_limit", "motor_torque_rate"):
            v = getattr(self, key)
            check(v > 0.0, where, key, v, "expected a value > 0")
        for key in ("column_damping", "torsion_bar_damping", "rack_damping", "linkage_mass",
                    "motor_inertia", "motor_time_constant", "kp", "ki", "kd", "integral_limit"):
            v = getattr(self, key)
            check(v >= 0.0 and math.isfinite(v), where, key, v, "expected a finite value >= 0")
        check(0.0 < self.reduction_efficiency <= 1.0, where, "reduction_efficiency",
              self.reduction_efficiency, "expected 0 < eta <= 1")
        check(self.rack_travel_per_rad < 0.1, where, "rack_travel_per_rad", self.rack_travel_per_rad,
              "expected metres of rack per pinion radian (< 0.1)")
        from_mapping(LagConfig, self.command, f"{where}.command")


def steering_config(data=None, where: str = "steering") -> SteeringConfig:
    """Validated SteeringConfig from a mapping (a TOML table), an instance, or None (defaults)."""
    return from_mapping(SteeringConfig, data, where)


def steering_params(cfg: SteeringConfig | None = None) -> np.ndarray:
    c = steering_config(cfg)
    p = np.zeros(SP_SIZE)
    rp = c.rack_travel_per_rad
    p[SP_J_COL] = c.steering_wheel_inertia + c.column_inertia + c.reduction_ratio ** 2 * c.motor_inertia
    p[SP_C_COL] = c.column_damping
    p[SP_K_TB] = c.torsion_bar_stiffness
    p[SP_C_TB] = c.torsion_bar_damping
    p[SP_J_PIN] = c.pinion_inertia + (c.rack_mass + c.linkage_mass) * rp * rp
    p[SP_C_PIN] = c.rack_damping * rp * rp
    p[SP_RP] = rp
    p[SP_N] = c.reduction_ratio
    p[SP_ETA] = c.reduction_efficiency
    p[SP_KP] = c.kp
    p[SP_KI] = c.ki
    p[SP_KD] = c.kd
    p[SP_I_MAX] = c.integral_limit
    p[SP_TM_MAX] = c.motor_torque_limit
    p[SP_LINK_M] = c.linkage_mass
    p[SP_MOTOR:SP_MOTOR + LAG_NPAR] = LagConfig(
        time_constant=c.motor_time_constant, rate_limit=c.motor_torque_rate,
        min=-c.motor_torque_limit, max=c.motor_torque_limit).params()
    p[SP_CMD:SP_CMD + LAG_NPAR] = c.command.params()
    return p


def steering_state(params: np.ndarray, dt: float, angle: float = 0.0) -> np.ndarray:
    """At rest, unloaded, steering wheel at `angle` rad (and commanded there)."""
    s = np.zeros(SS_CMD + lag_state_size(params, SP_CMD, dt))
    s[SS_TH_C] = angle
    s[SS_TH_P] = angle
    lag_init(params, SP_MOTOR, s, SS_MOTOR, dt, 0.0)
    lag_init(params, SP_CMD, s, SS_CMD, dt, angle)
    return s


def describe(cfg: SteeringConfig | None = None) -> dict:
    c = steering_config(cfg)
    return {
        "rack_travel_per_steering_wheel_turn_m": 2.0 * math.pi * c.rack_travel_per_rad,
        "column_torque_capacity_Nm": c.motor_torque_limit * c.reduction_ratio * c.reduction_efficiency,
        "rack_force_capacity_N": c.motor_torque_limit * c.reduction_ratio * c.reduction_efficiency
        / c.rack_travel_per_rad,
        "torsion_bar_Nm_per_deg": c.torsion_bar_stiffness * math.pi / 180.0,
    }


# ----------------------------------------------------------------------------------------- kernel
@kernel
def steering_step(p, s, inp, dt, out):
    """Advance the steer-by-wire sub-model by one step; write the outputs (SO_*). Returns the rack
    position (m)."""
    cmd = lag_step(p, SP_CMD, s, SS_CMD, inp[SI_CMD], dt)
    th_c = s[SS_TH_C]
    w_c = s[SS_W_C]
    th_p = s[SS_TH_P]
    w_p = s[SS_W_P]
    # position controller (column torque), motor demand through the reduction
    n_eta = p[SP_N] * p[SP_ETA]
    err = cmd - th_c
    t_col = p[SP_KP] * err + s[SS_I] - p[SP_KD] * w_c
    tm_dem = t_col / n_eta
    tmax = p[SP_TM_MAX]
    saturated = (tm_dem > tmax and err > 0.0) or (tm_dem < -tmax and err < 0.0)
    if not saturated:
        i_new = s[SS_I] + p[SP_KI] * err * dt
        imax = p[SP_I_MAX]
        if i_new > imax:
            i_new = imax
        elif i_new < -imax:
            i_new = -imax
        s[SS_I] = i_new
    tm = lag_step(p, SP_MOTOR, s, SS_MOTOR, tm_dem, dt)
    # backward Euler on the column/pinion mechanics
    rp = p[SP_RP]
    jc = p[SP_J_COL]
    jp = p[SP_J_PIN]
    k = p[SP_K_TB]
    ctb = p[SP_C_TB]
    f_c = n_eta * tm
    f_p = -rp * (inp[SI_RACK_FORCE] - p[SP_LINK_M] * s[SS_A_RACK])
    tw = k * (th_c - th_p)
    dt2k = dt * dt * k
    a11 = jc + dt * (p[SP_C_COL] + ctb) + dt2k
    a12 = -dt * ctb - dt2k
    a22 = jp + dt * (ctb + p[SP_C_PIN]) + dt2k
    r1 = jc * w_c + dt * (f_c - tw)
    r2 = jp * w_p + dt * (f_p + tw)
    det = a11 * a22 - a12 * a12
    w_c1 = (r1 * a22 - a12 * r2) / det
    w_p1 = (a11 * r2 - a12 * r1) / det
    th_c1 = th_c + dt * w_c1
    th_p1 = th_p + dt * w_p1
    s[SS_TH_C] = th_c1
    s[SS_W_C] = w_c1
    s[SS_TH_P] = th_p1
    s[SS_W_P] = w_p1
    acc = rp * (w_p1 - w_p) / dt
    s[SS_A_RACK] = acc
    out[SO_SW_ANGLE] = th_c1
    out[SO_RACK_POS] = rp * th_p1
    out[SO_RACK_VEL] = rp * w_p1
    out[SO_RACK_ACC] = acc
    out[SO_TORQUE] = k * (th_c1 - th_p1)
    out[SO_MOTOR_TORQUE] = tm
    out[SO_PINION_ANGLE] = th_p1
    out[SO_CMD] = cmd
    return rp * th_p1
