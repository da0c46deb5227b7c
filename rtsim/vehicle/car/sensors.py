"""The car's sensors (the seed's Table 1) as channels in SI units (rtsim.channels.SENSORS): their
physical values computed from the multibody state. What the sensors report of them (bias, scale,
noise, quantisation, delay) is the kit's sensor model (rtsim.vehicle.kit.sensor_model).

Inertial channels at the IMU mounting point rho (body frame, from the centre of mass):
  a = r'' + alpha x rho + omega x (omega x rho),  accel = R^T (a - g)   (specific force, body axes;
  g the multibody model's gravity: the kit's IMU, rtsim.vehicle.kit.imu)
  gyro = R^T omega,  with omega = (u x u' + v x v' + w x w') / 2 and alpha = (u x u'' + ...) / 2
  for the chassis frame R = [u v w]. Inclinometers: roll = atan2(v_z, w_z) (positive right side
  down), pitch = asin(-u_z) (positive nose down).
Steer angles: the heading of each front wheel's spin axis in the body frame, delta = atan2(-a_x, a_y).
"""
from __future__ import annotations

from math import asin, atan2

from rtsim.channels import EPS_SENSORS, SENSOR_NAMES
from rtsim.jit import kernel
from rtsim.mbs.constraints import poly_value

from ..kit.imu import imu_reading, model_gravity
from .layout import CI_PHI, CI_S, CI_Z

# channel indices, from the car's channel dictionary (rtsim.channels.car_sensors; the last two are the
# drive-torque sensors on the driven axle's left and right wheels, whichever axle that is)
(S_ACCEL_X, S_ACCEL_Y, S_ACCEL_Z, S_GYRO_X, S_GYRO_Y, S_GYRO_Z, S_ROLL, S_PITCH, S_WHEEL_FL, S_WHEEL_FR,
 S_WHEEL_RL, S_WHEEL_RR, S_BRAKE_PRESSURE, S_SW_ANGLE, S_STEER_FL, S_STEER_FR, S_ENGINE_SPEED,
 S_STEERING_TORQUE, S_THROTTLE, S_DRIVE_TORQUE_LEFT, S_DRIVE_TORQUE_RIGHT) = (
    SENSOR_NAMES.index(n) for n in (*SENSOR_NAMES[:-2], "wheel_torque_rl", "wheel_torque_rr"))
NSENSOR = len(SENSOR_NAMES)
assert tuple(SENSOR_NAMES[S_ACCEL_X:S_GYRO_Z + 1]) == ("accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z")
assert SENSOR_NAMES[S_WHEEL_FL] == "wheel_angle_fl" and SENSOR_NAMES[S_STEER_FR] == "steer_angle_fr"
# a car with electric power steering: its EPS's channels follow (rtsim.channels.EPS_SENSORS)
S_EPS0 = NSENSOR
NSENSOR_EPS = NSENSOR + len(EPS_SENSORS)

# subsystem signals handed to the sensors (Signals array); the EPS's five in EPS_SENSORS order
(SG_BRAKE_PRESSURE, SG_SW_ANGLE, SG_ENGINE_SPEED, SG_STEERING_TORQUE, SG_THROTTLE, SG_TORQUE_LEFT, SG_TORQUE_RIGHT,
 SG_MOTOR_ANGLE, SG_MOTOR_SPEED, SG_MOTOR_CURRENT, SG_POWER_STAGE, SG_VEHICLE_SPEED) = range(12)
NSIGNAL = 12


@kernel
def true_sensors(m, d, veh, signals, out):
    """Noise-free channel values of the current state into out (NSENSOR channels, or NSENSOR_EPS for a
    car with electric power steering)."""
    q, qd, qdd = d.q, d.qd, d.qdd
    ci = veh.chassis_idx
    om0 = om1 = om2 = 0.0
    al0 = al1 = al2 = 0.0
    for k in (3, 6, 9):
        e0, e1, e2 = q[ci[k]], q[ci[k + 1]], q[ci[k + 2]]
        d0, d1, d2 = qd[ci[k]], qd[ci[k + 1]], qd[ci[k + 2]]
        a0, a1, a2 = qdd[ci[k]], qdd[ci[k + 1]], qdd[ci[k + 2]]
        om0 += 0.5 * (e1 * d2 - e2 * d1)
        om1 += 0.5 * (e2 * d0 - e0 * d2)
        om2 += 0.5 * (e0 * d1 - e1 * d0)
        al0 += 0.5 * (e1 * a2 - e2 * a1)
        al1 += 0.5 * (e2 * a0 - e0 * a2)
        al2 += 0.5 * (e0 * a1 - e1 * a0)
    ux, uy, uz = q[ci[3]], q[ci[4]], q[ci[5]]
    vx, vy, vz = q[ci[6]], q[ci[7]], q[ci[8]]
    wx, wy, wz = q[ci[9]], q[ci[10]], q[ci[11]]
    lx, ly, lz = veh.imu_local[0], veh.imu_local[1], veh.imu_local[2]
    rx = lx * ux + ly * vx + lz * wx
    ry = lx * uy + ly * vy + lz * wy
    rz = lx * uz + ly * vz + lz * wz
    # omega x rho, then omega x (omega x rho) and alpha x rho
    c0 = om1 * rz - om2 * ry
    c1 = om2 * rx - om0 * rz
    c2 = om0 * ry - om1 * rx
    ax = qdd[ci[0]] + (al1 * rz - al2 * ry) + (om1 * c2 - om2 * c1)
    ay = qdd[ci[1]] + (al2 * rx - al0 * rz) + (om2 * c0 - om0 * c2)
    az = qdd[ci[2]] + (al0 * ry - al1 * rx) + (om0 * c1 - om1 * c0)
    imu_reading((ax, ay, az), (om0, om1, om2), (ux, uy, uz), (vx, vy, vz), (wx, wy, wz), model_gravity(m), out,
                S_ACCEL_X, S_GYRO_X)
    out[S_ROLL] = atan2(vz, wz)
    out[S_PITCH] = asin(min(1.0, max(-1.0, -uz)))
    for i in range(4):
        out[S_WHEEL_FL + i] = q[veh.corner_idx[i, CI_PHI]]
    for i in range(2):
        z = q[veh.corner_idx[i, CI_Z]]
        s = q[veh.corner_idx[i, CI_S]]
        a0 = poly_value(veh.axis_coef[i, 0], m.poly_exp, z, s)
        a1 = poly_value(veh.axis_coef[i, 1], m.poly_exp, z, s)
        out[S_STEER_FL + i] = atan2(-a0, a1)
    out[S_BRAKE_PRESSURE] = signals[SG_BRAKE_PRESSURE]
    out[S_SW_ANGLE] = signals[SG_SW_ANGLE]
    out[S_ENGINE_SPEED] = signals[SG_ENGINE_SPEED]
    out[S_STEERING_TORQUE] = signals[SG_STEERING_TORQUE]
    out[S_THROTTLE] = signals[SG_THROTTLE]
    out[S_DRIVE_TORQUE_LEFT] = signals[SG_TORQUE_LEFT]
    out[S_DRIVE_TORQUE_RIGHT] = signals[SG_TORQUE_RIGHT]
    for j in range(out.shape[0] - NSENSOR):
        out[S_EPS0 + j] = signals[SG_MOTOR_ANGLE + j]
