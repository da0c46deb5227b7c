"""Compiled parts of the switchable physical effects (rtsim.vehicle.car.effects has the catalogue): the
array layouts and the kernels the vehicle step calls when an effect is on.

Parameter array ``Parts.effects`` (float64, FX_SIZE), packed by ``rtsim.vehicle.car.effects.pack_effects``;
all zeros (but the neutral scales, 1.0) is the nominal model, and with ``FX_ON`` = 0 the vehicle step
runs exactly the nominal code. State array ``States.effects`` (float64, EffectState.SIZE): brake lag, driveline
nodes. Units SI; brake torques N*m, pressures kPa.

Formulations (each chosen so that the multibody step stays implicit and allocation-free):

- rolling_resistance: My -= c Fz r_l sat(vx / RR_SPEED_EPS) on each wheel, r_l = |P - W| along the road
  normal, i.e. a force c Fz at the contact point opposing rolling; sat is the C1 cubic
  x (3 - x^2) / 2 on |x| < 1 (smooth through standstill), +-1 outside.
- aero_drag: drag area added to the model's (same law, 0.5 rho CdA |v| v at the centre of mass).
- road_grade: gravity tilted by theta = atan(grade) about the horizontal axis normal to the car's heading
  (uphill ahead): every translational mass m gets m (g' - g), g' = -g (sin theta h + cos theta e_z),
  h the heading in the horizontal plane; accelerometers and inclinometers see the tilted gravity.
- brake_friction, brake_lag, brake_stiction act on each wheel's sliding torque tau_s and breakaway
  torque tau_b after the pressure actuator (``effects_brake``): x = first-order lag of the nominal
  tau_s (exact step, x += (1 - exp(-h/tau)) (tau_s - x)), tau_s' = scale x, tau_b' = (mu_s/mu) tau_s'
  + T_b min(1, p_eff / BRAKE_STICTION_PRESSURE), p_eff = x / gain the (lagged) wheel-cylinder pressure.
- driveline_compliance: per driven wheel a node of inertia J_d (DRIVELINE_INERTIA) takes the drive
  torque and drives the wheel through a torsional spring k and damper c = 2 zeta sqrt(k J_d). The node is
  integrated with the trapezoidal rule inside the multibody step and condensed out exactly
  (``driveline_torque``), so the shaft torque and its stiffness/damping enter the implicit step; the
  powertrain sees the node speed.
- tyre_slip_stiffness: the slips fed to the force law are kappa s and atan(s tan alpha) (slip
  stiffnesses scaled by s, peak forces unchanged).
- tyre_relaxation: relaxation lengths lengthened by L in the transient-slip model.
- bearing_drag: -T sat(omega_rel / BEARING_OMEGA_EPS) between wheel and knuckle (implicit, with its
  damping in the tangent).
- mass: a point mass dm at the sprung centre of mass: generalized force -dm r'' - dm g e_z with its
  exact tangent dm on W (rtsim.vehicle.car.step); the constant mass matrix of the model is untouched.
- sensor_*: parameters of the one sensor model (rtsim.vehicle.kit.sensor_model), packed there; the
  vehicle step records the physical values into its history ring (``record_sensors``) for the delays.
"""
from __future__ import annotations

from enum import IntEnum
from math import sqrt

import numpy as np

from rtsim.jit import inline_kernel, kernel

from ..kit.brake import BO_TAU_BREAK, BO_TAU_SLIDE, BP_BREAK_RATIO, BP_GAIN, BP_STUCK, BS_P_FRONT, BS_P_REAR, \
    BS_TAU_BREAK, BS_TAU_SLIDE
from ..kit.layout import offsets
from ..kit.sensor_model import sensor_apply, sensor_fill, sensor_next_row
from .layout import CI_PHI
from .sensors import S_ACCEL_X, S_PITCH, S_ROLL, true_sensors

# ---- constants of the formulations ------------------------------------------------------------------
RR_SPEED_EPS = 0.1            # m/s, rolling resistance fades linearly-smoothly to 0 below this speed
BEARING_OMEGA_EPS = 0.2       # rad/s, bearing drag band around zero relative spin
BRAKE_STICTION_PRESSURE = 100.0   # kPa: the added breakaway torque grows with pressure up to here
DRIVELINE_INERTIA = 0.1       # kg*m^2 per driven wheel: propshaft, differential, inboard half-shaft
DRIVELINE_DAMPING_RATIO = 0.1  # zeta of the node on the spring against a held wheel

# ---- parameter array layout (Parts.effects) -----------------------------------------------------------
(FX_ON,           # 1.0: a model effect is on (nothing else is read otherwise)
 FX_RR,           # rolling resistance coefficient added, 1
 FX_CDA,          # drag area added, m^2
 FX_GRADE,        # 1.0: road grade on
 FX_G_SIN,        # g sin(theta), m/s^2
 FX_G_1MCOS,      # g (1 - cos(theta)), m/s^2
 FX_SIN,          # sin(theta)
 FX_COS,          # cos(theta)
 FX_BRAKE,        # 1.0: a brake effect is on
 FX_B_SCALE,      # brake friction scale (1 nominal)
 FX_B_BREAK,      # added breakaway torque per wheel, N*m
 FX_B_LAG,        # 1 - exp(-h / tau) of the brake lag (0: no lag)
 FX_DL,           # 1.0: driveline compliance on
 FX_DL_K,         # N*m/rad
 FX_DL_C,         # N*m*s/rad
 FX_DL_J,         # kg*m^2
 FX_SLIP,         # tyre slip stiffness scale (1 nominal)
 FX_RELAX,        # relaxation length added, m
 FX_BEARING,      # bearing drag per wheel, N*m
 FX_MASS,         # added mass at the sprung centre of mass, kg
 FX_M_CHASSIS,    # sprung mass + added mass, kg (for the grade)
 FX_M_CORNER,     # [4] unsprung masses, kg (for the grade)
 FX_SIZE) = offsets(*(1,) * 21, 4)

# ---- state array layout (States.effects) ---------------------------------------------------------------
class EffectState(IntEnum):
    """The effects' state array (States.effects): offsets of its blocks, then SIZE (rtsim.mbs.model's
    FS_* index the model's float settings, another array)."""
    (LAG,            # [4] lagged nominal sliding torque, N*m
     DL,             # [2 x 3] driven wheels left, right: node angle rad, node speed rad/s, shaft torque N*m
     SIZE) = offsets(4, 2 * 3)


def neutral_params() -> np.ndarray:
    """The parameter array of the nominal model (no effect on)."""
    fx = np.zeros(FX_SIZE)
    fx[FX_B_SCALE] = 1.0
    fx[FX_SLIP] = 1.0
    fx[FX_COS] = 1.0
    return fx


# ---- helpers -----------------------------------------------------------------------------------------
@inline_kernel
def smooth_sign(x, eps):
    """(s, ds/dx): the C1 cubic s = y (3 - y^2) / 2, y = x / eps, on |y| < 1; sign(x) outside."""
    y = x / eps
    if y >= 1.0:
        return 1.0, 0.0
    if y <= -1.0:
        return -1.0, 0.0
    return 0.5 * y * (3.0 - y * y), 1.5 * (1.0 - y * y) / eps


@inline_kernel
def driveline_torque(fx, fs, j, t_src, phi, phid, h):
    """Shaft torque on driven wheel j (0 left, 1 right) at the end of a step h for the wheel's spin angle phi
    and rate phid at that instant, with the node's trapezoidal step condensed out:
        x = x_n + h/2 (w_n + w),  J (w - w_n) = h T_src - h/2 (T_n + T),  T = k (x - phi) + c (w - phid).
    Returns (T, node speed w, node angle x, dT/d(-phi) = k g, dT/d(-phid) = c g) with g = J / (J + h/2 B)."""
    k = fx[FX_DL_K]
    c = fx[FX_DL_C]
    jd = fx[FX_DL_J]
    o = EffectState.DL + 3 * j
    x0 = fs[o]
    w0 = fs[o + 1]
    t0 = fs[o + 2]
    hh = 0.5 * h
    a = k * (x0 + hh * w0 - phi) - c * phid
    b = k * hh + c
    den = jd + hh * b
    w = (jd * w0 + h * t_src - hh * (t0 + a)) / den
    gam = jd / den
    return a + b * w, w, x0 + hh * (w0 + w), k * gam, c * gam


# ---- kernels called by the vehicle step ------------------------------------------------------------------
@kernel
def effects_brake(fx, fs, bp, bs, out):
    """Brake lag, friction scale and added stiction on each wheel's sliding and breakaway torques, after
    brake_step set them from the line pressure (rtsim.vehicle.kit.brake state BS_*, outputs BO_*)."""
    a = fx[FX_B_LAG]
    scale = fx[FX_B_SCALE]
    t_break = fx[FX_B_BREAK]
    for i in range(4):
        if bp[BP_STUCK + i] > 0.5:          # a stuck caliper (rtsim.faults): its torques stay
            out[BO_TAU_SLIDE + i] = bs[BS_TAU_SLIDE + i]
            out[BO_TAU_BREAK + i] = bs[BS_TAU_BREAK + i]
            continue
        pw = bs[BS_P_FRONT] if i < 2 else bs[BS_P_REAR]
        gain = bp[BP_GAIN + i]
        target = gain * pw
        x = target
        if a > 0.0:
            x = fs[EffectState.LAG + i] + a * (target - fs[EffectState.LAG + i])
        fs[EffectState.LAG + i] = x
        ts = scale * x
        tb = ts * bp[BP_BREAK_RATIO + i]
        if t_break > 0.0 and gain > 0.0:
            r = x / (gain * BRAKE_STICTION_PRESSURE)
            if r > 1.0:
                r = 1.0
            elif r < 0.0:
                r = 0.0
            tb += t_break * r
        bs[BS_TAU_SLIDE + i] = ts
        bs[BS_TAU_BREAK + i] = tb
        out[BO_TAU_SLIDE + i] = ts
        out[BO_TAU_BREAK + i] = tb


@kernel
def driveline_commit(fx, fs, d, veh, drive, h):
    """Advance the driveline nodes over the converged step (drive: source torques, N*m)."""
    for j in range(2):
        i = veh.driven[j]
        kp = veh.corner_idx[i, CI_PHI]
        t, w, x, _k, _c = driveline_torque(fx, fs, j, drive[i], d.q[kp], d.qd[kp], h)
        o = EffectState.DL + 3 * j
        fs[o] = x
        fs[o + 1] = w
        fs[o + 2] = t


@inline_kernel
def heading(veh, q):
    """The car's heading in the horizontal plane: its x axis projected and normalised (x, y)."""
    ci = veh.chassis_idx
    hx, hy = q[ci[3]], q[ci[4]]
    nh = sqrt(hx * hx + hy * hy)
    if nh > 1e-9:
        hx /= nh
        hy /= nh
    return hx, hy


@inline_kernel
def _grade_sensors(fx, q, veh, out):
    """Accelerometers and inclinometers under the tilted gravity of the road grade."""
    ci = veh.chassis_idx
    ux, uy, uz = q[ci[3]], q[ci[4]], q[ci[5]]
    hx, hy = heading(veh, q)
    # specific force f' = f - (g' - g) = f + g sin h - g (1 - cos) e_z, in body axes
    gs = fx[FX_G_SIN]
    gc = fx[FX_G_1MCOS]
    dx, dy, dz = gs * hx, gs * hy, -gc
    for k in range(3):
        e = ci[3 + 3 * k]
        out[S_ACCEL_X + k] += dx * q[e] + dy * q[e + 1] + dz * q[e + 2]
    # "up" is now sin h + cos e_z
    s, c = fx[FX_SIN], fx[FX_COS]
    upx, upy, upz = s * hx, s * hy, c
    vu = q[ci[6]] * upx + q[ci[7]] * upy + q[ci[8]] * upz
    wu = q[ci[9]] * upx + q[ci[10]] * upy + q[ci[11]] * upz
    uu = ux * upx + uy * upy + uz * upz
    out[S_ROLL] = np.arctan2(vu, wu)
    out[S_PITCH] = np.arcsin(min(1.0, max(-1.0, -uu)))


@kernel
def physical_sensors(m, d, veh, signals, fx, out):
    """Noise-free channel values (rtsim.channels.SENSOR_NAMES order) including the model effects that
    change what the sensors sense (the grade's tilted gravity)."""
    true_sensors(m, d, veh, signals, out)
    if fx[FX_ON] > 0.5 and fx[FX_GRADE] > 0.5:
        _grade_sensors(fx, d.q, veh, out)


@kernel
def record_sensors(m, d, veh, signals, fx, sm_params, sm_state):
    """Append this step's physical sensor values to the sensor model's history ring (for its delays)."""
    n = sm_params.shape[0]
    o = sensor_next_row(sm_state, n)
    physical_sensors(m, d, veh, signals, fx, sm_state[o:o + n])


@kernel
def fill_history(m, d, veh, signals, fx, sm_state, scratch):
    """Fill the sensor model's whole history ring with the current physical values (before the first
    step nothing older is known: the signal is held)."""
    physical_sensors(m, d, veh, signals, fx, scratch)
    sensor_fill(sm_state, scratch)


@kernel
def sensor_stage(m, d, veh, signals, fx, sm_params, sm_state, out):
    """The sensor channels as the car's sensors report them: the physical values (true_sensors, and
    what model effects change in the sensing) through the sensor model (rtsim.vehicle.kit.sensor_model;
    with every channel neutral, exactly the physical values). A drop-in for true_sensors in compiled loops."""
    physical_sensors(m, d, veh, signals, fx, out)
    sensor_apply(sm_params, sm_state, out, out)
