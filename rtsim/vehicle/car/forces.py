"""The car's forces inside the ALI3-P step, as named stages.

`vehicle_forces` runs at every Newton iteration (so tyre, suspension, brake and aero forces are
implicit in the step). It is a pipeline of stages; each adds its generalized forces to d.force, with
`tangent` its stiffness (scaled by bq = h^2/4) and damping (by hc = h/2) to W, and writes its own
force record: its rows of the port-force array VehicleData.pf (rows PORT_*, rtsim.vehicle.car.layout),
the generalized forces that element puts on the coordinates. The records are written only while
the power audit is on (VehicleData.audit, the flag `rec` every stage takes; the stages' forces are
the same either way), at every evaluation (the last one of a step is at the converged state), so the
power audit (rtsim.vehicle.car.energy) is a sum over them after the step; with the audit off the
records cost nothing.

Per corner, in this order (the corners share the rack coordinate, so each corner's stages run
together and the forces add in one fixed order):

- suspension_stage: spring (with bump stop) and damper along the element, whose length is a
  polynomial of (z, s): Q_z = F dL/dz, Q_s = F dL/ds; the travel stops; anti-roll bars on the travel
  difference;
- corner_kinematics: the wheel's spin axis, the knuckle's rotation rates with z and s (the kinematic
  polynomials), its angular velocity and the wheel's absolute spin rate (no forces);
- brake_stage: brake torque on the spin coordinate with stiction (rtsim.vehicle.kit.brake);
- drive_stage: drive torque (set per step by the powertrain, on the driven axle's wheels) on the spin
  coordinate, reacting on the chassis; the driveline-compliance and bearing-drag effects;
- spin_torques: the brake's and the drive's records summed onto the spin and travel coordinates;
- tyre_stage: disc-on-road contact (rtsim.road.query.wheel_contact), vertical force from the radial
  deflection, transient-slip MF 5.2 (or linear) forces at the contact point P. The force acts on the
  wheel centre W; its moment about W, (P - W) x F + Mz n + My a, acts on the wheel: its component on
  the spin axis drives the spin coordinate, and the whole moment reaches the knuckle, i.e. the chassis
  axes (Q_e += M x e / 2 for e = u, v, w) and the travel and rack coordinates through the knuckle's
  rotation rates; the axle reactions. The tyre effects (relaxation, slip stiffness, rolling resistance)
  change this stage's tyre model.

Then for the whole car: steering_stage (column and rack: steer-by-wire or EPS), aero_stage (drag at
the centre of mass, with the aero-drag effect) and, when any effect is on, effects_stage (added mass
and road grade). Effects: parameters fx = Parts.effects, states fs = States.effects
(rtsim.vehicle.car.effect_kernels); with fx[FX_ON] = 0 none of their code runs.
"""
from __future__ import annotations

from enum import IntEnum
from math import atan, sqrt, tan

import numpy as np

from rtsim.jit import inline_kernel, kernel, stage_kernel
from rtsim.mbs.constraints import poly_eval
from rtsim.mbs.envelope import add_entry
from rtsim.road.query import CT_D, CT_EX, CT_GAMMA, CT_MU, CT_NX, CT_PX, CT_RR, wheel_contact

from .effect_kernels import (BEARING_OMEGA_EPS, FX_BEARING, FX_CDA, FX_DL, FX_G_1MCOS, FX_G_SIN, FX_GRADE,
                             FX_M_CHASSIS, FX_M_CORNER, FX_MASS, FX_ON, FX_RELAX, FX_RR, FX_SLIP, RR_SPEED_EPS,
                             driveline_torque, heading, smooth_sign)
from ..kit.brake import BP_EPS, BS_TAU_SLIDE, brake_wheel_torque
from ..kit.steering import rack_stop_tangent, steering_forces, steering_tangent
from ..kit.eps import eps_forces
from ..kit.end_stop import travel_stops
from ..kit.imu import model_gravity
from ..kit.rigid import add_moment, angular_velocity, cross, vec3
from ..kit.spring_damper import spring_damper_force
from .layout import (TYRE_LINEAR, CI_PHI, CI_S, CI_WX, CI_Z, STEER_COLUMN, STEER_EPS, STEER_RACK, PORT_AERO, PORT_ARB,
                     PORT_AXLE_REACTION, PORT_BRAKE, PORT_DAMPER, PORT_DRIVE, PORT_EFFECTS, PORT_EPS, PORT_SPRING,
                     PORT_STEER_BY_WIRE, PORT_TYRE, Susp)
from ..kit.tyre.magic_formula import (effective_rolling_radius, mf52_forces, transient_slip, transient_slip_relaxed,
                                      vertical_force)
from ..kit.tyre.linear import linear_forces
from ..kit.tyre.tir import P_UNLOADED_RADIUS, P_VERTICAL_DAMPING, P_VERTICAL_STIFFNESS



class TyreOut(IntEnum):
    """Per-tyre outputs of the last force evaluation, for logging and sensors: columns of
    VehicleData.tyre[w, :] (zeros without contact)."""
    FX = 0          # N, longitudinal force (contact frame)
    FY = 1          # N, lateral force
    FZ = 2          # N, vertical force
    MZ = 3          # N m, aligning moment
    KAPPA = 4       # longitudinal slip
    ALPHA = 5       # rad, slip angle
    PX = 6          # m, contact point (world)
    PY = 7
    PZ = 8
    VX = 9          # m/s, the wheel centre's speed along the contact's longitudinal axis
    GAMMA = 10      # rad, camber to the road
    OMEGA = 11      # rad/s, the wheel's absolute spin rate
    RE = 12         # m, effective rolling radius
    VSY = 13        # m/s, lateral slip speed at the contact point


NTO = len(TyreOut)

_vec = vec3
_cross = cross


@inline_kernel
def _body_to_world(veh, q, x0, x1, x2):
    """[u v w] x for a body-frame vector x."""
    ci = veh.chassis_idx
    return (x0 * q[ci[3]] + x1 * q[ci[6]] + x2 * q[ci[9]],
            x0 * q[ci[4]] + x1 * q[ci[7]] + x2 * q[ci[10]],
            x0 * q[ci[5]] + x1 * q[ci[8]] + x2 * q[ci[11]])


@inline_kernel
def chassis_omega(veh, q, qd):
    """Angular velocity of the chassis frame: omega = (u x u' + v x v' + w x w') / 2."""
    ci = veh.chassis_idx
    return angular_velocity(q, qd, ci[3], ci[6], ci[9])


@inline_kernel
def _add_chassis_moment(veh, q, force, m0, m1, m2):
    """Generalized forces of a moment M on the chassis frame: Q_e += M x e / 2 for e = u, v, w."""
    ci = veh.chassis_idx
    add_moment(force, q, ci[3], ci[6], ci[9], m0, m1, m2)


@inline_kernel
def _poly3x3(ca, cb, cc, exps, z, s):
    """Three body-frame 3-vector polynomials of (z, s) at once: (a0, a1, a2, b0, b1, b2, c0, c1, c2).
    Each is summed exactly as rtsim.mbs.constraints.poly_value sums it (same terms, same order, so the
    same bits); the nine independent sums in one pass keep the processor's pipelines full, where one
    polynomial at a time waits on each multiply-add."""
    nterm = exps.shape[0]
    nb = exps[nterm - 1, 1] + 1
    na = nterm // nb
    nbu = nb if s != 0.0 else 1
    p0 = p1 = p2 = p3 = p4 = p5 = p6 = p7 = p8 = 0.0
    za = 1.0
    for a in range(na):
        q0 = q1 = q2 = q3 = q4 = q5 = q6 = q7 = q8 = 0.0
        sb = 1.0
        base = a * nb
        for b in range(nbu):
            j = base + b
            q0 += ca[0, j] * sb
            q1 += ca[1, j] * sb
            q2 += ca[2, j] * sb
            q3 += cb[0, j] * sb
            q4 += cb[1, j] * sb
            q5 += cb[2, j] * sb
            q6 += cc[0, j] * sb
            q7 += cc[1, j] * sb
            q8 += cc[2, j] * sb
            sb *= s
        p0 += za * q0
        p1 += za * q1
        p2 += za * q2
        p3 += za * q3
        p4 += za * q4
        p5 += za * q5
        p6 += za * q6
        p7 += za * q7
        p8 += za * q8
        za *= z
    return p0, p1, p2, p3, p4, p5, p6, p7, p8


@inline_kernel
def _corner_travel(veh, vd, q, qd, i):
    """The corner's travel and rack coordinates: (kz, ks, z, z', s, s'); s includes the compliance steer
    held over the step, and s = s' = 0 (ks = -1) on an unsteered corner."""
    ix = veh.corner_idx[i]
    kz = ix[CI_Z]
    ks = ix[CI_S]
    s = (q[ks] + vd.steer_offset[i]) if ks >= 0 else 0.0
    sd = qd[ks] if ks >= 0 else 0.0
    return kz, ks, q[kz], qd[kz], s, sd


@inline_kernel
def suspension_stage(m, d, veh, vd, i, rec, tangent, bq, hc):
    """Corner i's spring and damper (tables: force in compression against compression from the design
    length, and against compression speed), its travel stops and its anti-roll bar. Records: PORT_SPRING,
    PORT_DAMPER (with the stops: a non-storing port), PORT_ARB."""
    q = d.q
    f = d.force
    pf = vd.pf
    kz, ks, z, zd, s, sd = _corner_travel(veh, vd, q, d.qd, i)
    sp = veh.susp[i]
    length, lz, ls, _a, _b, _c = poly_eval(veh.spring_coef[i], m.poly_exp, z, s)
    ldot = lz * zd + ls * sd
    f_spring, k_eff, f_damp, c = spring_damper_force(veh.spring_tab[i], veh.damper_tab[i], sp[Susp.L0] - length, -ldot)
    fsp = f_spring + f_damp
    f[kz] += fsp * lz
    if ks >= 0:
        f[ks] += fsp * ls
    # rebound and bump stops at the ends of the travel (a hanging wheel, a slammed one)
    f_ts, k_ts, c_ts = travel_stops(z, zd, sp[Susp.Z_LO], sp[Susp.Z_HI], sp[Susp.STOP_K], sp[Susp.STOP_C])
    if k_ts != 0.0:
        f[kz] += f_ts
        if rec:
            pf[PORT_DAMPER, kz] += f_ts
        if tangent:
            add_entry(d.w_env, m.first, m.ptr, m.pinv, kz, kz, bq * k_ts + hc * c_ts)
    # anti-roll bar on the travel difference with the other wheel of the axle
    partner = veh.corner_idx[int(sp[Susp.PARTNER]), CI_Z]
    f_arb = -sp[Susp.ARB] * (z - q[partner])
    f[kz] += f_arb
    if rec:
        pf[PORT_SPRING, kz] += f_spring * lz
        pf[PORT_DAMPER, kz] += f_damp * lz
        if ks >= 0:
            pf[PORT_SPRING, ks] += f_spring * ls
            pf[PORT_DAMPER, ks] += f_damp * ls
        pf[PORT_ARB, kz] += f_arb
    if tangent:
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kz, kz, bq * (k_eff * lz * lz + sp[Susp.ARB]) + hc * c * lz * lz)
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kz, partner, -0.5 * bq * sp[Susp.ARB])


@inline_kernel
def corner_kinematics(m, d, veh, vd, i, om):
    """Corner i's wheel: its spin axis a (unit, world), the knuckle's rotation per unit travel tz and
    per unit rack travel ts (world), the knuckle's angular velocity ok (with the chassis' om) and the
    wheel's absolute spin rate about a. Returns (ax, ay, az, tzx, tzy, tzz, tsx, tsy, tsz, okx, oky, okz,
    omega)."""
    q = d.q
    exps = m.poly_exp
    _kz, _ks, z, zd, s, sd = _corner_travel(veh, vd, q, d.qd, i)
    v = _poly3x3(veh.axis_coef[i], veh.rotz_coef[i], veh.rots_coef[i], exps, z, s)
    ax, ay, az = _body_to_world(veh, q, v[0], v[1], v[2])
    na = sqrt(ax * ax + ay * ay + az * az)
    ax /= na
    ay /= na
    az /= na
    tzx, tzy, tzz = _body_to_world(veh, q, v[3], v[4], v[5])
    tsx, tsy, tsz = _body_to_world(veh, q, v[6], v[7], v[8])
    okx = om[0] + tzx * zd + tsx * sd        # knuckle angular velocity
    oky = om[1] + tzy * zd + tsy * sd
    okz = om[2] + tzz * zd + tsz * sd
    omega = d.qd[veh.corner_idx[i, CI_PHI]] + okx * ax + oky * ay + okz * az      # absolute spin rate about a
    return ax, ay, az, tzx, tzy, tzz, tsx, tsy, tsz, okx, oky, okz, omega


@inline_kernel
def brake_stage(m, d, veh, vd, bp, bs, i, rec, tangent, bq, hc):
    """Corner i's brake torque on the spin coordinate (implicit, with stiction): VehicleData.brake_torque
    and the record PORT_BRAKE; spin_torques adds it to the force."""
    kp = veh.corner_idx[i, CI_PHI]
    w = d.qd[kp]
    tb, dtdw, dtdth = brake_wheel_torque(bp, bs, i, d.q[kp], w)
    vd.brake_torque[i] = tb
    if rec:
        vd.pf[PORT_BRAKE, kp] += tb
    if tangent:
        # Near a locked wheel the sliding law's slope is -tau_s/omega_eps inside the band and 0
        # outside: a tangent of 0 lets Newton jump across the band and back forever. Within 20 bands
        # of zero speed use the secant to the band's far edge, tau_s / (|omega| + omega_eps): Newton
        # then reaches the band in one or two iterations without jumping across it (the band's own
        # slope there, 20 times too stiff at the edge, made it crawl ~7 % an iteration towards a
        # locking wheel and run out of iterations under full brake).
        c_b = -dtdw
        w_band = bp[BP_EPS]
        if c_b == 0.0 and abs(w) < 20.0 * w_band and w_band > 0.0:
            c_b = bs[BS_TAU_SLIDE + i] / (abs(w) + w_band)
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kp, kp, -bq * dtdth + hc * c_b)
    return tb


@inline_kernel
def drive_stage(m, d, veh, vd, fx, fs, i, a_dot_tz, rec, tangent, bq, hc):
    """Corner i's drive torque on the spin coordinate, its reaction on the travel (a . tz per N m), with
    the driveline-compliance effect (the torque through the driveline's nodes) and the bearing-drag
    effect (its torque on the spin coordinate: record PORT_EFFECTS). Record PORT_DRIVE; spin_torques adds
    it to the force."""
    kp = veh.corner_idx[i, CI_PHI]
    kz = veh.corner_idx[i, CI_Z]
    pf = vd.pf
    drive = vd.drive[i]
    k_fx = 0.0         # stiffness and damping of the effects on the spin coordinate
    c_fx = 0.0
    if fx[FX_ON] > 0.5:
        if fx[FX_DL] > 0.5 and veh.drive_slot[i] >= 0:
            drive, _w, _x, k_fx, c_fx = driveline_torque(fx, fs, veh.drive_slot[i], vd.drive[i], d.q[kp], d.qd[kp],
                                                         2.0 * hc)
        if fx[FX_BEARING] != 0.0:
            sb, dsb = smooth_sign(d.qd[kp], BEARING_OMEGA_EPS)
            d.force[kp] -= fx[FX_BEARING] * sb
            c_fx += fx[FX_BEARING] * dsb
            if rec:
                pf[PORT_EFFECTS, kp] -= fx[FX_BEARING] * sb
    if rec:
        pf[PORT_DRIVE, kp] += drive
        pf[PORT_DRIVE, kz] += drive * a_dot_tz
    if tangent and (k_fx != 0.0 or c_fx != 0.0):
        add_entry(d.w_env, m.first, m.ptr, m.pinv, kp, kp, bq * k_fx + hc * c_fx)
    return drive


@inline_kernel
def spin_torques(veh, f, i, tb, drive, a_dot_tz):
    """Corner i's brake torque tb and drive torque (N m, from brake_stage and drive_stage) added to the
    force: one torque on the spin coordinate, the drive's reaction on the travel (a . tz per N m)."""
    kp = veh.corner_idx[i, CI_PHI]
    kz = veh.corner_idx[i, CI_Z]
    f[kp] += tb + drive
    f[kz] += drive * a_dot_tz


@inline_kernel
def _add_tyre_load(veh, q, f, ix, fvx, fvy, fvz, q_spin, m0, m1, m2, q_z, q_s):
    """A tyre's generalized forces into f (the force, or its record): the force F on the wheel centre,
    q_spin on the spin coordinate, its moment M about the centre on the chassis axes, q_z and q_s on the
    travel and (if steered) rack coordinates of the corner whose index row is ix."""
    kw = ix[CI_WX]
    ks = ix[CI_S]
    f[kw] += fvx
    f[kw + 1] += fvy
    f[kw + 2] += fvz
    f[ix[CI_PHI]] += q_spin
    _add_chassis_moment(veh, q, f, m0, m1, m2)
    f[ix[CI_Z]] += q_z
    if ks >= 0:
        f[ks] += q_s


@inline_kernel
def tyre_stage(m, d, veh, vd, road, tp, fx, i, kin, rec, tangent, bq, hc):
    """Corner i's tyre on the road, with the corner's kinematics `kin` (corner_kinematics): contact,
    vertical force, transient slip, MF 5.2 or linear forces; its force and moment on the wheel centre,
    the spin coordinate, the chassis and the knuckle's travel and rack coordinates; the axle reactions.
    Outputs VehicleData.tyre[i] (zeros without contact); records PORT_TYRE, PORT_AXLE_REACTION."""
    q = d.q
    qd = d.qd
    f = d.force
    pf = vd.pf
    ix = veh.corner_idx[i]
    kz = ix[CI_Z]
    kw = ix[CI_WX]
    ax, ay, az, tzx, tzy, tzz, tsx, tsy, tsz, okx, oky, okz, omega = kin
    fx_on = fx[FX_ON] > 0.5
    wx, wy, wz = _vec(q, kw)
    vwx, vwy, vwz = _vec(qd, kw)
    ct = vd.contact
    wheel_contact(road, wx, wy, wz, ax, ay, az, tp[P_UNLOADED_RADIUS], ct)
    out = vd.tyre[i]
    defl = ct[CT_D]
    if not defl > 0.0:
        for k in range(NTO):
            out[k] = 0.0
        return
    nx, ny, nz = ct[CT_NX], ct[CT_NX + 1], ct[CT_NX + 2]
    ex, ey, ez = ct[CT_EX], ct[CT_EX + 1], ct[CT_EX + 2]
    lyx, lyy, lyz = _cross(nx, ny, nz, ex, ey, ez)
    px, py, pz = ct[CT_PX] - wx, ct[CT_PX + 1] - wy, ct[CT_PX + 2] - wz     # P - W
    gamma = ct[CT_GAMMA]
    rate = -(vwx * nx + vwy * ny + vwz * nz)
    fz = vertical_force(tp, defl, rate)
    vx = vwx * ex + vwy * ey + vwz * ez
    rv = _cross(okx, oky, okz, px, py, pz)
    vsy = (vwx + rv[0]) * lyx + (vwy + rv[1]) * lyy + (vwz + rv[2]) * lyz
    re = effective_rolling_radius(tp, fz)
    if fx_on and fx[FX_RELAX] != 0.0:
        kappa, alpha = transient_slip_relaxed(tp, vd.slip, i, fz, gamma, vx, vsy, omega, re, fx[FX_RELAX])
    else:
        kappa, alpha = transient_slip(tp, vd.slip, i, fz, gamma, vx, vsy, omega, re)
    # the property file describes a left-side tyre; a right-side one is its mirror image
    # (MF-Tyre convention): Fy(alpha, gamma) -> -Fy(-alpha, -gamma), likewise Mz
    side = veh.side[i]
    kap_in = kappa
    alp_in = side * alpha
    if fx_on and fx[FX_SLIP] != 1.0:
        kap_in = fx[FX_SLIP] * kappa
        alp_in = atan(fx[FX_SLIP] * tan(alp_in))
    if veh.tyre_model[0] == TYRE_LINEAR:
        fxt, fy, mz, my = linear_forces(tp, fz, kap_in, alp_in, side * gamma, vx, ct[CT_MU])
    else:
        fxt, fy, mz, my = mf52_forces(tp, fz, kap_in, alp_in, side * gamma, vx, ct[CT_MU])
    fy *= side
    mz *= side
    rr = ct[CT_RR] * fz * re
    my -= rr if vx > 0.1 else (-rr if vx < -0.1 else rr * vx / 0.1)
    if fx_on and fx[FX_RR] != 0.0:
        sr, _d = smooth_sign(vx, RR_SPEED_EPS)
        my += fx[FX_RR] * fz * (px * nx + py * ny + pz * nz) * sr     # -c Fz r_l sat(vx)
    fvx = fxt * ex + fy * lyx + fz * nx
    fvy = fxt * ey + fy * lyy + fz * ny
    fvz = fxt * ez + fy * lyz + fz * nz
    mm = _cross(px, py, pz, fvx, fvy, fvz)
    m0 = mm[0] + mz * nx + my * ax
    m1 = mm[1] + mz * ny + my * ay
    m2 = mm[2] + mz * nz + my * az
    q_spin = m0 * ax + m1 * ay + m2 * az
    q_z = m0 * tzx + m1 * tzy + m2 * tzz
    q_s = m0 * tsx + m1 * tsy + m2 * tsz
    _add_tyre_load(veh, q, f, ix, fvx, fvy, fvz, q_spin, m0, m1, m2, q_z, q_s)
    # axle reactions (Brouilhet effects): the tyre forces' moments about the wheel centre taken by
    # the axle's swing arms, a force on the travel (positive: pulls the body down onto the wheel)
    f_ar = -fxt * veh.susp[i, Susp.BX] + side * fy * veh.susp[i, Susp.BY]
    f[kz] += f_ar
    if rec:
        _add_tyre_load(veh, q, pf[PORT_TYRE], ix, fvx, fvy, fvz, q_spin, m0, m1, m2, q_z, q_s)
        pf[PORT_AXLE_REACTION, kz] += f_ar
    out[TyreOut.FX] = fxt
    out[TyreOut.FY] = fy
    out[TyreOut.FZ] = fz
    out[TyreOut.MZ] = mz
    out[TyreOut.KAPPA] = kappa
    out[TyreOut.ALPHA] = alpha
    out[TyreOut.PX] = ct[CT_PX]
    out[TyreOut.PY] = ct[CT_PX + 1]
    out[TyreOut.PZ] = ct[CT_PX + 2]
    out[TyreOut.VX] = vx
    out[TyreOut.GAMMA] = gamma
    out[TyreOut.OMEGA] = omega
    out[TyreOut.RE] = re
    out[TyreOut.VSY] = vsy
    if tangent:
        kzt = tp[P_VERTICAL_STIFFNESS]
        czt = tp[P_VERTICAL_DAMPING]
        nvec = (nx, ny, nz)
        for a in range(3):
            for b in range(a, 3):
                val = bq * kzt * nvec[a] * nvec[b] + hc * czt * nvec[a] * nvec[b]
                add_entry(d.w_env, m.first, m.ptr, m.pinv, kw + a, kw + b, val)


@inline_kernel
def steering_stage(m, d, veh, vd, stp, sts, rec, tangent, bq, hc):
    """The steering column and rack: the EPS (rtsim.vehicle.kit.eps, its own records from PORT_EPS on)
    or steer-by-wire (rtsim.vehicle.kit.steering, one record PORT_STEER_BY_WIRE)."""
    ic = veh.steer_idx[STEER_COLUMN]
    ir = veh.steer_idx[STEER_RACK]
    pf = vd.pf
    if veh.steer_kind[0] == STEER_EPS:
        eps_forces(m, d, stp, sts, ic, ir, 2.0 * hc, tangent, bq, hc, rec, pf[PORT_EPS:])
    else:
        f = d.force
        fc0 = f[ic]
        fr0 = f[ir]
        steering_forces(stp, sts, d.q, d.qd, f, ic, ir)
        if rec:
            pf[PORT_STEER_BY_WIRE, ic] += f[ic] - fc0
            pf[PORT_STEER_BY_WIRE, ir] += f[ir] - fr0
        if tangent:
            steering_tangent(m, d.w_env, stp, ic, ir, bq, hc)
            rack_stop_tangent(m, d.w_env, stp, d.q, d.qd, ir, bq, hc)


@inline_kernel
def aero_stage(m, d, veh, vd, fx, rec, tangent, hc):
    """Aerodynamic drag at the centre of mass, -rho CdA |v| v / 2 (CdA with the aero-drag effect's
    addition). Record PORT_AERO."""
    ci = veh.chassis_idx
    f = d.force
    pf = vd.pf
    qd = d.qd
    vx, vy, vz = qd[ci[0]], qd[ci[1]], qd[ci[2]]
    speed = sqrt(vx * vx + vy * vy + vz * vz)
    cda = veh.aero[0]
    if fx[FX_ON] > 0.5:
        cda += fx[FX_CDA]
    cd = 0.5 * veh.aero[1] * cda * speed
    f[ci[0]] -= cd * vx
    f[ci[1]] -= cd * vy
    f[ci[2]] -= cd * vz
    if rec:
        pf[PORT_AERO, ci[0]] -= cd * vx
        pf[PORT_AERO, ci[1]] -= cd * vy
        pf[PORT_AERO, ci[2]] -= cd * vz
    if tangent and speed > 0.0:
        for a in range(3):
            add_entry(d.w_env, m.first, m.ptr, m.pinv, ci[a], ci[a], hc * 2.0 * cd)


@inline_kernel
def effects_stage(m, d, veh, vd, fx, rec, tangent):
    """The effects that are forces of their own (the others change the stage they act in): the mass
    effect (dm (g - r'') at the centre of mass, g the model's gravity vector, tangent dm on W: the step
    then integrates (M + dm) r'' exactly) and the road grade (m (g' - g) on every translational mass).
    Record PORT_EFFECTS."""
    ci = veh.chassis_idx
    f = d.force
    re_ = vd.pf[PORT_EFFECTS]
    dm = fx[FX_MASS]
    if dm != 0.0:
        for a in range(3):
            f[ci[a]] -= dm * d.qdd[ci[a]]
            if rec:
                re_[ci[a]] -= dm * d.qdd[ci[a]]
        g = model_gravity(m)
        for a in range(3):
            f[ci[a]] += dm * g[a]
            if rec:
                re_[ci[a]] += dm * g[a]
        if tangent:
            for a in range(3):
                add_entry(d.w_env, m.first, m.ptr, m.pinv, ci[a], ci[a], dm)
    if fx[FX_GRADE] > 0.5:
        hx, hy = heading(veh, d.q)
        gs = fx[FX_G_SIN]
        gc = fx[FX_G_1MCOS]
        for k in range(5):
            if k == 0:
                mass = fx[FX_M_CHASSIS]
                j = ci[0]
            else:
                mass = fx[FX_M_CORNER + k - 1]
                j = veh.corner_idx[k - 1, CI_WX]
            f[j] -= mass * gs * hx
            f[j + 1] -= mass * gs * hy
            f[j + 2] += mass * gc
            if rec:
                re_[j] -= mass * gs * hx
                re_[j + 1] -= mass * gs * hy
                re_[j + 2] += mass * gc


@kernel
def vehicle_forces(m, d, veh, vd, road, parts, states, tangent, bq, hc):
    """add_vehicle_forces as a function of its own, for calls outside the step's Newton iteration (the
    evaluation at a step's converged q, benchmarks, tests), so that the step compiles its body once."""
    return add_vehicle_forces(m, d, veh, vd, road, parts, states, tangent, bq, hc)


@stage_kernel
def add_vehicle_forces(m, d, veh, vd, road, parts, states, tangent, bq, hc):
    """Add the car's forces to d.force (and with `tangent` their K, C to d.w_env, scaled by bq = h^2/4
    and hc = h/2), stage by stage; while the power audit is on (vd.audit) each stage's force record goes
    to its rows of vd.pf, else vd.pf is left as it is. parts, states:
    the car's Parts and States (rtsim.vehicle.car.step). Returns the index of a non-finite generalized
    force, or -1."""
    fx = parts.effects
    f = d.force
    rec = vd.audit[0] > 0.5
    if rec:
        vd.pf[:, :] = 0.0
    om = chassis_omega(veh, d.q, d.qd)
    for i in range(4):
        suspension_stage(m, d, veh, vd, i, rec, tangent, bq, hc)
        kin = corner_kinematics(m, d, veh, vd, i, om)
        a_dot_tz = kin[0] * kin[3] + kin[1] * kin[4] + kin[2] * kin[5]
        tb = brake_stage(m, d, veh, vd, parts.brake, states.brake, i, rec, tangent, bq, hc)
        drive = drive_stage(m, d, veh, vd, fx, states.effects, i, a_dot_tz, rec, tangent, bq, hc)
        spin_torques(veh, f, i, tb, drive, a_dot_tz)
        tyre_stage(m, d, veh, vd, road, parts.tyre, fx, i, kin, rec, tangent, bq, hc)
    steering_stage(m, d, veh, vd, parts.steering, states.steering, rec, tangent, bq, hc)
    aero_stage(m, d, veh, vd, fx, rec, tangent, hc)
    if fx[FX_ON] > 0.5:
        effects_stage(m, d, veh, vd, fx, rec, tangent)
    for i in range(m.nq):
        if not np.isfinite(f[i]):
            return i
    return -1
