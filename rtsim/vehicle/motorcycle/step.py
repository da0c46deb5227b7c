"""The two-wheeler's applied forces inside the ALI3-P step, and the step itself.

`two_wheeler_forces` runs at every Newton iteration (tyre, suspension, steering, brake, chain and aero
forces are implicit in the step):

- tyres (slip models; knife-edge wheels are constraints instead): the toroidal contact of
  rtsim.vehicle.kit.tyre.two_wheel on the flat road z = 0, the vertical force from the penetration, the
  transient slip held by the relaxation states, the force law, and the wrench moved to the wheel centre:
  the force on the centre W, the moment on the wheel's natural coordinates (Q_e += M x e / 2 for its
  axle and in-plane vectors);
- fork: spring (table, with top-out and bottom-out) and damper (table) on the compression zeta;
- rear shock: its length follows from the swingarm angle theta and the two eyes (one on the frame, one
  on the swingarm); force F acts on theta as F dL/dtheta;
- steering: the rider's (or an ECU's) torque on the steer angle, the steering damper, the lock stops;
- brakes: torque between each wheel and its carrier (front: the fork; rear: the swingarm), a smooth
  Coulomb law of the relative spin rate;
- chain: the drive torque at the rear wheel pulls the chain's upper run (engine braking: the lower run)
  along its line between the sprockets; the force acts on the rear sprocket's tangent point (the wheel)
  and its reaction on the gearbox sprocket's centre (the frame), so squat and anti-squat follow from
  the geometry;
- aerodynamic drag and lift at the centre of pressure (a point of the frame).
"""
from __future__ import annotations

from math import sqrt, tanh

import numpy as np

from rtsim.jit import inline_kernel, kernel
from rtsim.mbs.envelope import add_entry
from rtsim.mbs.integrator import step_with

from ..kit.layout import offsets
from ..kit.rigid import add_moment, angular_velocity, cross, vec3
from ..kit.spring_damper import spring_damper_force
from ..kit.tyre.two_wheel import (advance_two_wheel_slip, contact_force_world, toroidal_contact,
                                  two_wheel_rolling_radius, two_wheel_transient_slip, two_wheel_tyre_forces,
                                  two_wheel_vertical_force, wrench_at_wheel_centre, TW_CZ, TW_KZ)
from .layout import (K_B_F, K_B_R, K_C_F, K_C_R, K_DELTA, K_E1, K_E_U, K_H, K_P, K_PHI_F, K_PHI_R, K_THETA, K_V,
                     K_W_F, K_W_R, K_ZETA)

# Scalar parameters (TwoWheelerParts.par), positions in the rear frame's axes (e1, h) from the pivot, m.
(MP_SHOCK_FX, MP_SHOCK_FZ, MP_SHOCK_SX, MP_SHOCK_SZ, MP_THETA0, MP_SHOCK_L0, MP_SHOCK_C0, MP_STEER_DAMP,
 MP_LOCK, MP_STOP_K, MP_CHAIN_CX, MP_CHAIN_CZ, MP_CHAIN_RF, MP_CHAIN_RR, MP_CDA, MP_CLA, MP_RHO, MP_CP_X,
 MP_CP_Z, MP_BRAKE_EPS, MP_SLIP_TYRES, MP_FREE_SUSPENSION, MP_MU, MP_HAS_CHAIN, MP_SPIN_F, MP_SPIN_R,
 MP_SIZE) = offsets(*(1,) * 26)
# Tables (TwoWheelerParts.tab rows): force (N, compression positive) against compression (m) and rate (m/s).
T_FORK_SPRING, T_FORK_DAMPER, T_SHOCK_SPRING, T_SHOCK_DAMPER = range(4)
# Inputs (TwoWheelerParts.u), held over a step.
U_STEER_TORQUE, U_DRIVE_TORQUE, U_BRAKE_FRONT, U_BRAKE_REAR, U_SIZE = offsets(1, 1, 1, 1)
# Per-tyre outputs (TwoWheelerParts.tyre[w, :]), w = 0 front, 1 rear.
(TO_FX, TO_FY, TO_FZ, TO_MZ, TO_KAPPA, TO_ALPHA, TO_GAMMA, TO_VX, TO_OMEGA, TO_RE, TO_VSY, TO_SIZE) = offsets(*(1,) * 11)
FRONT, REAR = 0, 1


@inline_kernel
def _frame_point_force(f, idx, x, z, f0, f1, f2):
    """Generalized forces of a force F at the frame's point P + x e1 + z h."""
    kp = idx[K_P]
    ke = idx[K_E1]
    kh = idx[K_H]
    for c, fc in ((0, f0), (1, f1), (2, f2)):
        f[kp + c] += fc
        f[ke + c] += x * fc
        f[kh + c] += z * fc


@inline_kernel
def _spin_rate(q, qd, kb, kc):
    """Absolute spin rate of a wheel about its axle a (triad b, a, c with b x a = c): omega.a = c'.b."""
    return qd[kc] * q[kb] + qd[kc + 1] * q[kb + 1] + qd[kc + 2] * q[kb + 2]


@inline_kernel
def _tyre(m, d, idx, tp, slip, tyre, w, kw, ka, kb, kc, mu, tangent, bq, hc):
    """The tyre force and moment of wheel w on its centre and its body; outputs into tyre[w]."""
    q = d.q
    qd = d.qd
    f = d.force
    p = tp[w]
    wx, wy, wz = vec3(q, kw)
    ax, ay, az = vec3(q, ka)
    px, py, pz, pen, gamma, tx, ty, tz, lx, ly, lz = toroidal_contact(p, wx, wy, wz, ax, ay, az, wx, wy, 0.0,
                                                                      0.0, 0.0, 1.0)
    if pen <= 0.0:
        for k in range(TO_SIZE):
            tyre[w, k] = 0.0
        return
    vwx, vwy, vwz = vec3(qd, kw)
    fz = two_wheel_vertical_force(p, pen, -vwz)
    # material velocity at P: W' + omega x (P - W), omega the wheel's angular velocity (1/2 sum e x e')
    o0, o1, o2 = angular_velocity(q, qd, ka, kb, kc)
    r = cross(o0, o1, o2, px - wx, py - wy, pz - wz)
    vsx = vwx + r[0]
    vsy_w = vwy + r[1]
    vx = vwx * tx + vwy * ty + vwz * tz
    vsy = vsx * lx + vsy_w * ly
    omega = o0 * ax + o1 * ay + o2 * az
    re = two_wheel_rolling_radius(p, pen, gamma)
    kappa, alpha = two_wheel_transient_slip(p, slip, w, fz, gamma, vx, vsy, omega, re)
    fx, fy, mx, my, mz = two_wheel_tyre_forces(p, fz, kappa, alpha, gamma, vx, mu)
    fwx, fwy, fwz = contact_force_world(tx, ty, tz, lx, ly, lz, 0.0, 0.0, 1.0, fx, fy, fz)
    f0, f1, f2, m0, m1, m2 = wrench_at_wheel_centre(wx, wy, wz, px, py, pz, fwx, fwy, fwz, tx, ty, tz,
                                                    ax, ay, az, 0.0, 0.0, 1.0, mx, my, mz)
    f[kw] += f0
    f[kw + 1] += f1
    f[kw + 2] += f2
    add_moment(f, q, ka, kb, kc, m0, m1, m2)
    if tangent:
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kw + 2, kw + 2, bq * p[TW_KZ] + hc * p[TW_CZ])
    t = tyre[w]
    t[TO_FX] = fx
    t[TO_FY] = fy
    t[TO_FZ] = fz
    t[TO_MZ] = mz
    t[TO_KAPPA] = kappa
    t[TO_ALPHA] = alpha
    t[TO_GAMMA] = gamma
    t[TO_VX] = vx
    t[TO_OMEGA] = omega
    t[TO_RE] = re
    t[TO_VSY] = vsy


@inline_kernel
def _shock_length(par, theta):
    """Shock length (m) and dL/dtheta at swingarm angle theta: the swingarm eye rotated about the pivot
    by theta - theta0 in the frame's (e1, h) plane, the frame eye fixed."""
    a = theta - par[MP_THETA0]
    ca = np.cos(a)
    sa = np.sin(a)
    sx = par[MP_SHOCK_SX] * ca + par[MP_SHOCK_SZ] * sa
    sz = -par[MP_SHOCK_SX] * sa + par[MP_SHOCK_SZ] * ca
    dx = par[MP_SHOCK_FX] - sx
    dz = par[MP_SHOCK_FZ] - sz
    length = sqrt(dx * dx + dz * dz)
    # d(sx, sz)/da = (sz, -sx)
    return length, -(dx * sz - dz * sx) / length


@kernel
def two_wheeler_forces(m, d, idx, par, tab, u, tp, slip, tyre, tangent, bq, hc):
    """Add the two-wheeler's applied forces to d.force (and with `tangent` their stiffness and damping to
    d.w_env, scaled by bq = h^2/4 and hc = h/2). Returns the index of a non-finite force or -1."""
    q = d.q
    qd = d.qd
    f = d.force
    # ---- suspension -------------------------------------------------------------------------------------
    if par[MP_FREE_SUSPENSION] > 0.5:
        kz = idx[K_ZETA]
        fs, ks, fd, cs = spring_damper_force(tab[T_FORK_SPRING], tab[T_FORK_DAMPER], q[kz], qd[kz])
        f[kz] -= fs + fd
        kt = idx[K_THETA]
        length, dl = _shock_length(par, q[kt])
        comp = par[MP_SHOCK_C0] + par[MP_SHOCK_L0] - length
        fs2, ks2, fd2, cs2 = spring_damper_force(tab[T_SHOCK_SPRING], tab[T_SHOCK_DAMPER], comp, -dl * qd[kt])
        f[kt] += (fs2 + fd2) * dl
        if tangent:
            add_entry(d.w_env, m.first, m.ptr, m.pinv, kz, kz, bq * ks + hc * cs)
            add_entry(d.w_env, m.first, m.ptr, m.pinv, kt, kt, (bq * ks2 + hc * cs2) * dl * dl)
    # ---- steering: input torque, damper, lock stops ------------------------------------------------------
    kd = idx[K_DELTA]
    delta = q[kd]
    stop = 0.0
    k_stop = 0.0
    if delta > par[MP_LOCK]:
        stop = -par[MP_STOP_K] * (delta - par[MP_LOCK])
        k_stop = par[MP_STOP_K]
    elif delta < -par[MP_LOCK]:
        stop = -par[MP_STOP_K] * (delta + par[MP_LOCK])
        k_stop = par[MP_STOP_K]
    f[kd] += u[U_STEER_TORQUE] - par[MP_STEER_DAMP] * qd[kd] + stop
    if tangent:
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kd, kd, bq * k_stop + hc * par[MP_STEER_DAMP])
    # ---- brakes: smooth Coulomb torque against the wheel's spin relative to its carrier ----------------------
    # The regularisation speed is the config's slip speed, but never below the change of spin rate the
    # brake's torque T can make on its wheel in one step, T h / I_spin (h = 2 hc): below it the step cannot
    # resolve the lock anyway, and with it the brake's damping T / eps stays at most I_spin / h, so Newton
    # (whose tangent holds that damping) contracts by at least 2/3 per iteration however hard the brake
    # is applied. A brake that locks its wheel within a step (full pressure at walking speed) made the
    # damping up to 30 times the wheel's inertia term and Newton ran out of iterations at the first step.
    eps = par[MP_BRAKE_EPS]
    h = 2.0 * hc
    eps_f = max(eps, u[U_BRAKE_FRONT] * h / par[MP_SPIN_F])
    eps_r = max(eps, u[U_BRAKE_REAR] * h / par[MP_SPIN_R])
    kpf = idx[K_PHI_F]
    tb = u[U_BRAKE_FRONT] * tanh(qd[kpf] / eps_f)
    f[kpf] -= tb
    kpr = idx[K_PHI_R]
    kt = idx[K_THETA]
    rel = qd[kpr] - qd[kt]
    tb = u[U_BRAKE_REAR] * tanh(rel / eps_r)
    f[kpr] -= tb
    f[kt] += tb
    if tangent:
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kpf, kpf, hc * u[U_BRAKE_FRONT] / eps_f)
        c_r = hc * u[U_BRAKE_REAR] / eps_r           # on the relative rate: the 2 x 2 block of (kpr, kt)
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kpr, kpr, c_r)
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kt, kt, c_r)
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kpr, kt, -c_r)
    # ---- chain: drive torque at the rear wheel as tension along the chain line -------------------------------
    if par[MP_HAS_CHAIN] > 0.5 and u[U_DRIVE_TORQUE] != 0.0:
        _chain(f, q, idx, par, u[U_DRIVE_TORQUE])
    # ---- aero at the centre of pressure ----------------------------------------------------------------------
    kp = idx[K_P]
    vx = qd[kp]
    vy = qd[kp + 1]
    speed = sqrt(vx * vx + vy * vy)
    half = 0.5 * par[MP_RHO] * speed
    _frame_point_force(f, idx, par[MP_CP_X], par[MP_CP_Z], -half * par[MP_CDA] * vx, -half * par[MP_CDA] * vy,
                       half * par[MP_CLA] * speed)
    # ---- tyres ---------------------------------------------------------------------------------------------
    if par[MP_SLIP_TYRES] > 0.5:
        _tyre(m, d, idx, tp, slip, tyre, FRONT, idx[K_W_F], idx[K_E_U], idx[K_B_F], idx[K_C_F], par[MP_MU],
              tangent, bq, hc)
        _tyre(m, d, idx, tp, slip, tyre, REAR, idx[K_W_R], idx[K_V], idx[K_B_R], idx[K_C_R], par[MP_MU],
              tangent, bq, hc)
    for i in range(m.nq):
        if not np.isfinite(f[i]):
            return i
    return -1


@inline_kernel
def _chain(f, q, idx, par, torque):
    """The chain run's tension T = |torque| / r_rear along the common tangent of the sprockets (upper run
    when driving, lower when braking the engine), in the frame's (e1, h) plane."""
    kp, ke, kh, kw = idx[K_P], idx[K_E1], idx[K_H], idx[K_W_R]
    # rear sprocket centre in frame coordinates
    rx = rz = 0.0
    for c in range(3):
        dc = q[kw + c] - q[kp + c]
        rx += dc * q[ke + c]
        rz += dc * q[kh + c]
    dx = par[MP_CHAIN_CX] - rx
    dz = par[MP_CHAIN_CZ] - rz
    dist = sqrt(dx * dx + dz * dz)
    ux = dx / dist
    uz = dz / dist
    side = 1.0 if torque > 0.0 else -1.0
    # unit normal n of the run (towards the run's side): n.d = r_rear - r_front
    sb = (par[MP_CHAIN_RR] - par[MP_CHAIN_RF]) / dist
    cb = sqrt(max(1.0 - sb * sb, 0.0))
    # perpendicular of d pointing "up" in the (e1, h) plane: (-uz, ux)
    nx = side * cb * (-uz) + sb * ux
    nz = side * cb * ux + sb * uz
    # tangent points and the run's direction from rear to front
    xr = rx + par[MP_CHAIN_RR] * nx
    zr = rz + par[MP_CHAIN_RR] * nz
    xf = par[MP_CHAIN_CX] + par[MP_CHAIN_RF] * nx
    zf = par[MP_CHAIN_CZ] + par[MP_CHAIN_RF] * nz
    ex = xf - xr
    ez = zf - zr
    el = sqrt(ex * ex + ez * ez)
    tension = abs(torque) / par[MP_CHAIN_RR]
    # world force on the rear sprocket: tension along the run towards the front sprocket
    w0 = w1 = w2 = 0.0
    n0 = n1 = n2 = 0.0
    for c in range(3):
        w_c = tension * (ex * q[ke + c] + ez * q[kh + c]) / el
        n_c = par[MP_CHAIN_RR] * (nx * q[ke + c] + nz * q[kh + c])
        if c == 0:
            w0, n0 = w_c, n_c
        elif c == 1:
            w1, n1 = w_c, n_c
        else:
            w2, n2 = w_c, n_c
    f[kw] += w0
    f[kw + 1] += w1
    f[kw + 2] += w2
    m0, m1, m2 = cross(n0, n1, n2, w0, w1, w2)
    add_moment(f, q, idx[K_V], idx[K_B_R], idx[K_C_R], m0, m1, m2)
    _frame_point_force(f, idx, par[MP_CHAIN_CX], par[MP_CHAIN_CZ], -w0, -w1, -w2)


@inline_kernel
def _forces_args(m, d, args, tangent, bq, hc):
    idx, par, tab, u, tp, slip, tyre = args
    return two_wheeler_forces(m, d, idx, par, tab, u, tp, slip, tyre, tangent, bq, hc)


@kernel
def two_wheeler_step(m, d, h, idx, par, tab, u, tp, slip, tyre):
    """One ALI3-P step of h seconds with the two-wheeler's forces; then the tyres' relaxation states
    advance over the step at the converged state. Returns a status code (rtsim.mbs.model.OK)."""
    status = step_with(m, d, h, _forces_args, (idx, par, tab, u, tp, slip, tyre))
    if status == 0:
        two_wheeler_after_mbs(h, par, tp, slip, tyre)
    return status


@inline_kernel
def two_wheeler_after_mbs(h, par, tp, slip, tyre):
    """After the multibody step: the slip tyres' relaxation states advance over it at the converged state."""
    if par[MP_SLIP_TYRES] < 0.5:
        return
    for w in range(2):
        t = tyre[w]
        if t[TO_FZ] > 0.0:
            advance_two_wheel_slip(tp[w], slip, w, t[TO_FZ], t[TO_GAMMA], t[TO_VX], t[TO_VSY], t[TO_OMEGA],
                                   t[TO_RE], h)
