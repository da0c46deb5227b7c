"""The vehicle's forces inside the ALI3-P step, and the vehicle step itself.

`vehicle_forces` runs at every Newton iteration (so tyre, suspension, brake and aero forces are
implicit in the step) and adds to the generalized forces and, when the iteration refactors, their
stiffness and damping to W:

- tyres: disc-on-road contact (rtsim.road.query.wheel_contact), vertical force from the radial
  deflection, transient-slip MF 5.2 (or linear) forces at the contact point P. The force acts on the
  wheel centre W; its moment about W, (P - W) x F + Mz n + My a, acts on the wheel: its component on
  the spin axis drives the spin coordinate, and the whole moment reaches the knuckle, i.e. the chassis
  axes (Q_e += M x e / 2 for e = u, v, w) and the travel and rack coordinates through the knuckle's
  rotation rates with z and s (the kinematic polynomials);
- suspension spring (with bump stop) and damper along the element, whose length is a polynomial of
  (z, s): Q_z = F dL/dz, Q_s = F dL/ds; anti-roll bars on the travel difference;
- brakes: torque on the spin coordinate with stiction (rtsim.vehicle.kit.brake), reaction on the knuckle;
- drive torques (set per step by the powertrain, on the driven axle's wheels) on the spin coordinate,
  reacting on the chassis;
- aerodynamic drag at the centre of mass;
- the switchable effects of rtsim.vehicle.car.effects when any is on (parameters fx = Parts.effects, states
  fs = States.effects; with fx[FX_ON] = 0 none of their code runs and the step is the nominal one).
"""
from __future__ import annotations

from collections import namedtuple
from math import atan, sqrt, tan

import numpy as np

from rtsim.jit import inline_kernel, kernel
from rtsim.mbs.constraints import poly_eval, poly_value
from rtsim.mbs.envelope import add_entry
from rtsim.mbs.integrator import step_with
from rtsim.mbs.model import OK
from rtsim.road.query import CT_D, CT_EX, CT_GAMMA, CT_MU, CT_NX, CT_PX, CT_RR, NCONTACT, wheel_contact

from .effect_kernels import (BEARING_OMEGA_EPS, FS_DL, FX_BEARING, FX_BRAKE, FX_CDA, FX_DL,
                             FX_G_1MCOS, FX_G_SIN, FX_GRADE, FX_M_CHASSIS, FX_M_CORNER, FX_MASS, FX_ON,
                             FX_RELAX, FX_RR, FX_SLIP, RR_SPEED_EPS, driveline_commit, driveline_torque,
                             effects_brake, heading, record_sensors, smooth_sign)
from ..kit.brake import BI_SIZE, BO_LINE, BO_SIZE, BP_EPS, BS_TAU_SLIDE, brake_commit, brake_step, brake_wheel_torque
from ..kit.powertrain import (PI_OMEGA_LEFT, PI_OMEGA_RIGHT, PI_SELECTOR, PI_SIZE, PI_THROTTLE_CMD, PI_TORQUE_LEFT, PI_TORQUE_RIGHT,
                         PO_ENGINE_SPEED, PO_SIZE, PO_THROTTLE, PO_TORQUE_LEFT, PO_TORQUE_RIGHT, powertrain_step)
from .sensors import (NSIGNAL, SG_BRAKE_PRESSURE, SG_ENGINE_SPEED, SG_MOTOR_ANGLE, SG_MOTOR_CURRENT,
                      SG_MOTOR_SPEED, SG_POWER_STAGE, SG_STEERING_TORQUE, SG_SW_ANGLE, SG_THROTTLE, SG_TORQUE_LEFT,
                      SG_TORQUE_RIGHT, SG_VEHICLE_SPEED)
from ..kit.sensor_model import ST_SLOTS as SM_ST_SLOTS
from ..kit.steering import SO_SIZE, SO_SW_ANGLE, SO_TORQUE, rack_stop_tangent, steering_control, steering_forces, \
    steering_outputs, steering_tangent
from ..kit.eps import (EO_CURRENT, EO_MOTOR_ANGLE, EO_MOTOR_SPEED, EO_SIZE, EO_SW_ANGLE, EO_TB_TORQUE, EP_DRIVER,
                       EP_K_TB, EP_N, EP_RP, ES_EXT, ES_STAGE, ES_T_DRIVER, DRIVER_TORQUE, eps_commit, eps_control,
                       eps_forces, eps_outputs, external_command, hands_step)
from ..kit.end_stop import travel_stops
from ..kit.rigid import add_moment, angular_velocity, cross, vec3
from ..kit.tables import table_eval
from .energy_kernels import audit_commit
from .layout import (
    G, TYRE_LINEAR, CI_PHI, CI_S, CI_WX, CI_Z, STEER_COLUMN, STEER_EPS, STEER_RACK, SP_ARB, SP_BX, SP_BY, SP_CFY,
    SP_CMZ, SP_L0, SP_PARTNER, SP_STOP_C, SP_STOP_K, SP_Z_HI, SP_Z_LO, PORT_AERO, PORT_ARB, PORT_AXLE_REACTION, PORT_BRAKE, PORT_DAMPER, PORT_DRIVE,
    PORT_EFFECTS, PORT_EPS, PORT_SPRING, PORT_STEER_BY_WIRE, PORT_TYRE, NPORT,
)
from ..kit.tyre.magic_formula import (advance_deflections, advance_deflections_relaxed, effective_rolling_radius,
                                 mf52_forces, transient_slip, transient_slip_relaxed, vertical_force)
from ..kit.tyre.linear import linear_forces
from ..kit.tyre.tir import P_UNLOADED_RADIUS, P_VERTICAL_DAMPING, P_VERTICAL_STIFFNESS

# Per-tyre outputs (VehicleData.tyre[w, :]) for logging and sensors.
TO_FX, TO_FY, TO_FZ, TO_MZ, TO_KAPPA, TO_ALPHA, TO_PX, TO_PY, TO_PZ, TO_VX, TO_GAMMA, TO_OMEGA, TO_RE, \
    TO_VSY = range(14)
NTO = 14

VehicleData = namedtuple("VehicleData", [
    "slip",        # (4, 2) tyre contact deflections (transient slip states), m
    "drive",       # (4,) drive torques on the wheels, N m (set per step)
    "tyre",        # (4, NTO) tyre outputs of the last force evaluation
    "contact",     # (NCONTACT,) scratch of the contact query
    "brake_torque",  # (4,) brake torque of the last evaluation, N m
    "theta", "omega",  # (4,) wheel spin angles and rates handed to the brake commit
    "brake_in", "brake_out",  # brake kernel input (BI_SIZE) and outputs (BO_SIZE)
    "steer_offset",  # (4,) rad, compliance steer of each knuckle, held over the step (from the tyre forces)
    "audit",       # (1,) 1: the force evaluations at a refactored tangent also fill pf (energy audit)
    "pf",          # (NPORT, nq) generalized forces per port of the last tangent evaluation
    "pf_prev", "q_prev", "qc", "qc_prev",   # the audit's values at the previous step's end (energy.py)
    "audit_e",     # (A_SIZE,) the audit's cumulative energies (rtsim.vehicle.car.energy)
    "e_base",      # (3,) the EPS's electrical energies when the audit started
])
AUDIT_SIZE = 64    # >= rtsim.vehicle.car.energy.A_SIZE (checked there)


def make_vehicle_data(nq: int = 1) -> VehicleData:
    return VehicleData(slip=np.zeros((4, 2)), drive=np.zeros(4), tyre=np.zeros((4, NTO)),
                       contact=np.zeros(NCONTACT), brake_torque=np.zeros(4), theta=np.zeros(4),
                       omega=np.zeros(4), brake_in=np.zeros(BI_SIZE), brake_out=np.zeros(BO_SIZE),
                       steer_offset=np.zeros(4), audit=np.zeros(1), pf=np.zeros((NPORT, nq)),
                       pf_prev=np.zeros((NPORT, nq)), q_prev=np.zeros(nq), qc=np.zeros((2, nq)),
                       qc_prev=np.zeros((2, nq)), audit_e=np.zeros(AUDIT_SIZE), e_base=np.zeros(3))


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
def _poly3(coef, exps, z, s):
    """A body-frame 3-vector polynomial: (v0, v1, v2)."""
    return poly_value(coef[0], exps, z, s), poly_value(coef[1], exps, z, s), poly_value(coef[2], exps, z, s)


@kernel
def vehicle_forces(m, d, veh, vd, road, tp, bp, bs, stp, sts, fx, fs, tangent, bq, hc):
    """Add the vehicle's forces to d.force (and with `tangent` their K, C to d.w_env, scaled by
    bq = h^2/4 and hc = h/2): tyres, suspensions, brakes (parameters bp, state bs), drive torques, the
    steering (parameters stp, state sts), aero, and the effects of fx, fs (rtsim.vehicle.car.effect_kernels). Returns the
    index of a non-finite generalized force, or -1."""
    q = d.q
    qd = d.qd
    f = d.force
    exps = m.poly_exp
    om = chassis_omega(veh, q, qd)
    r0 = tp[P_UNLOADED_RADIUS]
    fx_on = fx[FX_ON] > 0.5
    pf = vd.pf
    audit = tangent and vd.audit[0] > 0.5
    if audit:
        pf[:, :] = 0.0
    for i in range(4):
        ix = veh.corner_idx[i]
        kz = ix[CI_Z]
        ks = ix[CI_S]
        kp = ix[CI_PHI]
        kw = ix[CI_WX]
        z = q[kz]
        zd = qd[kz]
        s = (q[ks] + vd.steer_offset[i]) if ks >= 0 else 0.0
        sd = qd[ks] if ks >= 0 else 0.0
        # ---- suspension spring and damper (tables: force in compression against compression from
        # the design length, and against compression speed) ----------------------------------------
        sp = veh.susp[i]
        length, lz, ls, _a, _b, _c = poly_eval(veh.spring_coef[i], exps, z, s)
        ldot = lz * zd + ls * sd
        f_spring, k_eff = table_eval(veh.spring_tab[i], sp[SP_L0] - length)
        f_damp, c = table_eval(veh.damper_tab[i], -ldot)
        fsp = f_spring + f_damp
        f[kz] += fsp * lz
        if ks >= 0:
            f[ks] += fsp * ls
        # rebound and bump stops at the ends of the travel (a hanging wheel, a slammed one); their work
        # is booked with the dampers' (a non-storing port)
        f_ts, k_ts, c_ts = travel_stops(z, zd, sp[SP_Z_LO], sp[SP_Z_HI], sp[SP_STOP_K], sp[SP_STOP_C])
        if k_ts != 0.0:
            f[kz] += f_ts
            if audit:
                pf[PORT_DAMPER, kz] += f_ts
            if tangent:
                add_entry(d.w_env, m.first, m.ptr, m.pinv, kz, kz, bq * k_ts + hc * c_ts)
        # anti-roll bar on the travel difference with the other wheel of the axle
        partner = veh.corner_idx[int(sp[SP_PARTNER]), CI_Z]
        f_arb = -sp[SP_ARB] * (z - q[partner])
        f[kz] += f_arb
        if audit:
            pf[PORT_SPRING, kz] += f_spring * lz
            pf[PORT_DAMPER, kz] += f_damp * lz
            if ks >= 0:
                pf[PORT_SPRING, ks] += f_spring * ls
                pf[PORT_DAMPER, ks] += f_damp * ls
            pf[PORT_ARB, kz] += f_arb
        if tangent:
            add_entry(d.w_env, m.first, m.ptr, m.pinv, kz, kz, bq * (k_eff * lz * lz + sp[SP_ARB]) + hc * c * lz * lz)
            add_entry(d.w_env, m.first, m.ptr, m.pinv, kz, partner, -0.5 * bq * sp[SP_ARB])
        # ---- kinematics of the corner ----------------------------------------------------------------
        ab = _poly3(veh.axis_coef[i], exps, z, s)
        ax, ay, az = _body_to_world(veh, q, ab[0], ab[1], ab[2])
        na = sqrt(ax * ax + ay * ay + az * az)
        ax /= na
        ay /= na
        az /= na
        tz = _poly3(veh.rotz_coef[i], exps, z, s)
        tzx, tzy, tzz = _body_to_world(veh, q, tz[0], tz[1], tz[2])
        ts = _poly3(veh.rots_coef[i], exps, z, s)
        tsx, tsy, tsz = _body_to_world(veh, q, ts[0], ts[1], ts[2])
        okx = om[0] + tzx * zd + tsx * sd        # knuckle angular velocity
        oky = om[1] + tzy * zd + tsy * sd
        okz = om[2] + tzz * zd + tsz * sd
        wx, wy, wz = _vec(q, kw)
        vwx, vwy, vwz = _vec(qd, kw)
        omega = qd[kp] + okx * ax + oky * ay + okz * az      # absolute spin rate about a
        # ---- brake (implicit, with stiction) and drive torques on the spin coordinate --------------
        tb, dtdw, dtdth = brake_wheel_torque(bp, bs, i, q[kp], qd[kp])
        vd.brake_torque[i] = tb
        drive = vd.drive[i]
        k_fx = 0.0         # stiffness and damping of the effects on the spin coordinate
        c_fx = 0.0
        if fx_on:
            if fx[FX_DL] > 0.5 and veh.drive_slot[i] >= 0:
                drive, _w, _x, k_fx, c_fx = driveline_torque(fx, fs, veh.drive_slot[i], vd.drive[i], q[kp], qd[kp],
                                                             2.0 * hc)
            if fx[FX_BEARING] != 0.0:
                sb, dsb = smooth_sign(qd[kp], BEARING_OMEGA_EPS)
                f[kp] -= fx[FX_BEARING] * sb
                c_fx += fx[FX_BEARING] * dsb
                if audit:
                    pf[PORT_EFFECTS, kp] -= fx[FX_BEARING] * sb
        f[kp] += tb + drive
        f[kz] += drive * (ax * tzx + ay * tzy + az * tzz)
        if audit:
            pf[PORT_BRAKE, kp] += tb
            pf[PORT_DRIVE, kp] += drive
            pf[PORT_DRIVE, kz] += drive * (ax * tzx + ay * tzy + az * tzz)
        if tangent:
            # Near a locked wheel the sliding law's slope is -tau_s/omega_eps inside the band and 0
            # outside: a tangent of 0 lets Newton jump across the band and back forever. Within 20 bands
            # of zero speed use the secant to the band's far edge, tau_s / (|omega| + omega_eps): Newton
            # then reaches the band in one or two iterations without jumping across it (the band's own
            # slope there, 20 times too stiff at the edge, made it crawl ~7 % an iteration towards a
            # locking wheel and run out of iterations under full brake).
            c_b = -dtdw
            w_band = bp[BP_EPS]
            if c_b == 0.0 and abs(qd[kp]) < 20.0 * w_band and w_band > 0.0:
                c_b = bs[BS_TAU_SLIDE + i] / (abs(qd[kp]) + w_band)
            add_entry(d.w_env, m.first, m.ptr, m.pinv, kp, kp, -bq * dtdth + hc * c_b)
            if k_fx != 0.0 or c_fx != 0.0:
                add_entry(d.w_env, m.first, m.ptr, m.pinv, kp, kp, bq * k_fx + hc * c_fx)
        # ---- tyre --------------------------------------------------------------------------------
        ct = vd.contact
        wheel_contact(road, wx, wy, wz, ax, ay, az, r0, ct)
        out = vd.tyre[i]
        defl = ct[CT_D]
        if not defl > 0.0:
            for k in range(NTO):
                out[k] = 0.0
            continue
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
        f[kw] += fvx
        f[kw + 1] += fvy
        f[kw + 2] += fvz
        mm = _cross(px, py, pz, fvx, fvy, fvz)
        m0 = mm[0] + mz * nx + my * ax
        m1 = mm[1] + mz * ny + my * ay
        m2 = mm[2] + mz * nz + my * az
        f[kp] += m0 * ax + m1 * ay + m2 * az
        _add_chassis_moment(veh, q, f, m0, m1, m2)
        f[kz] += m0 * tzx + m1 * tzy + m2 * tzz
        if ks >= 0:
            f[ks] += m0 * tsx + m1 * tsy + m2 * tsz
        # axle reactions (Brouilhet effects): the tyre forces' moments about the wheel centre taken by
        # the axle's swing arms, a force on the travel (positive: pulls the body down onto the wheel)
        f_ar = -fxt * sp[SP_BX] + side * fy * sp[SP_BY]
        f[kz] += f_ar
        if audit:
            pf[PORT_TYRE, kw] += fvx
            pf[PORT_TYRE, kw + 1] += fvy
            pf[PORT_TYRE, kw + 2] += fvz
            pf[PORT_TYRE, kp] += m0 * ax + m1 * ay + m2 * az
            _add_chassis_moment(veh, q, pf[PORT_TYRE], m0, m1, m2)
            pf[PORT_TYRE, kz] += m0 * tzx + m1 * tzy + m2 * tzz
            if ks >= 0:
                pf[PORT_TYRE, ks] += m0 * tsx + m1 * tsy + m2 * tsz
            pf[PORT_AXLE_REACTION, kz] += f_ar
        out[TO_FX] = fxt
        out[TO_FY] = fy
        out[TO_FZ] = fz
        out[TO_MZ] = mz
        out[TO_KAPPA] = kappa
        out[TO_ALPHA] = alpha
        out[TO_PX] = ct[CT_PX]
        out[TO_PY] = ct[CT_PX + 1]
        out[TO_PZ] = ct[CT_PX + 2]
        out[TO_VX] = vx
        out[TO_GAMMA] = gamma
        out[TO_OMEGA] = omega
        out[TO_RE] = re
        out[TO_VSY] = vsy
        if tangent:
            kzt = tp[P_VERTICAL_STIFFNESS]
            czt = tp[P_VERTICAL_DAMPING]
            nvec = (nx, ny, nz)
            for a in range(3):
                for b in range(a, 3):
                    val = bq * kzt * nvec[a] * nvec[b] + hc * czt * nvec[a] * nvec[b]
                    add_entry(d.w_env, m.first, m.ptr, m.pinv, kw + a, kw + b, val)
    # ---- steering column and rack --------------------------------------------------------------
    ic = veh.steer_idx[STEER_COLUMN]
    ir = veh.steer_idx[STEER_RACK]
    if veh.steer_kind[0] == STEER_EPS:
        eps_forces(m, d, stp, sts, ic, ir, 2.0 * hc, tangent, bq, hc, pf[PORT_EPS:], audit)
    else:
        if audit:
            fc0 = f[ic]
            fr0 = f[ir]
        steering_forces(stp, sts, q, qd, f, ic, ir)
        if audit:
            pf[PORT_STEER_BY_WIRE, ic] += f[ic] - fc0
            pf[PORT_STEER_BY_WIRE, ir] += f[ir] - fr0
        if tangent:
            steering_tangent(m, d.w_env, stp, ic, ir, bq, hc)
            rack_stop_tangent(m, d.w_env, stp, q, qd, ir, bq, hc)
    # ---- aerodynamic drag at the centre of mass -------------------------------------------------
    ci = veh.chassis_idx
    vx, vy, vz = qd[ci[0]], qd[ci[1]], qd[ci[2]]
    speed = sqrt(vx * vx + vy * vy + vz * vz)
    cda = veh.aero[0]
    if fx_on:
        cda += fx[FX_CDA]
    cd = 0.5 * veh.aero[1] * cda * speed
    f[ci[0]] -= cd * vx
    f[ci[1]] -= cd * vy
    f[ci[2]] -= cd * vz
    if audit:
        pf[PORT_AERO, ci[0]] -= cd * vx
        pf[PORT_AERO, ci[1]] -= cd * vy
        pf[PORT_AERO, ci[2]] -= cd * vz
    if tangent and speed > 0.0:
        for a in range(3):
            add_entry(d.w_env, m.first, m.ptr, m.pinv, ci[a], ci[a], hc * 2.0 * cd)
    if fx_on:
        if audit:
            for k in range(m.nq):
                pf[PORT_EFFECTS, k] -= f[k]
        _mass_and_grade(m, d, veh, fx, tangent)
        if audit:
            for k in range(m.nq):
                pf[PORT_EFFECTS, k] += f[k]
    for i in range(m.nq):
        if not np.isfinite(f[i]):
            return i
    return -1


@inline_kernel
def _mass_and_grade(m, d, veh, fx, tangent):
    """The mass effect (-dm r'' - dm g e_z at the centre of mass, tangent dm on W: the step then
    integrates (M + dm) r'' exactly) and the road grade (m (g' - g) on every translational mass)."""
    ci = veh.chassis_idx
    f = d.force
    dm = fx[FX_MASS]
    if dm != 0.0:
        for a in range(3):
            f[ci[a]] -= dm * d.qdd[ci[a]]
        f[ci[2]] -= dm * G
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


@inline_kernel
def _car_forces(m, d, a, tangent, bq, hc):
    return vehicle_forces(m, d, a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], a[9], tangent, bq, hc)


@kernel
def vehicle_mbs_step(m, d, veh, vd, road, tp, bp, bs, stp, sts, fx, fs, h):
    """One ALI3-P step of the vehicle: the multibody stages with the vehicle's forces added."""
    return step_with(m, d, h, _car_forces, (veh, vd, road, tp, bp, bs, stp, sts, fx, fs))


# parameter arrays; effects: rtsim.vehicle.car.effect_kernels FX_* (neutral_params() for the nominal model);
# sensors: the sensor model's (rtsim.vehicle.kit.sensor_model, (channels, NSM))
Parts = namedtuple("Parts", ["tyre", "brake", "powertrain", "steering", "effects", "sensors"])
# subsystem state arrays; effects: FS_* (brake lag, driveline nodes); sensors: the sensor model's history
States = namedtuple("States", ["brake", "powertrain", "steering", "effects", "sensors"])
IO = namedtuple("IO", [
    "commands",     # (NCMD,) CMD_*: throttle rad, brake kPa, steering-wheel angle rad, EPS current A, invalid
    "extra",        # (4,) measured drive torque on the driven axle's left, right wheel (N m), selector
                    # (+1 D, 0 N, -1 R), spare
    "pt_in", "pt_out",
    "st_out",       # (SO_SIZE,) steering outputs after the step (rtsim.vehicle.kit.steering SO_*)
    "eps_out",      # (EO_SIZE,) EPS outputs after the step (rtsim.vehicle.kit.eps EO_*)
    "signals",      # (NSIGNAL,) subsystem values handed to the sensors
])
# the vehicle's command slots; the last two: an external EPS controller's current (A) and 1.0 while it
# has no valid command (none yet, or timed out); COMMAND_SLOTS: where each command channel goes
CMD_THROTTLE, CMD_BRAKE, CMD_STEER, CMD_MOTOR_CURRENT, CMD_MOTOR_INVALID = range(5)
NCMD = 5
COMMAND_SLOTS = {"throttle_angle_cmd": CMD_THROTTLE, "brake_pressure_cmd": CMD_BRAKE,
                 "steering_wheel_angle_cmd": CMD_STEER, "motor_current_cmd": CMD_MOTOR_CURRENT}
INVALID_SLOTS = {"motor_current_cmd": CMD_MOTOR_INVALID}
EX_TORQUE_LEFT, EX_TORQUE_RIGHT, EX_SELECTOR, EX_SW_TORQUE = 0, 1, 2, 3   # EX_SW_TORQUE: N m, EPS torque mode


def make_io() -> IO:
    return IO(commands=np.zeros(NCMD), extra=np.array([0.0, 0.0, 1.0, 0.0]), pt_in=np.zeros(PI_SIZE),
              pt_out=np.zeros(PO_SIZE), st_out=np.zeros(SO_SIZE), eps_out=np.zeros(EO_SIZE),
              signals=np.zeros(NSIGNAL))


@kernel
def vehicle_step(m, d, veh, vd, road, parts, states, io, h):
    """A full vehicle step at fixed step h:
    1. subsystems to t + h from the commands: brake pressure (actuator), steer-by-wire controller and
       motor (the column torque held over the step), powertrain (drive torques from the current wheel
       speeds);
    2. the multibody step with tyre, suspension, steering, brake, drive and aero forces implicit;
    3. between-step commits: brake stick/slide modes, tyre contact deflections; signals for sensors.
    Effects (parts.effects) act in 1 (brake torques, driveline speeds), 2 and 3 (driveline nodes,
    relaxation, sensor history)."""
    fx = parts.effects
    fs = states.effects
    fx_on = fx[FX_ON] > 0.5
    vd.brake_in[0] = io.commands[CMD_BRAKE]
    brake_step(parts.brake, states.brake, vd.brake_in, h, vd.brake_out)
    if fx_on and fx[FX_BRAKE] > 0.5:
        effects_brake(fx, fs, parts.brake, states.brake, vd.brake_out)
    ic = veh.steer_idx[STEER_COLUMN]
    ir = veh.steer_idx[STEER_RACK]
    eps = veh.steer_kind[0] == STEER_EPS
    if eps:
        _eps_before_step(m, d, veh, parts.steering, states.steering, io, h, ic, ir)
    else:
        steering_control(parts.steering, states.steering, io.commands[CMD_STEER], d.q[ic], d.qd[ic], h)
    io.pt_in[PI_THROTTLE_CMD] = io.commands[CMD_THROTTLE]
    if fx_on and fx[FX_DL] > 0.5:       # the gearbox turns with the driveline nodes
        io.pt_in[PI_OMEGA_LEFT] = fs[FS_DL + 1]
        io.pt_in[PI_OMEGA_RIGHT] = fs[FS_DL + 4]
    else:
        io.pt_in[PI_OMEGA_LEFT] = d.qd[veh.corner_idx[veh.driven[0], CI_PHI]]
        io.pt_in[PI_OMEGA_RIGHT] = d.qd[veh.corner_idx[veh.driven[1], CI_PHI]]
    io.pt_in[PI_TORQUE_LEFT] = io.extra[EX_TORQUE_LEFT]
    io.pt_in[PI_TORQUE_RIGHT] = io.extra[EX_TORQUE_RIGHT]
    io.pt_in[PI_SELECTOR] = io.extra[EX_SELECTOR]
    powertrain_step(parts.powertrain, states.powertrain, io.pt_in, h, io.pt_out)
    vd.drive[veh.driven[0]] = io.pt_out[PO_TORQUE_LEFT]
    vd.drive[veh.driven[1]] = io.pt_out[PO_TORQUE_RIGHT]
    status = vehicle_mbs_step(m, d, veh, vd, road, parts.tyre, parts.brake, states.brake, parts.steering,
                              states.steering, fx, fs, h)
    if status != OK:
        return status
    for i in range(4):
        kp = veh.corner_idx[i, CI_PHI]
        vd.theta[i] = d.q[kp]
        vd.omega[i] = d.qd[kp]
    brake_commit(parts.brake, states.brake, vd.theta, vd.omega)
    if fx_on and fx[FX_DL] > 0.5:
        driveline_commit(fx, fs, d, veh, vd.drive, h)
    relax = fx[FX_RELAX] if fx_on else 0.0
    for i in range(4):
        t = vd.tyre[i]
        if relax != 0.0:
            advance_deflections_relaxed(parts.tyre, vd.slip, i, t[TO_FZ], t[TO_GAMMA], t[TO_VX], t[TO_VSY],
                                        t[TO_OMEGA], t[TO_RE], h, relax)
        else:
            advance_deflections(parts.tyre, vd.slip, i, t[TO_FZ], t[TO_GAMMA], t[TO_VX], t[TO_VSY],
                                t[TO_OMEGA], t[TO_RE], h)
    io.signals[SG_BRAKE_PRESSURE] = vd.brake_out[BO_LINE]
    if eps:
        stp = parts.steering
        sts = states.steering
        eps_commit(stp, sts, h, stp[EP_N] * d.qd[ir] / stp[EP_RP])
        row = veh.driver_row[0]
        t_driver = -d.lam[row] if row >= 0 else sts[ES_T_DRIVER]
        eps_outputs(stp, sts, d.q, d.qd, ic, ir, t_driver, io.eps_out)
        io.signals[SG_SW_ANGLE] = io.eps_out[EO_SW_ANGLE]
        io.signals[SG_STEERING_TORQUE] = io.eps_out[EO_TB_TORQUE]
        io.signals[SG_MOTOR_ANGLE] = io.eps_out[EO_MOTOR_ANGLE]
        io.signals[SG_MOTOR_SPEED] = io.eps_out[EO_MOTOR_SPEED]
        io.signals[SG_MOTOR_CURRENT] = io.eps_out[EO_CURRENT]
        io.signals[SG_POWER_STAGE] = sts[ES_STAGE]
        for i in range(2):       # compliance steer of the front knuckles over the next step
            sp = veh.susp[i]
            vd.steer_offset[i] = sp[SP_CFY] * vd.tyre[i, TO_FY] + sp[SP_CMZ] * vd.tyre[i, TO_MZ]
    else:
        steering_outputs(parts.steering, states.steering, d.q, ic, ir, io.st_out)
        io.signals[SG_SW_ANGLE] = io.st_out[SO_SW_ANGLE]
        io.signals[SG_STEERING_TORQUE] = io.st_out[SO_TORQUE]
    if vd.audit[0] > 0.5:
        audit_commit(m, d, veh, vd, parts.steering, states.steering)
    ci = veh.chassis_idx
    io.signals[SG_VEHICLE_SPEED] = sqrt(d.qd[ci[0]] ** 2 + d.qd[ci[1]] ** 2 + d.qd[ci[2]] ** 2)
    io.signals[SG_ENGINE_SPEED] = io.pt_out[PO_ENGINE_SPEED]
    io.signals[SG_THROTTLE] = io.pt_out[PO_THROTTLE]
    io.signals[SG_TORQUE_LEFT] = io.pt_out[PO_TORQUE_LEFT]
    io.signals[SG_TORQUE_RIGHT] = io.pt_out[PO_TORQUE_RIGHT]
    if states.sensors[SM_ST_SLOTS] > 0.0:
        record_sensors(m, d, veh, io.signals, fx, parts.sensors, states.sensors)
    return OK


@inline_kernel
def _eps_before_step(m, d, veh, stp, sts, io, h, ic, ir):
    """The EPS over the coming step: the drive's voltage from the torsion-bar torque, the vehicle speed
    and the motor speed at the step's start; the driver's input at its end (the angle the hands impose,
    with its rate and acceleration, or a torque)."""
    rp = stp[EP_RP]
    t_tb = stp[EP_K_TB] * (d.q[ic] - d.q[ir] / rp)
    ci = veh.chassis_idx
    speed = sqrt(d.qd[ci[0]] ** 2 + d.qd[ci[1]] ** 2 + d.qd[ci[2]] ** 2)
    if sts[ES_EXT] > 0.5:
        external_command(stp, sts, io.commands[CMD_MOTOR_CURRENT], io.commands[CMD_MOTOR_INVALID] > 0.5)
    eps_control(stp, sts, t_tb, speed, stp[EP_N] * d.qd[ir] / rp, h)
    if stp[EP_DRIVER] == DRIVER_TORQUE:
        sts[ES_T_DRIVER] = io.extra[EX_SW_TORQUE]
    else:
        k = m.con_drv[veh.driver_row[0]]
        th, w, al = hands_step(stp, sts, io.commands[CMD_STEER], h)
        d.drv_ext[k, 0] = th
        d.drv_ext[k, 1] = w
        d.drv_ext[k, 2] = al


@kernel
def vehicle_advance(m, d, veh, vd, road, parts, states, io, h, nsteps):
    """nsteps vehicle steps with the commands held (benchmarks, settling). Returns (status, steps done)."""
    for n in range(nsteps):
        status = vehicle_step(m, d, veh, vd, road, parts, states, io, h)
        if status != OK:
            return status, n
    return OK, nsteps
