"""Electric power steering (EPS) with two actuating lines, the driver's and the motor's, after the
bond-graph vehicle study (bondgraph-vehicle-eps, sec. 3.4), as part of the multibody model.

Driver's line: steering wheel and column (one inertia, viscous friction), the torsion bar (stiffness
and damping; the torque sensor reads its elastic torque) to the pinion. The driver imposes the
steering-wheel angle (a rheonomic constraint: the study's modulated flow source) or a torque.
Motor's line: a DC motor, electrically L di/dt = V - R i - Kt w_m, torque Kt i, rotor inertia, viscous
and dry friction, on the pinion through a reduction gear (ratio N) whose efficiency depends on the
direction of the power flow; the supply voltage from a current loop whose command is the assistance
law, a table of motor current against torsion-bar torque and vehicle speed (or an external EPS
controller's command over CAN).
Transmission: pinion (inertia, dry friction) to rack (mass, viscous and dry friction) with a
direction-dependent efficiency; the rack to the front wheels' pivots through tie rods (crank-rod
constraints of the assembly; the pivots' inertias are the assembly's). The rack's travel ends at two
end stops (rtsim.vehicle.kit.end_stop: rack_travel_m, their stiffness and damping); their force is in
the rack-friction port of the audit.

Coordinates (the assembly's multibody model): the column angle theta_c (rad, = steering-wheel angle)
and the rack travel x (m, positive steers left). The pinion is geared rigidly to the rack, theta_p =
x / r_p, the motor to the pinion, w_m = N x' / r_p: their inertias sit on the rack coordinate.
The motor current is not a coordinate: it is integrated by the same trapezoidal rule as the
mechanics, inside the Newton iteration, i1 = (i0 (1 - a) + b (2 V - Kt (w0 + w1))) / (1 + a),
a = h R / 2L, b = h / 2L, so the back-emf is an implicit (symmetric) damping on the rack and the
electrical energy balance closes exactly with the mechanical one.

Dry frictions are saturated-linear within a small velocity band, implicit in the step (their slope
is in the tangent), so they neither chatter at 1 ms nor creep measurably. The gear efficiencies switch
between eta (input driving) and 1/eta_back (output driving) with the sign of the power, smoothly within
the input's friction speed band; the loss (1 - e) P is never negative.

Energy audit: while the audit is on every force is also written to its port's row of the port-force
array (PORT_*, the force records), and the electrical flows are kept in the state (ES_*), for
rtsim.vehicle.car.energy.
"""
from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from rtsim.configfile import Range, Strict
from rtsim.jit import inline_kernel, kernel
from rtsim.mbs.envelope import add_entry

from .layout import offsets
from .rack import RK_DAMPING, RK_MASS, RK_RP, RK_SIZE, RK_STOP_C, RK_STOP_K, RK_TRAVEL, rack_and_pinion, rack_force
from .tables import map_2d, map_eval

# ---------------------------------------------------------------------------------- parameter layout
(EP_J_COL,           # kg m^2, steering wheel + column
 EP_C_COL,           # N m s/rad, column viscous friction
 EP_K_TB,            # N m/rad, torsion bar
 EP_C_TB,            # N m s/rad, torsion bar damping
 EP_RACK,            # the rack and pinion (rtsim.vehicle.kit.rack, RK_SIZE floats; geared inertia N^2 J_motor)
 EP_T_FP,            # N m, pinion dry friction
 EP_W_FP,            # rad/s, its velocity band
 EP_N,               # motor turns per pinion turn
 EP_ETA_G,           # assist gear efficiency, motor driving
 EP_ETA_GB,          # assist gear efficiency, back-driven
 EP_ETA_RP,          # rack and pinion efficiency, pinion driving
 EP_ETA_RPB,         # rack and pinion efficiency, rack driving
 EP_F_FR,            # N, rack dry friction
 EP_V_FR,            # m/s, its velocity band
 EP_R,               # ohm, winding + drive resistance
 EP_L,               # H, winding inductance
 EP_KT,              # N m/A, torque (and back-emf) constant
 EP_C_M,             # N m s/rad, motor viscous friction
 EP_T_FM,            # N m, motor dry friction
 EP_W_FM,            # rad/s, its velocity band
 EP_I_MAX,           # A, current limit of the drive
 EP_V_SUP,           # V, supply voltage (drive output limit)
 EP_KP_I,            # V/A, current loop proportional gain
 EP_K_DAMP,          # A s/rad, assistance damping on the motor speed
 EP_DRIVER,          # 0: the driver imposes the angle, 1: a torque
 EP_J_M,             # kg m^2, rotor inertia (outputs)
 EP_W_HAND,          # rad/s, natural frequency of the driver's hands (imposed angle mode)
 EP_ASSIST,          # the assistance map (rtsim.vehicle.kit.tables.map_2d), EP_ASSIST_SIZE floats
 EP_SIZE) = offsets(1, 1, 1, 1, RK_SIZE, *(1,) * 22, 0)
EP_RP = EP_RACK + RK_RP                # m/rad, rack travel per pinion radian
EP_M_RACK = EP_RACK + RK_MASS          # kg, rack + (J_pinion + N^2 J_motor) / r_p^2
EP_C_RACK = EP_RACK + RK_DAMPING       # N s/m, rack viscous friction
EP_RACK_TRAVEL = EP_RACK + RK_TRAVEL   # m, rack travel from centre to either end stop
EP_STOP_K = EP_RACK + RK_STOP_K        # N/m, end-stop stiffness
EP_STOP_C = EP_RACK + RK_STOP_C        # N s/m, end-stop damping
DRIVER_ANGLE, DRIVER_TORQUE = 0.0, 1.0

# ------------------------------------------------------------------------------------- state layout
(ES_I,               # A, motor current at the start of the step (after it: at its end)
 ES_I1,              # A, current at the step's end, as the last force evaluation found it
 ES_W0,              # rad/s, motor speed at the start of the step
 ES_V,               # V, drive voltage held over the step
 ES_I_CMD,           # A, current command of the step
 ES_STAGE,           # 1: power stage on, 0: off (open winding, the safe state)
 ES_EXT,             # 1: an external controller commands the current (ES_EXT_I)
 ES_EXT_I,           # A, its command
 ES_FAULT,           # 1: the external controller's commands stopped (watchdog)
 ES_T_DRIVER,        # N m, driver torque (torque mode)
 ES_GAIN,            # assistance gain (1 nominal, 0 assist off)
 ES_E_SUPPLY,        # J, cumulative: supply energy into the drive (V i)
 ES_E_WINDING,       # J, cumulative: dissipated in R (and the winding's energy at a switch-off)
 ES_E_EMF,           # J, cumulative: electrical energy converted to mechanical (Kt w i)
 ES_HAND,            # rad, rad/s, rad/s^2: the driver's hands' steering-wheel angle, rate, acceleration
 ES_SIZE) = offsets(*(1,) * 14, 3)

# ---------------------------------------------------------------------------------- audit ports
# Rows of the port-force array the EPS writes to (generalized forces on the assembly's coordinates).
(PORT_DRIVER_TORQUE,  # the driver's torque on the column (torque mode)
 PORT_TORSION_BAR,    # the torsion bar's elastic torque (stored)
 PORT_COLUMN_FRICTION,  # column viscous friction and the torsion bar's damping
 PORT_MOTOR_EM,       # the motor's electromagnetic torque Kt i (converted electrical power)
 PORT_MOTOR_FRICTION,  # motor viscous and dry friction
 PORT_GEAR_LOSS,      # assist gear loss
 PORT_PINION_FRICTION,
 PORT_RACK_LOSS,      # rack and pinion loss
 PORT_RACK_FRICTION,  # rack viscous and dry friction, and the rack's end stops (their work while in contact)
 NPORT_EPS) = range(10)

# ------------------------------------------------------------------------------------------ outputs
(EO_SW_ANGLE,        # rad, steering-wheel angle
 EO_SW_TORQUE,       # N m, the driver's torque on the wheel
 EO_TB_TORQUE,       # N m, torsion-bar torque (the torque sensor)
 EO_RACK,            # m, rack travel
 EO_MOTOR_ANGLE,     # rad
 EO_MOTOR_SPEED,     # rad/s
 EO_CURRENT,         # A
 EO_VOLTAGE,         # V
 EO_POWER,           # W, electrical input power V i
 EO_ASSIST_TORQUE,   # N m, at the pinion (e_g N Kt i)
 EO_SIZE) = offsets(*(1,) * 10)


# ------------------------------------------------------------------------------------------- config
class AssistLaw(Strict):
    """Motor current command (A) against torsion-bar torque (N m, the law is odd in it) and vehicle
    speed (m/s): current_a[i][j] at torque_nm[i], speed_mps[j]."""
    torque_nm: list[Range(0.0, 50.0, "N m")] = Field(min_length=2, max_length=24)
    speed_mps: list[Range(0.0, 100.0, "m/s")] = Field(min_length=1, max_length=12)
    current_a: list[list[Range(-500.0, 500.0, "A")]]     # the drive's limit: current_limit_a <= 500 A

    @model_validator(mode="after")
    def _grid(self):
        if self.torque_nm[0] != 0.0 or any(b <= a for a, b in zip(self.torque_nm, self.torque_nm[1:])):
            raise ValueError("torque_nm must start at 0 and increase")
        if any(b <= a for a, b in zip(self.speed_mps, self.speed_mps[1:])):
            raise ValueError("speed_mps must increase")
        if len(self.current_a) != len(self.torque_nm) or any(len(r) != len(self.speed_mps) for r in self.current_a):
            raise ValueError(f"current_a must be {len(self.torque_nm)} rows (torques) of "
                             f"{len(self.speed_mps)} values (speeds)")
        if any(r[j] != 0.0 for r in self.current_a[:1] for j in range(len(r))):
            raise ValueError("current_a must be 0 at 0 N m")
        return self


def _default_assist() -> AssistLaw:
    # 0 .. 1.5 N m: little assistance on centre at speed (road feel); the boost rises to the drive's
    # limit by 5 N m when parking, more gently the faster the car.
    return AssistLaw(
        torque_nm=[0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 7.0],
        speed_mps=[0.0, 8.0, 16.0, 25.0, 35.0],
        current_a=[[0.0, 0.0, 0.0, 0.0, 0.0],
                   [2.0, 1.0, 0.5, 0.2, 0.0],
                   [8.0, 4.0, 2.0, 0.8, 0.4],
                   [18.0, 9.0, 4.5, 2.0, 1.2],
                   [30.0, 16.0, 8.0, 4.0, 2.5],
                   [50.0, 30.0, 16.0, 8.0, 5.5],
                   [65.0, 45.0, 25.0, 13.0, 9.0],
                   [70.0, 60.0, 35.0, 19.0, 13.0],
                   [70.0, 70.0, 55.0, 32.0, 24.0]])


class EpsConfig(Strict):
    """A column-pinion electric power steering (units in the key names; defaults: a mid-size car's)."""
    driver_input: Literal["angle", "torque"] = Field(
        default="angle", description="the driver imposes the steering-wheel angle or a torque")
    steering_wheel_inertia_kgm2: Range(0, 1, "kg m^2", lo_open=True) = 0.035
    column_inertia_kgm2: Range(0, 1, "kg m^2", lo_open=True) = 0.005
    column_damping_nms_per_rad: Range(0, 10, "N m s/rad") = 0.04
    torsion_bar_nm_per_rad: Range(0, 2000, "N m/rad", lo_open=True) = 2.0 * 180.0 / math.pi
    torsion_bar_damping_nms_per_rad: Range(0, 10, "N m s/rad") = 0.02
    pinion_inertia_kgm2: Range(0, 0.1, "kg m^2", lo_open=True) = 2.0e-4
    pinion_friction_nm: Range(0, 20, "N m") = 0.3
    pinion_friction_band_rad_s: Range(0, 1, "rad/s", lo_open=True) = 0.02
    rack_travel_per_rad_m: Range(1e-3, 0.05, "m/rad", lo_open=True) = Field(
        default=7.5e-3, description="rack travel per pinion radian")
    rack_mass_kg: Range(0, 50, "kg", lo_open=True) = 3.0
    rack_damping_ns_per_m: Range(0, 1e5, "N s/m") = 300.0
    rack_friction_n: Range(0, 5000, "N") = 120.0
    rack_friction_band_m_s: Range(0, 0.1, "m/s", lo_open=True) = 2.0e-4
    rack_efficiency: Range(0.3, 1, lo_open=True) = Field(default=0.92, description="pinion driving the rack")
    rack_efficiency_back: Range(0.3, 1, lo_open=True) = Field(default=0.88, description="rack driving the pinion")
    gear_ratio: Range(1, 100, lo_open=True) = Field(default=17.0, description="motor turns per pinion turn (worm)")
    gear_efficiency: Range(0.3, 1, lo_open=True) = Field(default=0.85, description="motor driving")
    gear_efficiency_back: Range(0.3, 1, lo_open=True) = Field(default=0.75, description="back-driven")
    motor_resistance_ohm: Range(0, 10, "ohm", lo_open=True) = Field(default=0.06, description="winding + drive")
    motor_inductance_h: Range(0, 0.1, "H", lo_open=True) = 1.0e-4
    motor_torque_constant_nm_per_a: Range(0, 5, "N m/A", lo_open=True) = 0.055
    motor_inertia_kgm2: Range(0, 0.01, "kg m^2", lo_open=True) = 5.0e-5
    motor_damping_nms_per_rad: Range(0, 1, "N m s/rad") = 1.0e-4
    motor_friction_nm: Range(0, 2, "N m") = 0.015
    motor_friction_band_rad_s: Range(0, 10, "rad/s", lo_open=True) = 0.3
    current_limit_a: Range(0, 500, "A", lo_open=True) = 70.0
    supply_voltage_v: Range(0, 100, "V", lo_open=True) = 13.5
    current_loop_gain_v_per_a: Range(0, 10, "V/A") = Field(
        default=0.05, description="proportional gain on the current error (with "
        "feed-forward of R i* and the back-emf)")
    assist_damping_a_s_per_rad: Range(0, 10, "A s/rad") = Field(
        default=0.02, description="current against motor speed")
    hands_bandwidth_hz: Range(1, 100, "Hz") = Field(
        default=8.0, description="angle mode: the steering-wheel angle follows the driver's command through the "
        "hands, a "
        "critically damped second-order lag of this natural frequency (no impulsive torques)")
    rack_travel_m: Range(0.005, 0.2, "m") = Field(
        default=0.065, description="rack travel from centre to either end stop (rtsim.vehicle.kit.end_stop)")
    rack_stop_stiffness_n_per_m: Range(1e5, 1e8, "N/m") = Field(
        default=5.0e6, description="the rack end stops' contact stiffness (steel stop with a polyurethane ring)")
    rack_stop_damping_ns_per_m: Range(0, 1e6, "N s/m") = Field(
        default=2.0e4, description="the rack end stops' damping (fades in over the first 0.5 mm of contact)")
    assist: AssistLaw = Field(default_factory=_default_assist)


def eps_params(c: EpsConfig) -> np.ndarray:
    n = c.gear_ratio
    law = c.assist
    assist = map_2d(law.torque_nm, law.speed_mps, law.current_a)
    p = np.zeros(EP_ASSIST + assist.size)
    p[EP_J_COL] = c.steering_wheel_inertia_kgm2 + c.column_inertia_kgm2
    p[EP_C_COL] = c.column_damping_nms_per_rad
    p[EP_K_TB] = c.torsion_bar_nm_per_rad
    p[EP_C_TB] = c.torsion_bar_damping_nms_per_rad
    rack_and_pinion(p, EP_RACK, travel_per_rad=c.rack_travel_per_rad_m, rack_mass=c.rack_mass_kg,
                    pinion_inertia=c.pinion_inertia_kgm2, damping=c.rack_damping_ns_per_m, travel=c.rack_travel_m,
                    stop_stiffness=c.rack_stop_stiffness_n_per_m, stop_damping=c.rack_stop_damping_ns_per_m,
                    geared_inertia=n * n * c.motor_inertia_kgm2)
    p[EP_T_FP] = c.pinion_friction_nm
    p[EP_W_FP] = c.pinion_friction_band_rad_s
    p[EP_N] = n
    p[EP_ETA_G] = c.gear_efficiency
    p[EP_ETA_GB] = c.gear_efficiency_back
    p[EP_ETA_RP] = c.rack_efficiency
    p[EP_ETA_RPB] = c.rack_efficiency_back
    p[EP_F_FR] = c.rack_friction_n
    p[EP_V_FR] = c.rack_friction_band_m_s
    p[EP_R] = c.motor_resistance_ohm
    p[EP_L] = c.motor_inductance_h
    p[EP_KT] = c.motor_torque_constant_nm_per_a
    p[EP_C_M] = c.motor_damping_nms_per_rad
    p[EP_T_FM] = c.motor_friction_nm
    p[EP_W_FM] = c.motor_friction_band_rad_s
    p[EP_I_MAX] = c.current_limit_a
    p[EP_V_SUP] = c.supply_voltage_v
    p[EP_KP_I] = c.current_loop_gain_v_per_a
    p[EP_K_DAMP] = c.assist_damping_a_s_per_rad
    p[EP_DRIVER] = DRIVER_ANGLE if c.driver_input == "angle" else DRIVER_TORQUE
    p[EP_J_M] = c.motor_inertia_kgm2
    p[EP_W_HAND] = 2.0 * math.pi * c.hands_bandwidth_hz
    p[EP_ASSIST:] = assist
    return p


def eps_state() -> np.ndarray:
    s = np.zeros(ES_SIZE)
    s[ES_STAGE] = 1.0
    s[ES_GAIN] = 1.0
    return s


def add_eps(b, p: np.ndarray, rack, angle: float = 0.0):
    """Fit the EPS to a multibody builder whose pivots hang on the rack coordinate `rack` (a length,
    m): the column angle coordinate (rad), the column and rack inertias, the tangent pattern, and in
    angle mode the driver's constraint (an external driver). Returns (column, driver index or -1)."""
    col = b.angle("steering_column", angle, velocity=0.0)
    b.scalar_inertia(col, float(p[EP_J_COL]))
    b.scalar_inertia(rack, float(p[EP_M_RACK]))
    b.couple(col, rack)
    drv = -1
    if p[EP_DRIVER] == DRIVER_ANGLE:
        drv = b.drive(col, external=True, name="driver: steering-wheel angle")
    return col, drv


# ------------------------------------------------------------------------------------------ kernels
@inline_kernel
def _sat(v, band):
    """Saturated-linear sign: v / band within the band, +-1 outside; and the slope the tangent uses:
    the band's within it, the secant across it, 1 / (|v| + band), out to 20 bands (a tangent of 0 just
    outside would let Newton jump across the band and back; the band's own slope there, up to 20 times
    too stiff, made it crawl)."""
    av = abs(v)
    slope = 1.0 / band if av <= band else (1.0 / (av + band) if av < 20.0 * band else 0.0)
    if v > band:
        return 1.0, slope
    if v < -band:
        return -1.0, slope
    return v / band, slope


@inline_kernel
def _efficiency(torque, speed, band, eta, eta_back):
    """Transmission factor e of a gear carrying `torque` at input `speed`: eta when the input drives
    (power flowing forwards), 1 / eta_back when the output drives, switched by the sign of the power,
    sign(torque) tanh(speed / band), within the speed band of the input's dry friction (the force
    e torque stays continuous: the regime changes with the torque only where it is zero). The loss
    P (1 - e) is never negative. Also returns d(e torque)/d(speed) (<= 0: a damping, in the tangent)."""
    th = math.tanh(speed / band)
    sg = th if torque >= 0.0 else -th
    k = (1.0 - eta) if sg >= 0.0 else (1.0 / eta_back - 1.0)
    # the slope for the tangent: the switch's own within the band; outside it (where tanh is flat) the
    # secant to zero speed, k |T| |th| / (|speed| + band): under a large torque at rest (a rack held on
    # its end stop) the switch is a force step of ~(1/eta_back - eta) T over a tiny band, and with a
    # slope of 0 outside it Newton jumped across the band and back for ever
    slope = (1.0 - th * th) / band
    sec = abs(th) / (abs(speed) + band)
    if sec > slope:
        slope = sec
    return 1.0 - k * sg, -k * abs(torque) * slope


@kernel
def eps_control(p, s, t_tb, speed, omega_m, dt):
    """The drive over the coming step (held): current command from the assistance law (or the external
    controller's), limited; voltage from the current loop (feed-forward of R i* and the back-emf,
    proportional feedback), limited to the supply. Stores the motor speed at the step's start."""
    s[ES_W0] = omega_m
    if s[ES_STAGE] < 0.5:
        s[ES_I_CMD] = 0.0
        s[ES_V] = 0.0
        return
    if s[ES_EXT] > 0.5:
        i_cmd = s[ES_EXT_I]
    else:
        mag = map_eval(p[EP_ASSIST:], abs(t_tb), speed)
        i_cmd = s[ES_GAIN] * (math.copysign(mag, t_tb) - p[EP_K_DAMP] * omega_m)
    imax = p[EP_I_MAX]
    if i_cmd > imax:
        i_cmd = imax
    elif i_cmd < -imax:
        i_cmd = -imax
    s[ES_I_CMD] = i_cmd
    v = p[EP_R] * i_cmd + p[EP_KT] * omega_m + p[EP_KP_I] * (i_cmd - s[ES_I])
    vs = p[EP_V_SUP]
    if v > vs:
        v = vs
    elif v < -vs:
        v = -vs
    s[ES_V] = v


@inline_kernel
def hands_step(p, s, cmd, h):
    """The driver's hands over the step: the steering-wheel angle, rate and acceleration at its end,
    a critically damped second-order lag of the command integrated by the trapezoidal rule, so that
    the imposed angle and rate are exactly consistent with the step's (the velocity projection then
    leaves the column's motion, and its energy, as the driver's constraint did it)."""
    wn = p[EP_W_HAND]
    a = 0.5 * h
    th0 = s[ES_HAND]
    w0 = s[ES_HAND + 1]
    al0 = s[ES_HAND + 2]
    w1 = (w0 + a * al0 + a * wn * wn * (cmd - th0 - a * w0)) / (1.0 + a * a * wn * wn + 2.0 * a * wn)
    th1 = th0 + a * (w0 + w1)
    al1 = wn * wn * (cmd - th1) - 2.0 * wn * w1
    s[ES_HAND] = th1
    s[ES_HAND + 1] = w1
    s[ES_HAND + 2] = al1
    return th1, w1, al1


@inline_kernel
def eps_current(p, s, omega1, h):
    """Motor current at the step's end for the motor speed omega1 there (trapezoidal rule) and its
    derivative with respect to omega1. Zero with the power stage off (open winding)."""
    if s[ES_STAGE] < 0.5:
        return 0.0, 0.0
    a = 0.5 * h * p[EP_R] / p[EP_L]
    b = 0.5 * h / p[EP_L]
    kt = p[EP_KT]
    i1 = (s[ES_I] * (1.0 - a) + b * (2.0 * s[ES_V] - kt * (s[ES_W0] + omega1))) / (1.0 + a)
    return i1, -b * kt / (1.0 + a)


@inline_kernel
def eps_forces(m, d, p, s, ic, ir, h, tangent, bq, hc, rec, pf):
    """Add the EPS's generalized forces on the column (ic, N m) and the rack (ir, N) to d.force (with
    `tangent` their stiffness and damping to d.w_env), and with `rec` each element's to its row PORT_* of
    pf (the force records the power audit sums)."""
    q = d.q
    qd = d.qd
    f = d.force
    rp = p[EP_RP]
    n = p[EP_N]
    xd = qd[ir]
    wp = xd / rp                      # pinion speed
    wm = n * wp                       # motor speed
    # torsion bar (elastic + damping) and column friction
    tw = q[ic] - q[ir] / rp
    twd = qd[ic] - wp
    t_el = p[EP_K_TB] * tw
    t_damp = p[EP_C_TB] * twd
    t_col = p[EP_C_COL] * qd[ic]
    t_drv = s[ES_T_DRIVER] if p[EP_DRIVER] == DRIVER_TORQUE else 0.0
    # motor: current at the step's end, shaft torque
    i1, di = eps_current(p, s, wm, h)
    s[ES_I1] = i1
    t_em = p[EP_KT] * i1
    sf_m, dsf_m = _sat(wm, p[EP_W_FM])
    t_mf = -p[EP_C_M] * wm - p[EP_T_FM] * sf_m
    t_m = t_em + t_mf
    e_g, de_g = _efficiency(t_m, wm, p[EP_W_FM], p[EP_ETA_G], p[EP_ETA_GB])
    # pinion: torsion bar + assist gear output + pinion friction, to the rack
    sf_p, dsf_p = _sat(wp, p[EP_W_FP])
    t_pf = -p[EP_T_FP] * sf_p
    t_p = t_el + t_damp + e_g * n * t_m + t_pf
    e_rp, de_rp = _efficiency(t_p, wp, p[EP_W_FP], p[EP_ETA_RP], p[EP_ETA_RPB])
    sf_r, dsf_r = _sat(xd, p[EP_V_FR])
    f_rack, f_rf, f_stop, k_stop, c_stop = rack_force(p, EP_RACK, q[ir], xd, e_rp * t_p / rp, -p[EP_F_FR] * sf_r)
    f[ic] += t_drv - t_el - t_damp - t_col
    f[ir] += f_rack
    if rec:
        pf[PORT_DRIVER_TORQUE, ic] += t_drv
        pf[PORT_TORSION_BAR, ic] -= t_el
        pf[PORT_TORSION_BAR, ir] += t_el / rp
        pf[PORT_COLUMN_FRICTION, ic] -= t_damp + t_col
        pf[PORT_COLUMN_FRICTION, ir] += t_damp / rp
        pf[PORT_MOTOR_EM, ir] += n * t_em / rp
        pf[PORT_MOTOR_FRICTION, ir] += n * t_mf / rp
        pf[PORT_GEAR_LOSS, ir] += (e_g - 1.0) * n * t_m / rp
        pf[PORT_PINION_FRICTION, ir] += t_pf / rp
        pf[PORT_RACK_LOSS, ir] += (e_rp - 1.0) * t_p / rp
        pf[PORT_RACK_FRICTION, ir] += f_rf + f_stop
    if tangent:
        k_tb = bq * p[EP_K_TB] + hc * p[EP_C_TB]
        # rack damping: back-emf (d i1 / d w_m), frictions' bands, viscous terms, through the gears
        c_m = -p[EP_KT] * di + p[EP_C_M] + p[EP_T_FM] * dsf_m
        # the efficiencies' switching with the speed: damping -d(e T)/dw of each transmission
        c_m -= de_g
        c_r = (e_rp * (e_g * n * n * c_m + p[EP_T_FP] * dsf_p) / (rp * rp) + p[EP_C_RACK]
               + p[EP_F_FR] * dsf_r - de_rp / (rp * rp))
        add_entry(d.w_env, m.first, m.ptr, m.pinv, ic, ic, k_tb + hc * p[EP_C_COL])
        add_entry(d.w_env, m.first, m.ptr, m.pinv, ir, ir, k_tb / (rp * rp) + hc * c_r + bq * k_stop + hc * c_stop)
        add_entry(d.w_env, m.first, m.ptr, m.pinv, ic, ir, -k_tb / rp)


@kernel
def eps_commit(p, s, h, omega1):
    """After the step (motor speed omega1 at its end): the current at its end becomes the next step's
    start; the step's electrical energy flows, with the trapezoidal averages the step integrated them
    with, are accumulated: supply V <i> h, winding R <i>^2 h, converted Kt <w_m> <i> h (the mechanical
    side's is the port PORT_MOTOR_EM)."""
    ia = 0.5 * (s[ES_I] + s[ES_I1])
    if s[ES_STAGE] > 0.5:
        s[ES_E_SUPPLY] += h * s[ES_V] * ia
        s[ES_E_WINDING] += h * p[EP_R] * ia * ia
        s[ES_E_EMF] += h * p[EP_KT] * 0.5 * (s[ES_W0] + omega1) * ia
    s[ES_I] = s[ES_I1]


@kernel
def stage_off(p, s):
    """Switch the power stage off (safe state): the winding opens, its stored energy goes into the
    freewheeling path's resistance."""
    if s[ES_STAGE] > 0.5:
        s[ES_E_WINDING] += 0.5 * p[EP_L] * s[ES_I] ** 2
        s[ES_I] = 0.0
        s[ES_I1] = 0.0
        s[ES_STAGE] = 0.0


def inductance_energy(p: np.ndarray, s: np.ndarray) -> float:
    return 0.5 * p[EP_L] * s[ES_I] ** 2


@inline_kernel
def external_command(p, s, i_cmd, invalid):
    """An external controller's current command i_cmd (A) for the coming step (``ES_EXT`` set).
    ``invalid``: no valid command (none yet, or the watchdog timed out). The power stage switches on
    at the first valid command; a command that stops once the stage is on switches it off with the
    fault latched (ES_FAULT) until the EPS is reset: the safe state, assist off."""
    if invalid:
        if s[ES_STAGE] > 0.5:
            stage_off(p, s)
            s[ES_FAULT] = 1.0
    elif s[ES_STAGE] < 0.5 and s[ES_FAULT] < 0.5:
        s[ES_STAGE] = 1.0
    s[ES_EXT_I] = i_cmd


def external_mode(p: np.ndarray, s: np.ndarray, on: bool) -> None:
    """Hand the current command to an external controller (``on``; the stage waits, off, for its first
    valid command) or back to the built-in assistance law (stage on); either way the fault is cleared."""
    if on:
        stage_off(p, s)
    s[ES_EXT] = 1.0 if on else 0.0
    s[ES_STAGE] = 0.0 if on else 1.0
    s[ES_FAULT] = 0.0


@inline_kernel
def eps_outputs(p, s, q, qd, ic, ir, t_driver, out):
    """The EPS's outputs (EO_*) after the step; t_driver: the driver's torque on the wheel (N m)."""
    rp = p[EP_RP]
    out[EO_SW_ANGLE] = q[ic]
    out[EO_SW_TORQUE] = t_driver
    out[EO_TB_TORQUE] = p[EP_K_TB] * (q[ic] - q[ir] / rp)
    out[EO_RACK] = q[ir]
    out[EO_MOTOR_ANGLE] = p[EP_N] * q[ir] / rp
    out[EO_MOTOR_SPEED] = p[EP_N] * qd[ir] / rp
    out[EO_CURRENT] = s[ES_I]
    out[EO_VOLTAGE] = s[ES_V]
    out[EO_POWER] = s[ES_V] * s[ES_I]
    out[EO_ASSIST_TORQUE] = p[EP_ETA_G] * p[EP_N] * p[EP_KT] * s[ES_I]
