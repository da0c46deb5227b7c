"""Compiled kernels of the power audit (rtsim.vehicle.car.energy): the stored energies, and the
ports' work over each step paired with it as the trapezoidal rule integrates it."""
from __future__ import annotations

from rtsim.jit import kernel
from rtsim.mbs.constraints import poly_value
from rtsim.mbs.envelope import matvec_add

from ..kit.eps import EP_K_TB, EP_L, EP_RP, ES_E_EMF, ES_E_SUPPLY, ES_E_WINDING, ES_I
from ..kit.tables import table_integral
from .layout import CI_S, CI_Z, NPORT, STEER_COLUMN, STEER_EPS, STEER_RACK, Susp

# Audit array layout (VehicleData.audit_e): the port works (NPORT), the constraint ports, the electrical
# flows, the stored energies now and at the start, and the started flag.
(A_DRIVER_ANGLE, A_JOINTS, A_SUPPLY, A_WINDING, A_EMF) = range(NPORT, NPORT + 5)
NSTORED = 6    # kinetic, gravity, suspension springs, anti-roll bars, torsion bar, inductance
A_STORED = NPORT + 5
A_STORED0 = A_STORED + NSTORED
A_STARTED = A_STORED0 + NSTORED
A_SIZE = A_STARTED + 1


@kernel
def stored_energies(m, d, veh, vd, stp, sts, out):
    """Kinetic, gravity, suspension-spring, anti-roll-bar, torsion-bar and inductance energies (J)."""
    q = d.q
    y = d.y
    for i in range(m.nq):
        y[i] = 0.0
    matvec_add(m.m_env, m.first, m.ptr, m.perm, m.pinv, d.qd, y, 1.0)
    ke = 0.0
    pe = 0.0
    for i in range(m.nq):
        ke += 0.5 * d.qd[i] * y[i]
        pe -= m.q_grav[i] * q[i]
    springs = 0.0
    arb = 0.0
    for i in range(4):
        ix = veh.corner_idx[i]
        ks = ix[CI_S]
        s = (q[ks] + vd.steer_offset[i]) if ks >= 0 else 0.0
        length = poly_value(veh.spring_coef[i], m.poly_exp, q[ix[CI_Z]], s)
        springs += table_integral(veh.spring_tab[i], veh.susp[i, Susp.L0] - length)
        if i % 2 == 0:
            dz = q[ix[CI_Z]] - q[veh.corner_idx[i + 1, CI_Z]]
            arb += 0.5 * veh.susp[i, Susp.ARB] * dz * dz
    ic = veh.steer_idx[STEER_COLUMN]
    ir = veh.steer_idx[STEER_RACK]
    if veh.steer_kind[0] == STEER_EPS:
        tw = q[ic] - q[ir] / stp[EP_RP]
        tb = 0.5 * stp[EP_K_TB] * tw * tw
        ind = 0.5 * stp[EP_L] * sts[ES_I] * sts[ES_I]
    else:      # steer-by-wire: its torsion bar is inside the lumped port PORT_STEER_BY_WIRE
        tb = 0.0
        ind = 0.0
    out[0] = ke
    out[1] = pe
    out[2] = springs
    out[3] = arb
    out[4] = tb
    out[5] = ind


@kernel
def audit_commit(m, d, veh, vd, stp, sts):
    """After a step: the ports' work over it (trapezoidal pairing), the constraint ports', the
    electrical flows (from the EPS state), the stored energies."""
    a = vd.audit_e
    q = d.q
    qc = vd.qc
    # constraint forces at the step's end: the driver's row and the joints
    for k in range(m.nq):
        qc[0, k] = 0.0
        qc[1, k] = 0.0
    row = veh.driver_row[0]
    for i in range(m.nc):
        r = 0 if i == row else 1
        for s in range(m.con_nact[i]):
            slot = m.con_act[i, s]
            k = m.con_idx[i, slot]
            qc[r, k] -= d.jac[i, slot] * d.lam[i]
    if a[A_STARTED] > 0.5:
        for p in range(NPORT):
            w = 0.0
            for k in range(m.nq):
                w += (vd.pf_prev[p, k] + vd.pf[p, k]) * (q[k] - vd.q_prev[k])
            a[p] += 0.5 * w
        for r in range(2):
            w = 0.0
            for k in range(m.nq):
                w += (vd.qc_prev[r, k] + qc[r, k]) * (q[k] - vd.q_prev[k])
            a[A_DRIVER_ANGLE + r] += 0.5 * w
    for p in range(NPORT):
        for k in range(m.nq):
            vd.pf_prev[p, k] = vd.pf[p, k]
    for r in range(2):
        for k in range(m.nq):
            vd.qc_prev[r, k] = qc[r, k]
    for k in range(m.nq):
        vd.q_prev[k] = q[k]
    if veh.steer_kind[0] == STEER_EPS:
        a[A_SUPPLY] = sts[ES_E_SUPPLY]
        a[A_WINDING] = sts[ES_E_WINDING]
        a[A_EMF] = sts[ES_E_EMF]
    stored_energies(m, d, veh, vd, stp, sts, a[A_STORED:A_STORED0])
    if a[A_STARTED] < 0.5:
        for j in range(A_STORED, A_STORED0):
            a[j + A_STORED0 - A_STORED] = a[j]
        # the electrical flows count from here
        a[A_STARTED] = 1.0
        vd.e_base[0] = a[A_SUPPLY]
        vd.e_base[1] = a[A_WINDING]
        vd.e_base[2] = a[A_EMF]
