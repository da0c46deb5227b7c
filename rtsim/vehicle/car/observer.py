"""The observer state of the vehicle (rtsim.channels.STATE, SI units) from the multibody state and the
subsystem outputs, in one compiled call with no allocation (the service publishes it at 100 Hz).

Attitude as Euler z-y-x angles of the chassis frame R = [u v w] (ISO 8855 signs, as the inclinometer
channels): yaw = atan2(u_y, u_x), pitch = asin(-u_z) (nose down positive), roll = atan2(v_z, w_z)
(right side down positive). Velocities and rates in body axes: v_body = R^T r', omega_body = R^T omega
with omega = (u x u' + v x v' + w x w') / 2.
"""
from __future__ import annotations

from math import asin, atan2, sqrt

from rtsim.channels import STATE_NAMES, WHEELS
from rtsim.jit import kernel

from .inputs import DriverView
from .step import TyreOut
from .layout import CI_PHI, STEER_RACK
from .sensors import SG_BRAKE_PRESSURE, SG_ENGINE_SPEED, SG_SW_ANGLE, SG_THROTTLE

NSTATE_OUT = len(STATE_NAMES)
# offsets of the state channels, from the channel dictionary's names (blocks of 4 follow the wheel order)
X_POS, X_ATT, X_VEL, X_RATE, X_SPEED = (STATE_NAMES.index(n) for n in ("pos_x", "roll_angle", "vel_x", "roll_rate",
                                                                         "speed"))
X_WHEEL = STATE_NAMES.index("wheel_speed_fl")          # 7 blocks of 4 wheels follow
X_THROTTLE, X_BRAKE, X_SW_ANGLE, X_RACK, X_ENGINE, X_PHI = (STATE_NAMES.index(n) for n in (
    "throttle_angle", "brake_pressure", "steering_wheel_angle", "rack_position", "engine_speed",
    "constraint_violation"))
assert STATE_NAMES[X_WHEEL + 6 * 4:X_WHEEL + 7 * 4] == tuple(f"brake_torque_{w}" for w in WHEELS)
assert NSTATE_OUT == X_PHI + 1 and len(WHEELS) == 4


@kernel
def driver_view(d, veh, out):
    """What the closed-loop drivers read (rtsim.vehicle.car.inputs DriverView: speed m/s along the heading, x, y m
    and yaw rad of the centre of mass) into out[0:4]."""
    q, qd = d.q, d.qd
    ci = veh.chassis_idx
    ux, uy = q[ci[3]], q[ci[4]]
    out[DriverView.X] = q[ci[0]]
    out[DriverView.Y] = q[ci[1]]
    out[DriverView.YAW] = atan2(uy, ux)
    out[DriverView.SPEED] = ((qd[ci[0]] * ux + qd[ci[1]] * uy + qd[ci[2]] * q[ci[5]])
                             / max(1e-12, sqrt(ux * ux + uy * uy)))


@kernel
def vehicle_state_values(d, veh, vd, signals, out):
    """STATE_NAMES values of the current state into out[0:NSTATE_OUT]."""
    q, qd = d.q, d.qd
    ci = veh.chassis_idx
    ux, uy, uz = q[ci[3]], q[ci[4]], q[ci[5]]
    vx, vy, vz = q[ci[6]], q[ci[7]], q[ci[8]]
    wx, wy, wz = q[ci[9]], q[ci[10]], q[ci[11]]
    for k in range(3):
        out[X_POS + k] = q[ci[k]]
    out[X_ATT] = atan2(vz, wz)
    out[X_ATT + 1] = asin(min(1.0, max(-1.0, -uz)))
    out[X_ATT + 2] = atan2(uy, ux)
    r0, r1, r2 = qd[ci[0]], qd[ci[1]], qd[ci[2]]
    out[X_VEL] = r0 * ux + r1 * uy + r2 * uz
    out[X_VEL + 1] = r0 * vx + r1 * vy + r2 * vz
    out[X_VEL + 2] = r0 * wx + r1 * wy + r2 * wz
    om0 = om1 = om2 = 0.0
    for k in (3, 6, 9):
        e0, e1, e2 = q[ci[k]], q[ci[k + 1]], q[ci[k + 2]]
        d0, d1, d2 = qd[ci[k]], qd[ci[k + 1]], qd[ci[k + 2]]
        om0 += 0.5 * (e1 * d2 - e2 * d1)
        om1 += 0.5 * (e2 * d0 - e0 * d2)
        om2 += 0.5 * (e0 * d1 - e1 * d0)
    out[X_RATE] = om0 * ux + om1 * uy + om2 * uz
    out[X_RATE + 1] = om0 * vx + om1 * vy + om2 * vz
    out[X_RATE + 2] = om0 * wx + om1 * wy + om2 * wz
    out[X_SPEED] = sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    for i in range(4):
        out[X_WHEEL + i] = qd[veh.corner_idx[i, CI_PHI]]
        out[X_WHEEL + 4 + i] = vd.tyre[i, TyreOut.FX]
        out[X_WHEEL + 8 + i] = vd.tyre[i, TyreOut.FY]
        out[X_WHEEL + 12 + i] = vd.tyre[i, TyreOut.FZ]
        out[X_WHEEL + 16 + i] = vd.tyre[i, TyreOut.KAPPA]
        out[X_WHEEL + 20 + i] = vd.tyre[i, TyreOut.ALPHA]
        out[X_WHEEL + 24 + i] = vd.brake_torque[i]
    out[X_THROTTLE] = signals[SG_THROTTLE]
    out[X_BRAKE] = signals[SG_BRAKE_PRESSURE]
    out[X_SW_ANGLE] = signals[SG_SW_ANGLE]
    out[X_RACK] = q[veh.steer_idx[STEER_RACK]]
    out[X_ENGINE] = signals[SG_ENGINE_SPEED]
    worst = 0.0
    for k in range(d.phi.shape[0]):
        a = abs(d.phi[k])
        if a > worst:
            worst = a
    out[X_PHI] = worst
