"""The two-wheeler as the HIL service steps it: the rider inside the compiled step, the bus commands of
a rider-assist ECU, the sensors and the observer state, in the vehicle's channel dictionary
(rtsim.channels.two_wheeler_channels, configs/can/motorcycle.dbc).

Each step (``plant_step``): the inputs are formed from the rider's outputs and the bus commands, the
two-wheeler steps (rtsim.vehicle.motorcycle.step), and a fall ends the run with the status ``FELL``:

- throttle and the two caliper pressures: the ECU's command while it is valid (received and not timed
  out: the watchdog writes 1.0 into the command's ``*_INVALID`` slot otherwise), else the rider's own
  demand, as a mechanical fallback would give it (no rider: zero);
- steering torque: the rider's plus the ECU's assist torque (while valid);
- brake torque = pressure times the brake's gain (N m/kPa); the drive torque at the rear wheel from the
  engine and gearbox of the vehicle's [powertrain] (rtsim.vehicle.motorcycle.engine; a vehicle without
  one: the throttle times ``MAX_WHEEL_TORQUE``, an ideal drive).

The offline ride (rtsim.vehicle.motorcycle.ride) calls the same view and inputs kernels, with no bus
commands: a scenario run and a served session form their inputs alike.

The rider (``plant_rider``, rtsim.vehicle.motorcycle.rider) reads the same view as offline
(rtsim.vehicle.motorcycle.ride): the rear contact point, the pivot's velocity in the heading frame, yaw,
roll and steer with their rates.

Sensors (``plant_sensors``): the IMU at ``[sensors] imu_position_m`` on the rear frame in the frame's
axes (x along the ground line at zero pitch, y left, z up): specific force ``R^T (r'' - g)`` (g the
multibody model's gravity; the kit's IMU, rtsim.vehicle.kit.imu), angular
rate ``R^T omega`` with ``omega = 1/2 sum e x e'`` over the frame's unit vectors; roll ``asin(v_z)``
and pitch ``asin(-x_z)``; wheel speeds relative to their carriers; the steering head's angle, rate
and the rider's torque; fork and shock compressions; the rider's demands and the actuators' states.
They are ideal (no noise or bias model yet); the DBC quantises them.

Model/data: ``PlantParams`` (immutable, the ``veh`` slot of the service's step) and ``PlantState`` (the
rider's view and outputs, the applied inputs) are named tuples of arrays; the kernels allocate nothing.
"""
from __future__ import annotations

from collections import namedtuple
from math import asin, atan2, cos, sin, sqrt

import numpy as np

from rtsim.channels import TWO_WHEELER_SENSORS, TWO_WHEELER_STATE
from rtsim.jit import inline_kernel, kernel
from .rider import (RO_BRAKE_F, RO_BRAKE_R, RO_THROTTLE, RO_TORQUE, RV_DELTA, RV_DELTADOT, RV_PHI,
                           RV_PHIDOT, RV_R, RV_T, RV_U, RV_V, RV_X, RV_Y, RV_YAW, NRO, NRV, RiderState, rider_step)

from rtsim.mbs.model import gravity

from ..kit.imu import imu_reading
from ..kit.layout import offsets
from ..kit.rigid import angular_velocity
from .engine import ES_ENGINE_SPEED, ES_GEAR, engine_state, pack_engine, rear_wheel_torque
from .layout import (K_DELTA, K_E1, K_H, K_P, K_PHI_F, K_PHI_R, K_THETA, K_V, K_W_R, K_ZETA)
from .step import (MP_FREE_SUSPENSION, MP_SHOCK_C0, MP_SHOCK_L0, MP_THETA0, TO_ALPHA, TO_FX, TO_FY, TO_FZ, TO_GAMMA,
                   TO_KAPPA, TO_MZ, U_BRAKE_FRONT, U_BRAKE_REAR, U_DRIVE_TORQUE, U_STEER_TORQUE, _shock_length,
                   two_wheeler_step)
from .sim import FALL_ROLL

MAX_WHEEL_TORQUE = 1200.0       # N m at the rear wheel at full throttle, for a vehicle without [powertrain]
FELL = 64                       # plant_step's status for a fall (rtsim.mbs.model codes are below)
LIFT_GRACE = 0.5                # s: both tyres may be unloaded this long at the start (settling)

# The command array the service's watchdog fills (bridge.can_e2e.rx_watchdog): each bus command's value
# and, in its *_INVALID slot, 1.0 while it has no valid value.
(C_THROTTLE, C_BRAKE_FRONT, C_BRAKE_REAR, C_ASSIST, C_THROTTLE_INVALID, C_BRAKE_FRONT_INVALID,
 C_BRAKE_REAR_INVALID, C_ASSIST_INVALID, NCOMMAND) = offsets(*(1,) * 8)
COMMAND_SLOTS = {"throttle_cmd": C_THROTTLE, "brake_pressure_front_cmd": C_BRAKE_FRONT,
                 "brake_pressure_rear_cmd": C_BRAKE_REAR, "assist_torque_cmd": C_ASSIST}
INVALID_SLOTS = {"throttle_cmd": C_THROTTLE_INVALID, "brake_pressure_front_cmd": C_BRAKE_FRONT_INVALID,
                 "brake_pressure_rear_cmd": C_BRAKE_REAR_INVALID, "assist_torque_cmd": C_ASSIST_INVALID}

# PlantParams.pp: IMU position in the frame's (e1, h) axes from the pivot (m), the caster's cosine and
# sine (the frame's x and z from e1 and the steering axis h), rear wheel radius (m), brake gains (N m/kPa),
# maximum caliper pressure (kPa), drive torque at full throttle without an engine (N m), 1 with a rider,
# 1 with slip tyres, 1 with an engine (PlantParams.ep: rtsim.vehicle.motorcycle.engine.pack_engine), the
# multibody model's gravity vector (3 slots, m/s^2, world axes: the IMU's, rtsim.vehicle.kit.imu).
(PP_IMU_E1, PP_IMU_H, PP_COS_CASTER, PP_SIN_CASTER, PP_REAR_RADIUS, PP_BRAKE_GAIN_F, PP_BRAKE_GAIN_R,
 PP_MAX_PRESSURE, PP_MAX_DRIVE, PP_RIDER, PP_SLIP_TYRES, PP_ENGINE, PP_GRAVITY, NPP) = offsets(*(1,) * 12, 3)
# PlantState.inp: what acted over the last step, for the sensors and the state.
(IN_RIDER_TORQUE, IN_ASSIST, IN_THROTTLE, IN_BRAKE_F, IN_BRAKE_R, IN_RIDER_THROTTLE, IN_RIDER_BRAKE_F,
 IN_RIDER_BRAKE_R, IN_DRIVE, NIN) = offsets(*(1,) * 9)

# Where each channel goes in the sensor and state arrays: its position in the channel dictionary.
_SENSORS = [c.name for c in TWO_WHEELER_SENSORS]
(S_ACCEL_X, S_ACCEL_Y, S_ACCEL_Z, S_GYRO_X, S_GYRO_Y, S_GYRO_Z, S_ROLL, S_PITCH, S_WHEEL_F, S_WHEEL_R, S_STEER,
 S_STEER_RATE, S_STEER_TORQUE, S_FORK, S_SHOCK, S_RIDER_THROTTLE, S_RIDER_BRAKE_F, S_RIDER_BRAKE_R, S_THROTTLE,
 S_BRAKE_F, S_BRAKE_R) = (_SENSORS.index(n) for n in (
    "accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z", "roll", "pitch", "wheel_speed_front",
    "wheel_speed_rear", "steer_angle", "steer_rate", "steering_torque", "fork_travel", "shock_travel",
    "rider_throttle", "rider_brake_front", "rider_brake_rear", "throttle", "brake_pressure_front",
    "brake_pressure_rear"))
assert _SENSORS[S_ACCEL_X:S_GYRO_Z + 1] == ["accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z"]
_STATE = [c.name for c in TWO_WHEELER_STATE]
(X_POS_X, X_ROLL, X_PITCH, X_YAW, X_VEL_X, X_VEL_Y, X_VEL_Z, X_ROLL_RATE, X_PITCH_RATE, X_YAW_RATE, X_SPEED,
 X_STEER, X_STEER_RATE, X_FORK, X_SHOCK, X_SWINGARM, X_WHEEL_SPEED_F, X_WHEEL_SPEED_R, X_WHEEL_ANGLE_F,
 X_WHEEL_ANGLE_R, X_TYRES, X_RIDER_TORQUE, X_ASSIST, X_DRIVE, X_THROTTLE, X_BRAKE_F, X_BRAKE_R, X_ENGINE_SPEED,
 X_GEAR, X_PATH_OFFSET, X_VIOLATION) = (_STATE.index(n) for n in (
    "pos_x", "roll_angle", "pitch_angle", "yaw_angle", "vel_x", "vel_y", "vel_z", "roll_rate", "pitch_rate",
    "yaw_rate", "speed", "steer_angle", "steer_rate", "fork_travel", "shock_travel", "swingarm_angle",
    "wheel_speed_front", "wheel_speed_rear", "wheel_angle_front", "wheel_angle_rear", "tyre_fx_front",
    "steering_torque", "assist_torque", "drive_torque", "throttle", "brake_pressure_front", "brake_pressure_rear",
    "engine_speed", "gear", "path_offset", "constraint_violation"))
# the tyres' channels: front then rear, each in this order of the tyre outputs (TO_*)
TYRE_OUTPUTS = (("fx", TO_FX), ("fy", TO_FY), ("fz", TO_FZ), ("mz", TO_MZ), ("slip_ratio", TO_KAPPA),
                ("slip_angle", TO_ALPHA), ("camber", TO_GAMMA))
assert _STATE[X_POS_X:X_POS_X + 3] == ["pos_x", "pos_y", "pos_z"]
assert _STATE[X_TYRES:X_TYRES + 14] == [f"tyre_{k}_{w}" for w in ("front", "rear") for k, _ in TYRE_OUTPUTS]
TYRE_KEYS = np.array([k for _, k in TYRE_OUTPUTS], dtype=np.int64)

PlantParams = namedtuple("PlantParams", ["pp", "ep"])
PlantState = namedtuple("PlantState", ["rider_view", "rider_out", "inp", "es"])
PlantIO = namedtuple("PlantIO", ["commands"])


def make_plant(mm, rider_on: bool, gear: int | None = None) -> tuple[PlantParams, PlantState]:
    """The plant's parameters and a fresh state for the two-wheeler `mm` (rtsim.vehicle.motorcycle.build);
    gear: a fixed gear for the engine (None: the vehicle file's choice; 0: automatic)."""
    from .parts import frame_coordinates

    cfg = mm.config
    pp = np.zeros(NPP)
    pp[PP_IMU_E1], pp[PP_IMU_H] = frame_coordinates(mm, cfg.sensors.imu_position_m)
    pp[PP_COS_CASTER], pp[PP_SIN_CASTER] = np.cos(cfg.caster_rad), np.sin(cfg.caster_rad)
    pp[PP_REAR_RADIUS] = cfg.rear_wheel.radius_m
    if cfg.brakes is not None:
        pp[PP_BRAKE_GAIN_F], pp[PP_BRAKE_GAIN_R] = cfg.brakes.front_nm_per_kpa, cfg.brakes.rear_nm_per_kpa
        pp[PP_MAX_PRESSURE] = cfg.brakes.max_pressure_kpa
    pp[PP_MAX_DRIVE] = MAX_WHEEL_TORQUE
    pp[PP_RIDER] = float(rider_on)
    pp[PP_SLIP_TYRES] = 0.0 if mm.knife_edge else 1.0
    pp[PP_ENGINE] = float(cfg.powertrain is not None)
    pp[PP_GRAVITY:PP_GRAVITY + 3] = gravity(mm.mech.model)
    ep = pack_engine(cfg.powertrain, cfg.final_ratio, gear) if cfg.powertrain is not None else np.zeros(1)
    return PlantParams(pp, ep), PlantState(np.zeros(NRV), np.zeros(NRO), np.zeros(NIN), engine_state())


# ---- the rear frame's kinematics -----------------------------------------------------------------------
@inline_kernel
def _frame_axis(q, idx, pp, which):
    """The rear frame's x (which = 0) or z (which = 2) axis in the world, from e1 and the steering axis."""
    c, s = pp[PP_COS_CASTER], pp[PP_SIN_CASTER]
    ke, kh = idx[K_E1], idx[K_H]
    if which == 0:
        return c * q[ke] - s * q[kh], c * q[ke + 1] - s * q[kh + 1], c * q[ke + 2] - s * q[kh + 2]
    return s * q[ke] + c * q[kh], s * q[ke + 1] + c * q[kh + 1], s * q[ke + 2] + c * q[kh + 2]


@inline_kernel
def _yaw(q, idx):
    kv = idx[K_V]
    return atan2(-q[kv], q[kv + 1])


@inline_kernel
def _roll(q, idx):
    return asin(max(-1.0, min(1.0, q[idx[K_V] + 2])))


@inline_kernel
def _heading_velocity(q, qd, idx):
    """The pivot's velocity (forward, lateral) in the heading frame, m/s."""
    psi = _yaw(q, idx)
    c, s = cos(psi), sin(psi)
    kp = idx[K_P]
    return qd[kp] * c + qd[kp + 1] * s, -qd[kp] * s + qd[kp + 1] * c


@inline_kernel
def _shock_travel(q, idx, par):
    if par[MP_FREE_SUSPENSION] < 0.5:
        return 0.0
    length, _dl = _shock_length(par, q[idx[K_THETA]])
    return par[MP_SHOCK_C0] + par[MP_SHOCK_L0] - length


@inline_kernel
def _scalar(x, idx, k):
    return x[idx[k]] if idx[k] >= 0 else 0.0


# ---- the rider and the inputs --------------------------------------------------------------------------
@kernel
def plant_rider(d, idx, pp, rider, view, out):
    """The rider's view of the two-wheeler and one rider call."""
    plant_view(d, idx, pp, view)
    rider_step(rider, view, out)


@kernel
def plant_view(d, idx, pp, view):
    """The rider's view (rtsim.vehicle.motorcycle.rider RV_*): the rear contact point, the pivot's velocity in the
    heading frame, yaw, roll and steer with their rates."""
    q, qd = d.q, d.qd
    kv, kw = idx[K_V], idx[K_W_R]
    # rear contact: the wheel centre less the radius along the wheel plane's up direction
    a2 = q[kv + 2]
    u0, u1, u2 = -a2 * q[kv], -a2 * q[kv + 1], 1.0 - a2 * a2
    un = sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    r = pp[PP_REAR_RADIUS] / un
    psi = _yaw(q, idx)
    fwd, lat = _heading_velocity(q, qd, idx)
    w0, w1, w2 = angular_velocity(q, qd, idx[K_E1], idx[K_V], idx[K_H])
    view[RV_T] = d.t[0]
    view[RV_X] = q[kw] - r * u0
    view[RV_Y] = q[kw + 1] - r * u1
    view[RV_YAW] = psi
    view[RV_U] = fwd
    view[RV_V] = lat
    view[RV_R] = w2
    view[RV_PHI] = _roll(q, idx)
    view[RV_PHIDOT] = w0 * cos(psi) + w1 * sin(psi)
    view[RV_DELTA] = q[idx[K_DELTA]]
    view[RV_DELTADOT] = qd[idx[K_DELTA]]


@inline_kernel
def _clip(x, lo, hi):
    return lo if x < lo else (hi if x > hi else x)


@kernel
def plant_inputs(pp, ep, es, commands, out, u, inp, wheel_speed, h):
    """The inputs over the next step of h s from the rider's outputs and the bus commands (module
    docstring); wheel_speed: the rear wheel's spin relative to the frame, rad/s (the gearbox's)."""
    rider_thr, rider_bf, rider_br = out[RO_THROTTLE], out[RO_BRAKE_F], out[RO_BRAKE_R]
    thr = rider_thr if commands[C_THROTTLE_INVALID] > 0.5 else commands[C_THROTTLE]
    bf = rider_bf if commands[C_BRAKE_FRONT_INVALID] > 0.5 else commands[C_BRAKE_FRONT]
    br = rider_br if commands[C_BRAKE_REAR_INVALID] > 0.5 else commands[C_BRAKE_REAR]
    assist = 0.0 if commands[C_ASSIST_INVALID] > 0.5 else commands[C_ASSIST]
    thr = _clip(thr, 0.0, 1.0)
    bf = _clip(bf, 0.0, pp[PP_MAX_PRESSURE])
    br = _clip(br, 0.0, pp[PP_MAX_PRESSURE])
    u[U_STEER_TORQUE] = out[RO_TORQUE] + assist
    if pp[PP_ENGINE] > 0.5:
        u[U_DRIVE_TORQUE] = rear_wheel_torque(ep, es, thr, wheel_speed, h)
    else:
        u[U_DRIVE_TORQUE] = thr * pp[PP_MAX_DRIVE]
    u[U_BRAKE_FRONT] = bf * pp[PP_BRAKE_GAIN_F]
    u[U_BRAKE_REAR] = br * pp[PP_BRAKE_GAIN_R]
    inp[IN_RIDER_TORQUE] = out[RO_TORQUE]
    inp[IN_ASSIST] = assist
    inp[IN_THROTTLE] = thr
    inp[IN_BRAKE_F] = bf
    inp[IN_BRAKE_R] = br
    inp[IN_RIDER_THROTTLE] = rider_thr
    inp[IN_RIDER_BRAKE_F] = rider_bf
    inp[IN_RIDER_BRAKE_R] = rider_br
    inp[IN_DRIVE] = u[U_DRIVE_TORQUE]


@kernel
def plant_step(m, d, veh, vd, parts, io, h):
    """The inputs, one two-wheeler step of h s, the fall check. Returns OK, a step failure or FELL."""
    pp = veh.pp
    plant_inputs(pp, veh.ep, vd.es, io.commands, vd.rider_out, parts.u, vd.inp, d.qd[parts.idx[K_PHI_R]], h)
    status = two_wheeler_step(m, d, h, parts.idx, parts.par, parts.tab, parts.u, parts.tp, parts.slip, parts.tyre)
    if status != 0:
        return status
    if abs(_roll(d.q, parts.idx)) > FALL_ROLL:
        return FELL
    if pp[PP_SLIP_TYRES] > 0.5 and parts.tyre[0, TO_FZ] <= 0.0 and parts.tyre[1, TO_FZ] <= 0.0 \
            and d.t[0] > LIFT_GRACE:
        return FELL
    return 0


# ---- sensors and state ---------------------------------------------------------------------------------
@kernel
def plant_sensors(d, idx, par, pp, inp, out):
    """The sensor channels (the S_* slots of rtsim.channels.TWO_WHEELER_SENSORS) of the current state into out."""
    q, qd, qdd = d.q, d.qd, d.qdd
    x0, x1, x2 = _frame_axis(q, idx, pp, 0)
    z0, z1, z2 = _frame_axis(q, idx, pp, 2)
    kv, kp, ke, kh = idx[K_V], idx[K_P], idx[K_E1], idx[K_H]
    y0, y1, y2 = q[kv], q[kv + 1], q[kv + 2]
    a, b = pp[PP_IMU_E1], pp[PP_IMU_H]
    # IMU point r = P + a e1 + b h: r'' is linear in the coordinates' accelerations
    f0 = qdd[kp] + a * qdd[ke] + b * qdd[kh]
    f1 = qdd[kp + 1] + a * qdd[ke + 1] + b * qdd[kh + 1]
    f2 = qdd[kp + 2] + a * qdd[ke + 2] + b * qdd[kh + 2]
    w = angular_velocity(q, qd, idx[K_E1], idx[K_V], idx[K_H])
    g = (pp[PP_GRAVITY], pp[PP_GRAVITY + 1], pp[PP_GRAVITY + 2])
    imu_reading((f0, f1, f2), w, (x0, x1, x2), (y0, y1, y2), (z0, z1, z2), g, out, S_ACCEL_X, S_GYRO_X)
    out[S_ROLL] = _roll(q, idx)
    out[S_PITCH] = asin(max(-1.0, min(1.0, -x2)))
    out[S_WHEEL_F] = qd[idx[K_PHI_F]]
    out[S_WHEEL_R] = qd[idx[K_PHI_R]] - _scalar(qd, idx, K_THETA)
    out[S_STEER] = q[idx[K_DELTA]]
    out[S_STEER_RATE] = qd[idx[K_DELTA]]
    out[S_STEER_TORQUE] = inp[IN_RIDER_TORQUE]
    out[S_FORK] = _scalar(q, idx, K_ZETA)
    out[S_SHOCK] = _shock_travel(q, idx, par)
    out[S_RIDER_THROTTLE] = inp[IN_RIDER_THROTTLE]
    out[S_RIDER_BRAKE_F] = inp[IN_RIDER_BRAKE_F]
    out[S_RIDER_BRAKE_R] = inp[IN_RIDER_BRAKE_R]
    out[S_THROTTLE] = inp[IN_THROTTLE]
    out[S_BRAKE_F] = inp[IN_BRAKE_F]
    out[S_BRAKE_R] = inp[IN_BRAKE_R]


@kernel
def plant_state(d, idx, par, pp, tyre, inp, es, path_offset, out):
    """The observer state (the X_* slots of rtsim.channels.TWO_WHEELER_STATE) into out."""
    q, qd = d.q, d.qd
    kp = idx[K_P]
    psi = _yaw(q, idx)
    fwd, lat = _heading_velocity(q, qd, idx)
    w0, w1, w2 = angular_velocity(q, qd, idx[K_E1], idx[K_V], idx[K_H])
    _x0, _x1, x2 = _frame_axis(q, idx, pp, 0)
    kv = idx[K_V]
    for c in range(3):
        out[X_POS_X + c] = q[kp + c]
    out[X_ROLL] = _roll(q, idx)
    out[X_PITCH] = asin(max(-1.0, min(1.0, -x2)))
    out[X_YAW] = psi
    out[X_VEL_X] = fwd
    out[X_VEL_Y] = lat
    out[X_VEL_Z] = qd[kp + 2]
    out[X_ROLL_RATE] = w0 * cos(psi) + w1 * sin(psi)
    out[X_PITCH_RATE] = w0 * q[kv] + w1 * q[kv + 1] + w2 * q[kv + 2]
    out[X_YAW_RATE] = w2
    out[X_SPEED] = sqrt(fwd * fwd + lat * lat)
    out[X_STEER] = q[idx[K_DELTA]]
    out[X_STEER_RATE] = qd[idx[K_DELTA]]
    out[X_FORK] = _scalar(q, idx, K_ZETA)
    out[X_SHOCK] = _shock_travel(q, idx, par)
    out[X_SWINGARM] = _scalar(q, idx, K_THETA) - par[MP_THETA0] if idx[K_THETA] >= 0 else 0.0
    out[X_WHEEL_SPEED_F] = qd[idx[K_PHI_F]]
    out[X_WHEEL_SPEED_R] = qd[idx[K_PHI_R]] - _scalar(qd, idx, K_THETA)
    out[X_WHEEL_ANGLE_F] = q[idx[K_PHI_F]]
    out[X_WHEEL_ANGLE_R] = q[idx[K_PHI_R]]
    j = X_TYRES
    for w in range(2):
        for k in TYRE_KEYS:
            out[j] = tyre[w, k]
            j += 1
    out[X_RIDER_TORQUE] = inp[IN_RIDER_TORQUE]
    out[X_ASSIST] = inp[IN_ASSIST]
    out[X_DRIVE] = inp[IN_DRIVE]
    out[X_THROTTLE] = inp[IN_THROTTLE]
    out[X_BRAKE_F] = inp[IN_BRAKE_F]
    out[X_BRAKE_R] = inp[IN_BRAKE_R]
    out[X_ENGINE_SPEED] = es[ES_ENGINE_SPEED] if pp[PP_ENGINE] > 0.5 else 0.0
    out[X_GEAR] = es[ES_GEAR] if pp[PP_ENGINE] > 0.5 else 0.0
    out[X_PATH_OFFSET] = path_offset
    viol = 0.0
    for i in range(d.phi.shape[0]):
        viol = max(viol, abs(d.phi[i]))
    out[X_VIOLATION] = viol


@kernel
def rider_offset_kernel(rider, pp):
    """The rider's lateral offset from the path, m (0 without a rider)."""
    return rider.st[RiderState.N] if pp[PP_RIDER] > 0.5 else 0.0
