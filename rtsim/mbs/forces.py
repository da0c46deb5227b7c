"""Applied-force kernels: generalized forces Q(q, qd, t) and their tangent stiffness K = -dQ/dq and
damping C = -dQ/dqd, accumulated into W = M + cC C + cK K in envelope storage.

Gravity in natural coordinates is a constant generalized force (the mass distribution maps linearly
onto the coordinates), precomputed in the model as `q_grav`.
"""
from __future__ import annotations

import numpy as np
from rtsim.jit import kernel, stage_kernel

from .constraints import ref, refd
from .envelope import add_entry
from .model import FRC_SPRING, SCALAR


@kernel
def _add_block(m, w, row, ia_slot, ib_slot, kk, cc, e0, e1, e2, cK, cC, geo):
    """Add the 6x6 spring tangent [[K, -K], [-K, K]] with K = kk e e^T + geo (I - e e^T) (stiffness)
    and cc e e^T (damping) between the coordinates of slots A and B of force row `row`."""
    e = (e0, e1, e2)
    for a in range(6):
        sa = ia_slot if a < 3 else ib_slot
        ca = a % 3
        ia = m.frc_idx[row, 3 * sa + ca]
        if ia < 0:
            continue
        for b in range(a, 6):
            sb = ia_slot if b < 3 else ib_slot
            cb = b % 3
            ib = m.frc_idx[row, 3 * sb + cb]
            if ib < 0:
                continue
            eij = e[ca] * e[cb]
            kab = kk * eij + geo * ((1.0 if ca == cb else 0.0) - eij)
            val = cK * kab + cC * cc * eij
            if (a < 3) != (b < 3):
                val = -val
            if a != b and ia == ib:
                val *= 2.0
            add_entry(w, m.first, m.ptr, m.pinv, ia, ib, val)


@stage_kernel
def eval_forces(m, d, q, qd, want_tangent, cK, cC):
    """d.force = Q(q, qd, t); if want_tangent, d.w_env = M + cC C + cK K. Returns the index of the
    first non-finite generalized force, or -1."""
    out = d.force
    for i in range(m.nq):
        out[i] = m.q_grav[i] + d.q_ext[i]
    if want_tangent:
        for k in range(m.m_env.shape[0]):
            d.w_env[k] = m.m_env[k]
    idx = m.frc_idx
    cst = m.frc_cst
    for f in range(m.frc_kind.shape[0]):
        kind = m.frc_kind[f]
        par = m.frc_par[f]
        drive = 0.0
        if m.frc_drv[f] >= 0:
            drive = par[4] * d.drv[m.frc_drv[f], 0]
        if kind == FRC_SPRING:
            dx = ref(idx, cst, q, f, 0, 0) - ref(idx, cst, q, f, 1, 0)
            dy = ref(idx, cst, q, f, 0, 1) - ref(idx, cst, q, f, 1, 1)
            dz = ref(idx, cst, q, f, 0, 2) - ref(idx, cst, q, f, 1, 2)
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            if length < 1e-12:
                continue
            e0 = dx / length
            e1 = dy / length
            e2 = dz / length
            ld = (e0 * (refd(idx, qd, f, 0, 0) - refd(idx, qd, f, 1, 0))
                  + e1 * (refd(idx, qd, f, 0, 1) - refd(idx, qd, f, 1, 1))
                  + e2 * (refd(idx, qd, f, 0, 2) - refd(idx, qd, f, 1, 2)))
            tension = par[0] * (length - par[2]) + par[1] * ld + par[3] + drive
            e = (e0, e1, e2)
            for c in range(3):
                ka = idx[f, c]
                if ka >= 0:
                    out[ka] -= tension * e[c]
                kb = idx[f, 3 + c]
                if kb >= 0:
                    out[kb] += tension * e[c]
            if want_tangent:
                _add_block(m, d.w_env, f, 0, 1, par[0], par[1], e0, e1, e2, cK, cC, tension / length)
        else:  # FRC_COORD
            k = idx[f, SCALAR]
            out[k] += par[0] + drive - par[1] * (q[k] - par[2]) - par[3] * qd[k]
            if want_tangent:
                add_entry(d.w_env, m.first, m.ptr, m.pinv, k, k, cK * par[1] + cC * par[3])
    for i in range(m.nq):
        if not np.isfinite(out[i]):
            return i
    return -1


@kernel
def potential_energy(m, q):
    """Potential energy of gravity and of the conservative part of springs, J."""
    e = 0.0
    for i in range(m.nq):
        e -= m.q_grav[i] * q[i]
    idx = m.frc_idx
    cst = m.frc_cst
    for f in range(m.frc_kind.shape[0]):
        par = m.frc_par[f]
        if m.frc_kind[f] == FRC_SPRING:
            dx = ref(idx, cst, q, f, 0, 0) - ref(idx, cst, q, f, 1, 0)
            dy = ref(idx, cst, q, f, 0, 1) - ref(idx, cst, q, f, 1, 1)
            dz = ref(idx, cst, q, f, 0, 2) - ref(idx, cst, q, f, 1, 2)
            stretch = np.sqrt(dx * dx + dy * dy + dz * dz) - par[2]
            e += 0.5 * par[0] * stretch * stretch + par[3] * stretch
        else:
            k = idx[f, SCALAR]
            ds = q[k] - par[2]
            e += 0.5 * par[1] * ds * ds - par[0] * q[k]
    return e
