"""Small vector kernels over a rigid body held in natural coordinates by three orthonormal unit
vectors e1, e2, e3 (each three consecutive coordinates from its first index): the body's angular
velocity and the generalized forces of a moment on it. Shared by every assembly's force kernels."""
from __future__ import annotations

from rtsim.jit import inline_kernel


@inline_kernel
def vec3(q, k):
    return q[k], q[k + 1], q[k + 2]


@inline_kernel
def cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@inline_kernel
def angular_velocity(q, qd, ka, kb, kc):
    """omega = (e1 x e1' + e2 x e2' + e3 x e3') / 2, rad/s."""
    o0 = o1 = o2 = 0.0
    for k in (ka, kb, kc):
        c = cross(q[k], q[k + 1], q[k + 2], qd[k], qd[k + 1], qd[k + 2])
        o0 += 0.5 * c[0]
        o1 += 0.5 * c[1]
        o2 += 0.5 * c[2]
    return o0, o1, o2


@inline_kernel
def add_moment(force, q, ka, kb, kc, m0, m1, m2):
    """Generalized forces of a moment M (N m) on the body: Q_e += M x e / 2 for its three vectors."""
    for k in (ka, kb, kc):
        c = cross(m0, m1, m2, q[k], q[k + 1], q[k + 2])
        force[k] += 0.5 * c[0]
        force[k + 1] += 0.5 * c[1]
        force[k + 2] += 0.5 * c[2]
