"""The inertial measurement unit, one kit part for every vehicle: what a strapdown IMU fixed to a body reads.

    accel = R^T (a - g)      specific force, m/s^2, body axes
    gyro  = R^T omega        angular rate, rad/s, body axes

a: the absolute acceleration of the mounting point and omega: the body's angular velocity, both in
world axes; R = [x y z]: the body's unit axes in world axes (ISO 8855: x forward, y left, z up);
g: the gravity vector of the multibody model the vehicle was built with (rtsim.mbs.model.gravity,
(0, 0, -9.81) m/s^2 on level ground), so that a body at rest reads accel = (0, 0, +9.81) in level
attitude. The vehicle computes a, omega and its axes from its own coordinates; this kernel applies the
one gravity convention and the projection.
"""
from __future__ import annotations

from rtsim.jit import inline_kernel
from rtsim.mbs.model import FS_GRAVITY


@inline_kernel
def model_gravity(m):
    """The model's gravity vector as a tuple (gx, gy, gz), m/s^2, world axes."""
    return m.fset[FS_GRAVITY], m.fset[FS_GRAVITY + 1], m.fset[FS_GRAVITY + 2]


@inline_kernel
def imu_reading(acc, omega, x, y, z, g, out, k_accel, k_gyro):
    """The IMU's six channels into out: the specific force R^T (acc - g) at out[k_accel:k_accel + 3], the
    angular rate R^T omega at out[k_gyro:k_gyro + 3]. acc, omega, g and the body axes x, y, z are
    3-tuples in world axes (m/s^2, rad/s, m/s^2, unit vectors)."""
    a0, a1, a2 = acc[0] - g[0], acc[1] - g[1], acc[2] - g[2]
    out[k_accel] = a0 * x[0] + a1 * x[1] + a2 * x[2]
    out[k_accel + 1] = a0 * y[0] + a1 * y[1] + a2 * y[2]
    out[k_accel + 2] = a0 * z[0] + a1 * z[1] + a2 * z[2]
    w0, w1, w2 = omega
    out[k_gyro] = w0 * x[0] + w1 * x[1] + w2 * x[2]
    out[k_gyro + 1] = w0 * y[0] + w1 * y[1] + w2 * y[2]
    out[k_gyro + 2] = w0 * z[0] + w1 * z[1] + w2 * z[2]
