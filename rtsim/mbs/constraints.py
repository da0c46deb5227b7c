"""Constraint kernels: Phi(q, t), its Jacobian Phi_q (row-sparse, NSLOT entries per row), Phi_t,
and the velocity-quadratic term (Phi_q)' qd needed by the acceleration projection.

Natural-coordinate constraints are at most quadratic in q (constant distances, unit vectors, constant
dot products, linear combinations), so their second derivatives are exact and cheap. Relative angle
coordinates add one smooth trigonometric equation each, written so that it never needs switching.

A knife-edge wheel rolling on a plane adds one position row (its lowest point on the plane) and two
velocity rows (the contact point's material velocity is zero: no slip); see `_disc_rows`.
"""
from __future__ import annotations

import numpy as np
from rtsim.jit import inline_kernel, kernel, stage_kernel, uidx

from .model import (CON_ANGLE2D, CON_CRANK_ROD, CON_DISC_CONTACT, CON_DISC_ROLL, CON_DOT, CON_LINEAR, CON_POLY_POINT,
                    DRV_POLY, DRV_SINE, NSLOT, SCALAR, SCALAR2)


@inline_kernel
def ref(idx, cst, v, row, slot, comp):
    """Component `comp` of vector reference `slot` of row `row`: coordinate value plus constant."""
    k = idx[row, 3 * slot + comp]
    x = cst[row, 3 * slot + comp]
    if k >= 0:
        x += v[uidx(k)]
    return x


@inline_kernel
def refd(idx, v, row, slot, comp):
    """Rate of a vector reference (constants have zero rate)."""
    k = idx[row, 3 * slot + comp]
    if k >= 0:
        return v[uidx(k)]
    return 0.0


@inline_kernel
def poly_eval(coef, exps, z, s):
    """p(z, s) = sum_j coef[j] z^a_j s^b_j and its first and second derivatives
    (p, p_z, p_s, p_zz, p_zs, p_ss). The exponents form a full grid, a-major
    (j = a * nb + b), so the sums nest (Horner-like, no pow calls)."""
    nterm = exps.shape[0]
    nb = exps[nterm - 1, 1] + 1
    na = nterm // nb
    nb_used = nb if s != 0.0 else min(nb, 3)   # at s = 0 only s^0..s^2 terms reach p and its derivatives
    p = pz = ps = pzz = pzs = pss = 0.0
    za = 1.0     # z^a
    za1 = 0.0    # a z^(a-1)
    za2 = 0.0    # a (a-1) z^(a-2)
    for a in range(na):
        qv = qs = qss = 0.0
        sb = 1.0
        sb1 = 0.0
        sb2 = 0.0
        base = a * nb
        for b in range(nb_used):
            c = coef[base + b]
            qv += c * sb
            qs += c * sb1
            qss += c * sb2
            sb2 = (b + 1) * sb1
            sb1 = (b + 1) * sb
            sb = sb * s
        p += za * qv
        ps += za * qs
        pss += za * qss
        pz += za1 * qv
        pzs += za1 * qs
        pzz += za2 * qv
        za2 = (a + 1) * za1
        za1 = (a + 1) * za
        za = za * z
    return p, pz, ps, pzz, pzs, pss


@inline_kernel
def poly_value(coef, exps, z, s):
    """p(z, s) alone (see poly_eval)."""
    nterm = exps.shape[0]
    nb = exps[nterm - 1, 1] + 1
    na = nterm // nb
    p = 0.0
    za = 1.0
    for a in range(na):
        qv = 0.0
        sb = 1.0
        base = a * nb
        for b in range(nb if s != 0.0 else 1):
            qv += coef[base + b] * sb
            sb *= s
        p += za * qv
        za *= z
    return p


@inline_kernel
def _fill_poly_cache(m, pc, k, z, s):
    """pc[e, :] = (p, p_z, p_s, p_zz, p_zs, p_ss) of the three frame components of path k: poly_eval of
    each, its sums in its order (the same bits), the three components in one pass (independent sums
    keep the processor's pipelines full)."""
    coef = m.poly_coef[k]
    exps = m.poly_exp
    nterm = exps.shape[0]
    nb = exps[nterm - 1, 1] + 1
    na = nterm // nb
    nb_used = nb if s != 0.0 else min(nb, 3)
    p0 = pz0 = ps0 = pzz0 = pzs0 = pss0 = 0.0
    p1 = pz1 = ps1 = pzz1 = pzs1 = pss1 = 0.0
    p2 = pz2 = ps2 = pzz2 = pzs2 = pss2 = 0.0
    za = 1.0
    za1 = 0.0
    za2 = 0.0
    for a in range(na):
        qv0 = qs0 = qss0 = qv1 = qs1 = qss1 = qv2 = qs2 = qss2 = 0.0
        sb = 1.0
        sb1 = 0.0
        sb2 = 0.0
        base = a * nb
        for b in range(nb_used):
            c0 = coef[0, base + b]
            c1 = coef[1, base + b]
            c2 = coef[2, base + b]
            qv0 += c0 * sb
            qs0 += c0 * sb1
            qss0 += c0 * sb2
            qv1 += c1 * sb
            qs1 += c1 * sb1
            qss1 += c1 * sb2
            qv2 += c2 * sb
            qs2 += c2 * sb1
            qss2 += c2 * sb2
            sb2 = (b + 1) * sb1
            sb1 = (b + 1) * sb
            sb = sb * s
        p0 += za * qv0
        ps0 += za * qs0
        pss0 += za * qss0
        pz0 += za1 * qv0
        pzs0 += za1 * qs0
        pzz0 += za2 * qv0
        p1 += za * qv1
        ps1 += za * qs1
        pss1 += za * qss1
        pz1 += za1 * qv1
        pzs1 += za1 * qs1
        pzz1 += za2 * qv1
        p2 += za * qv2
        ps2 += za * qs2
        pss2 += za * qss2
        pz2 += za1 * qv2
        pzs2 += za1 * qs2
        pzz2 += za2 * qv2
        za2 = (a + 1) * za1
        za1 = (a + 1) * za
        za = za * z
    _store6(pc[0], p0, pz0, ps0, pzz0, pzs0, pss0)
    _store6(pc[1], p1, pz1, ps1, pzz1, pzs1, pss1)
    _store6(pc[2], p2, pz2, ps2, pzz2, pzs2, pss2)


@inline_kernel
def _store6(r, a, b, c, d, e, f):
    r[0] = a
    r[1] = b
    r[2] = c
    r[3] = d
    r[4] = e
    r[5] = f


@kernel
def eval_drivers(m, d, t):
    """Fill d.drv[k] = (f, f', f'') of every driver at time t."""
    for k in range(m.drv_kind.shape[0]):
        kind = m.drv_kind[k]
        p = m.drv_par[k]
        if kind == DRV_POLY:
            d.drv[k, 0] = p[0] + t * (p[1] + t * (p[2] + t * p[3]))
            d.drv[k, 1] = p[1] + t * (2.0 * p[2] + 3.0 * t * p[3])
            d.drv[k, 2] = 2.0 * p[2] + 6.0 * t * p[3]
        elif kind == DRV_SINE:
            s = np.sin(p[2] * t + p[3])
            c = np.cos(p[2] * t + p[3])
            d.drv[k, 0] = p[0] + p[1] * s
            d.drv[k, 1] = p[1] * p[2] * c
            d.drv[k, 2] = -p[1] * p[2] * p[2] * s
        else:  # DRV_EXTERNAL
            d.drv[k, 0] = d.drv_ext[k, 0]
            d.drv[k, 1] = d.drv_ext[k, 1]
            d.drv[k, 2] = d.drv_ext[k, 2]


@stage_kernel
def eval_constraints(m, d, q):
    """Phi, Jacobian values (d.jac, positions m.con_idx), Phi_t and Phi_tt at q and the drivers
    already evaluated in d.drv."""
    idx = m.con_idx
    cst = m.con_cst
    for i in range(m.nc):
        kind = m.con_kind[i]
        par = m.con_par[i]
        jac = d.jac[i]
        drv = m.con_drv[i]
        f = 0.0
        if drv >= 0:
            f = d.drv[drv, 0]
            d.phit[i] = -d.drv[drv, 1]
            d.phitt[i] = -d.drv[drv, 2]
        else:
            d.phit[i] = 0.0
            d.phitt[i] = 0.0
        if kind == CON_LINEAR:
            val = par[0]
            for s in range(NSLOT):
                k = idx[i, s]
                if k >= 0:
                    val += cst[i, s] * q[uidx(k)]
                    jac[s] = cst[i, s]
                else:
                    jac[s] = 0.0
            d.phi[i] = val - f
        elif kind == CON_DOT:
            val = -par[0]
            for s in range(12, NSLOT):
                jac[s] = 0.0
            for c in range(3):
                a = ref(idx, cst, q, i, 0, c) - ref(idx, cst, q, i, 1, c)
                b = ref(idx, cst, q, i, 2, c) - ref(idx, cst, q, i, 3, c)
                val += a * b
                jac[c] = b
                jac[3 + c] = -b
                jac[6 + c] = a
                jac[9 + c] = -a
            k = idx[i, SCALAR]
            if k >= 0:
                s = q[k]
                val -= par[1] * s + par[2] * s * s
                jac[SCALAR] = -par[1] - 2.0 * par[2] * s
            else:
                jac[SCALAR] = 0.0
            d.phi[i] = val - f
        elif kind == CON_ANGLE2D:
            th = q[idx[i, SCALAR]]
            sn = np.sin(th)
            cs = np.cos(th)
            dx = ref(idx, cst, q, i, 0, 0) - ref(idx, cst, q, i, 1, 0)
            dy = ref(idx, cst, q, i, 0, 1) - ref(idx, cst, q, i, 1, 1)
            d.phi[i] = dx * sn - dy * cs - f
            for s in range(NSLOT):
                jac[s] = 0.0
            jac[0] = sn
            jac[1] = -cs
            jac[3] = -sn
            jac[4] = cs
            jac[SCALAR] = dx * cs + dy * sn
        elif kind == CON_CRANK_ROD:
            th = q[idx[i, SCALAR]]
            x = q[idx[i, SCALAR2]]
            dx, dy, rx, ry, dirx, rod = _crank_rod(cst, i, th, x)
            for s_ in range(NSLOT):
                jac[s_] = 0.0
            jac[SCALAR] = (dy * rx - dx * ry) / rod
            jac[SCALAR2] = -dirx * dy / rod
            d.phi[i] = (dx * dx + dy * dy - rod * rod) / (2.0 * rod) - f
        elif kind == CON_POLY_POINT:
            k = int(par[0])
            comp = int(par[1])
            z = q[uidx(idx[i, SCALAR])]
            ks = idx[i, SCALAR2]
            s = q[uidx(ks)] if ks >= 0 else 0.0
            val = ref(idx, cst, q, i, 0, comp) - ref(idx, cst, q, i, 1, comp)
            dz = 0.0
            ds = 0.0
            for s_ in range(NSLOT):
                jac[s_] = 0.0
            jac[comp] = 1.0
            jac[3 + comp] = -1.0
            pc = d.poly_cache[k]
            if comp == 0:   # the three rows of a poly point share p(z, s): evaluate once
                _fill_poly_cache(m, pc, k, z, s)
            for e in range(3):
                p = pc[e, 0]
                pz = pc[e, 1]
                ps = pc[e, 2]
                ec = ref(idx, cst, q, i, 2 + e, comp)
                val -= p * ec
                jac[3 * (2 + e) + comp] = -p
                dz -= pz * ec
                ds -= ps * ec
            jac[SCALAR] = dz
            jac[SCALAR2] = ds if ks >= 0 else 0.0
            d.phi[i] = val - f
        elif kind == CON_DISC_CONTACT:
            for s_ in range(NSLOT):
                jac[s_] = 0.0
            r = par[0]
            az = ref(idx, cst, q, i, 1, 2)
            sq = np.sqrt(max(1.0 - az * az, 1e-12))
            jac[2] = 1.0
            jac[5] = r * az / sq
            d.phi[i] = ref(idx, cst, q, i, 0, 2) - r * sq - par[1] - f
        elif kind == CON_DISC_ROLL:
            comp = int(par[1])
            rb, rc = _disc_lever(idx, cst, q, i, par[0])
            scale = 2.0 / d.dt[0] if d.dt[0] > 0.0 else 1.0
            for s_ in range(NSLOT):
                jac[s_] = 0.0
            jac[comp] = scale
            jac[6 + comp] = scale * rb
            jac[9 + comp] = scale * rc
            d.phi[i] = (refd(idx, d.qd, i, 0, comp) + rb * refd(idx, d.qd, i, 2, comp)
                        + rc * refd(idx, d.qd, i, 3, comp))
        else:  # CON_ANGLE3D: u = A, v = B, w = C
            th = q[idx[i, SCALAR]]
            sn = np.sin(th)
            cs = np.cos(th)
            u0 = ref(idx, cst, q, i, 0, 0)
            u1 = ref(idx, cst, q, i, 0, 1)
            u2 = ref(idx, cst, q, i, 0, 2)
            v0 = ref(idx, cst, q, i, 1, 0)
            v1 = ref(idx, cst, q, i, 1, 1)
            v2 = ref(idx, cst, q, i, 1, 2)
            w0 = ref(idx, cst, q, i, 2, 0)
            w1 = ref(idx, cst, q, i, 2, 1)
            w2 = ref(idx, cst, q, i, 2, 2)
            # g1 = (u x v).w, g2 = u.v
            g1 = (u1 * v2 - u2 * v1) * w0 + (u2 * v0 - u0 * v2) * w1 + (u0 * v1 - u1 * v0) * w2
            g2 = u0 * v0 + u1 * v1 + u2 * v2
            d.phi[i] = g1 * cs - g2 * sn - f
            # d g1/du = v x w, d g1/dv = w x u, d g1/dw = u x v
            jac[0] = (v1 * w2 - v2 * w1) * cs - v0 * sn
            jac[1] = (v2 * w0 - v0 * w2) * cs - v1 * sn
            jac[2] = (v0 * w1 - v1 * w0) * cs - v2 * sn
            jac[3] = (w1 * u2 - w2 * u1) * cs - u0 * sn
            jac[4] = (w2 * u0 - w0 * u2) * cs - u1 * sn
            jac[5] = (w0 * u1 - w1 * u0) * cs - u2 * sn
            jac[6] = (u1 * v2 - u2 * v1) * cs
            jac[7] = (u2 * v0 - u0 * v2) * cs
            jac[8] = (u0 * v1 - u1 * v0) * cs
            for s in range(9, NSLOT):
                jac[s] = 0.0
            jac[SCALAR] = -g1 * sn - g2 * cs


@inline_kernel
def _disc_rows(idx, cst, q, qd, i, r):
    """A disc (axle a = slot B, in-plane unit vectors b, c = slots C, D) touching the plane z = h at
    its lowest point: nu = (e_z - a_z a) / s with s = sqrt(1 - a_z^2) is the in-plane unit vector
    pointing up, the contact point is W - r nu, and the material velocity there is
    W' + (rho.b) b' + (rho.c) c' with rho = -r nu. Returns (rho.b, rho.c) and their rates."""
    a0 = ref(idx, cst, q, i, 1, 0)
    a1 = ref(idx, cst, q, i, 1, 1)
    a2 = ref(idx, cst, q, i, 1, 2)
    ad0 = refd(idx, qd, i, 1, 0)
    ad1 = refd(idx, qd, i, 1, 1)
    ad2 = refd(idx, qd, i, 1, 2)
    sq = np.sqrt(max(1.0 - a2 * a2, 1e-12))
    sd = -a2 * ad2 / sq
    out0 = 0.0
    out1 = 0.0
    rate0 = 0.0
    rate1 = 0.0
    for k in range(2):
        slot = 2 + k
        b0 = ref(idx, cst, q, i, slot, 0)
        b1 = ref(idx, cst, q, i, slot, 1)
        b2 = ref(idx, cst, q, i, slot, 2)
        bd0 = refd(idx, qd, i, slot, 0)
        bd1 = refd(idx, qd, i, slot, 1)
        bd2 = refd(idx, qd, i, slot, 2)
        ab = a0 * b0 + a1 * b1 + a2 * b2
        abd = ad0 * b0 + ad1 * b1 + ad2 * b2 + a0 * bd0 + a1 * bd1 + a2 * bd2
        num = b2 - a2 * ab                       # (e_z - a_z a).b
        numd = bd2 - ad2 * ab - a2 * abd
        lever = -r * num / sq
        lever_d = -r * (numd / sq - num * sd / (sq * sq))
        if k == 0:
            out0 = lever
            rate0 = lever_d
        else:
            out1 = lever
            rate1 = lever_d
    return out0, out1, rate0, rate1


@inline_kernel
def _disc_lever(idx, cst, q, i, r):
    """(rho.b, rho.c) of a disc-roll row (see _disc_rows), positions only."""
    a2 = ref(idx, cst, q, i, 1, 2)
    sq = np.sqrt(max(1.0 - a2 * a2, 1e-12))
    a0 = ref(idx, cst, q, i, 1, 0)
    a1 = ref(idx, cst, q, i, 1, 1)
    ab = a0 * ref(idx, cst, q, i, 2, 0) + a1 * ref(idx, cst, q, i, 2, 1) + a2 * ref(idx, cst, q, i, 2, 2)
    ac = a0 * ref(idx, cst, q, i, 3, 0) + a1 * ref(idx, cst, q, i, 3, 1) + a2 * ref(idx, cst, q, i, 3, 2)
    return (-r * (ref(idx, cst, q, i, 2, 2) - a2 * ab) / sq,
            -r * (ref(idx, cst, q, i, 3, 2) - a2 * ac) / sq)


@inline_kernel
def _triple(a0, a1, a2, b0, b1, b2, c0, c1, c2):
    return (a1 * b2 - a2 * b1) * c0 + (a2 * b0 - a0 * b2) * c1 + (a0 * b1 - a1 * b0) * c2


@inline_kernel
def _crank_rod(cst, i, th, x):
    """Planar crank and rod: d = c + R(th) a - (0, dir x), the crank arm r = R(th) a; returns
    (dx, dy, rx, ry, dir, L) from the row's constants (c0, c1, a0 | a1, dir, L)."""
    sn = np.sin(th)
    cs = np.cos(th)
    a0 = cst[i, 2]
    a1 = cst[i, 3]
    rx = cs * a0 - sn * a1
    ry = sn * a0 + cs * a1
    dirx = cst[i, 4]
    return cst[i, 0] + rx, cst[i, 1] + ry - dirx * x, rx, ry, dirx, cst[i, 5]


@kernel
def eval_hqd(m, d, q, qd):
    """d.hqd = (d/dt Phi_q) qd, the velocity-quadratic part of Phi'' = Phi_q qdd + hqd + Phi_tt."""
    hqd_rows(m, d, q, qd, True)


@inline_kernel
def hqd_rows(m, d, q, qd, fill_poly):
    """eval_hqd; with fill_poly False the polynomial paths are read from d.poly_cache as the last
    eval_constraints left them, which must have been at this q (the integrator's finishing stage)."""
    idx = m.con_idx
    cst = m.con_cst
    for i in range(m.nc):
        kind = m.con_kind[i]
        if kind == CON_LINEAR:
            d.hqd[i] = 0.0
        elif kind == CON_DOT:
            h = 0.0
            for c in range(3):
                ad = refd(idx, qd, i, 0, c) - refd(idx, qd, i, 1, c)
                bd = refd(idx, qd, i, 2, c) - refd(idx, qd, i, 3, c)
                h += ad * bd
            h *= 2.0
            k = idx[i, SCALAR]
            if k >= 0:
                h -= 2.0 * m.con_par[i, 2] * qd[k] * qd[k]
            d.hqd[i] = h
        elif kind == CON_ANGLE2D:
            k = idx[i, SCALAR]
            th = q[k]
            thd = qd[k]
            sn = np.sin(th)
            cs = np.cos(th)
            dx = ref(idx, cst, q, i, 0, 0) - ref(idx, cst, q, i, 1, 0)
            dy = ref(idx, cst, q, i, 0, 1) - ref(idx, cst, q, i, 1, 1)
            dxd = refd(idx, qd, i, 0, 0) - refd(idx, qd, i, 1, 0)
            dyd = refd(idx, qd, i, 0, 1) - refd(idx, qd, i, 1, 1)
            d.hqd[i] = 2.0 * (dxd * cs + dyd * sn) * thd + (-dx * sn + dy * cs) * thd * thd
        elif kind == CON_CRANK_ROD:
            kt = idx[i, SCALAR]
            kx = idx[i, SCALAR2]
            dx, dy, rx, ry, dirx, rod = _crank_rod(cst, i, q[kt], q[kx])
            a2 = cst[i, 2] * cst[i, 2] + cst[i, 3] * cst[i, 3]
            ptt = (a2 - dx * rx - dy * ry) / rod
            ptx = -dirx * rx / rod
            pxx = dirx * dirx / rod
            td = qd[kt]
            xd = qd[kx]
            d.hqd[i] = ptt * td * td + 2.0 * ptx * td * xd + pxx * xd * xd
        elif kind == CON_POLY_POINT:
            kp = int(m.con_par[i, 0])
            comp = int(m.con_par[i, 1])
            kz = idx[i, SCALAR]
            ks = idx[i, SCALAR2]
            z = q[kz]
            zd = qd[kz]
            s = q[ks] if ks >= 0 else 0.0
            sd = qd[ks] if ks >= 0 else 0.0
            h = 0.0
            pc = d.poly_cache[kp]
            if comp == 0 and fill_poly:
                _fill_poly_cache(m, pc, kp, z, s)
            for e in range(3):
                pz = pc[e, 1]
                ps = pc[e, 2]
                pzz = pc[e, 3]
                pzs = pc[e, 4]
                pss = pc[e, 5]
                ec = ref(idx, cst, q, i, 2 + e, comp)
                ecd = refd(idx, qd, i, 2 + e, comp)
                h -= (pzz * zd * zd + 2.0 * pzs * zd * sd + pss * sd * sd) * ec + 2.0 * (pz * zd + ps * sd) * ecd
            d.hqd[i] = h
        elif kind == CON_DISC_CONTACT:
            r = m.con_par[i, 0]
            az = ref(idx, cst, q, i, 1, 2)
            azd = refd(idx, qd, i, 1, 2)
            sq = np.sqrt(max(1.0 - az * az, 1e-12))
            d.hqd[i] = r * azd * azd / (sq * sq * sq)
        elif kind == CON_DISC_ROLL:
            comp = int(m.con_par[i, 1])
            _rb, _rc, rbd, rcd = _disc_rows(idx, cst, q, qd, i, m.con_par[i, 0])
            scale = 2.0 / d.dt[0] if d.dt[0] > 0.0 else 1.0
            d.hqd[i] = scale * (rbd * refd(idx, qd, i, 2, comp) + rcd * refd(idx, qd, i, 3, comp))
        else:  # CON_ANGLE3D
            k = idx[i, SCALAR]
            th = q[k]
            thd = qd[k]
            sn = np.sin(th)
            cs = np.cos(th)
            u = (ref(idx, cst, q, i, 0, 0), ref(idx, cst, q, i, 0, 1), ref(idx, cst, q, i, 0, 2))
            v = (ref(idx, cst, q, i, 1, 0), ref(idx, cst, q, i, 1, 1), ref(idx, cst, q, i, 1, 2))
            w = (ref(idx, cst, q, i, 2, 0), ref(idx, cst, q, i, 2, 1), ref(idx, cst, q, i, 2, 2))
            ud = (refd(idx, qd, i, 0, 0), refd(idx, qd, i, 0, 1), refd(idx, qd, i, 0, 2))
            vd = (refd(idx, qd, i, 1, 0), refd(idx, qd, i, 1, 1), refd(idx, qd, i, 1, 2))
            wd = (refd(idx, qd, i, 2, 0), refd(idx, qd, i, 2, 1), refd(idx, qd, i, 2, 2))
            g1 = _triple(u[0], u[1], u[2], v[0], v[1], v[2], w[0], w[1], w[2])
            g2 = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
            # first and second time derivatives of g1 = (u x v).w and g2 = u.v, with qdd = 0
            g1d = (_triple(ud[0], ud[1], ud[2], v[0], v[1], v[2], w[0], w[1], w[2])
                   + _triple(u[0], u[1], u[2], vd[0], vd[1], vd[2], w[0], w[1], w[2])
                   + _triple(u[0], u[1], u[2], v[0], v[1], v[2], wd[0], wd[1], wd[2]))
            g1dd = 2.0 * (_triple(ud[0], ud[1], ud[2], vd[0], vd[1], vd[2], w[0], w[1], w[2])
                          + _triple(ud[0], ud[1], ud[2], v[0], v[1], v[2], wd[0], wd[1], wd[2])
                          + _triple(u[0], u[1], u[2], vd[0], vd[1], vd[2], wd[0], wd[1], wd[2]))
            g2d = ud[0] * v[0] + ud[1] * v[1] + ud[2] * v[2] + u[0] * vd[0] + u[1] * vd[1] + u[2] * vd[2]
            g2dd = 2.0 * (ud[0] * vd[0] + ud[1] * vd[1] + ud[2] * vd[2])
            # Phi = g1 cos - g2 sin; Phi'' (qdd = 0, theta'' = 0)
            d.hqd[i] = (g1dd * cs - 2.0 * g1d * sn * thd - g1 * cs * thd * thd
                        - g2dd * sn - 2.0 * g2d * cs * thd + g2 * sn * thd * thd)


@kernel
def jac_matvec(m, d, x, out):
    """out[i] = (Phi_q x)_i."""
    idx = m.con_idx
    for i in range(m.nc):
        s = 0.0
        for a in range(m.con_nact[i]):
            k = uidx(m.con_act[i, a])
            s += d.jac[i, k] * x[uidx(idx[i, k])]
        out[i] = s


@kernel
def jac_t_matvec_add(m, d, v, out, scale):
    """out += scale * Phi_q^T v."""
    idx = m.con_idx
    for i in range(m.nc):
        vi = scale * v[i]
        if vi != 0.0:
            for a in range(m.con_nact[i]):
                k = uidx(m.con_act[i, a])
                out[uidx(idx[i, k])] += d.jac[i, k] * vi
