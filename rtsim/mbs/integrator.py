"""The ALI3-P integrator: index-3 augmented Lagrangian with mass-damping-stiffness-orthogonal
projections, trapezoidal rule (seed paper, section 3.1, eqs. 1-4).

One step from t_n to t_{n+1} = t_n + h:
1. Predict q from (q_n, qd_n, qdd_n); the trapezoidal rule ties velocities and accelerations to q:
   qd = (2/h) q + qhd,  qdd = (4/h^2) q + qhdd  (eqs. 3, 4).
2. Newton-Raphson on the discretized equations of motion, scaled by h^2/4:
   f(q) = (h^2/4) [M qdd + Phi_q^T (alpha Phi + lambda*) - Q] = 0  (eq. 1),
   tangent  A = M + (h/2) C + (h^2/4) (Phi_q^T alpha Phi_q + K),
   with the multiplier iteration lambda* <- lambda* + alpha Phi after every update (eq. 2).
   The sparse Cholesky factor of A (rtsim.mbs.sparse) is reused across iterations and steps while
   Newton contracts fast enough; it is refreshed when it does not (a modified Newton method with a
   fallback). Newton stops when the last increment and the constraints at the iterate it was computed
   from are within tolerance, or (IS_ERROR_TEST) the estimated error of the new iterate and its
   constraints.
3. Projections of velocities and accelerations onto Phi' = 0 and Phi'' = 0 in the metric
   W = M + (h/2) C + (h^2/4) K:  A qd = W qd* - (h^2/4) Phi_q^T alpha Phi_t, and the same for qdd with
   (Phi_q)' qd + Phi_tt. Both are iterated augmented-Lagrangian projections that reuse the factor of
   A (and correct for it being stale), so the constraint rates are met to tolerance.

alpha is diagonal: one penalty factor per constraint, scaled to the mass matrix and the step (see
rtsim.mbs.simulation.penalty_factors). Kernels return a status code; they never raise.
"""
from __future__ import annotations

import numpy as np
from rtsim.jit import inline_kernel, kernel, stage_kernel, uidx

from .constraints import eval_constraints, eval_drivers, hqd_rows, jac_matvec, jac_t_matvec_add
from .envelope import matvec_add
from .forces import eval_forces
from .sparse import cholesky, solve
from .model import (
    ERR_FACTOR, ERR_NEWTON, ERR_NONFINITE_FORCE, ERR_NONFINITE_STATE, ERR_PROJECTION,
    FS_MIN_STEP, FS_REUSE_RATE, FS_STALL_RATE, FS_TOL_ACC, FS_TOL_ACC_FAIL, FS_TOL_DQ, FS_TOL_PHI, FS_TOL_VEL, FS_TOL_VEL_FAIL, IS_MAX_ITER, IS_MAX_PROJ,
    IS_ABSOLUTE_DQ, IS_ERROR_TEST, IS_FINISH_FORCES, IS_PREDICTOR, IS_PROJECTION_FACTOR, IS_REUSE_STEPS, IS_TANGENT_FORCES, OK, ST_FACTORIZATIONS, ST_FAIL_INDEX, ST_ITER_TOTAL, ST_LAST_ITER,
    ST_LAST_RESIDUAL, ST_MAX_PHI, ST_MAX_PHID, ST_MAX_PHIDD, ST_PROJ_ITER, ST_STEPS,
)

HAVE_FACTOR = 0
NEED_FACTOR = 1


@kernel
def factorize(m, d, bq):
    """a_env = W + bq Phi_q^T alpha Phi_q in the factor's pattern (rtsim.mbs.sparse), then l_env = chol(a_env).
    Returns the failing (factor-permuted) row or -1."""
    a = d.a_env
    for p in range(a.shape[0]):
        k = m.fw_map[p]
        a[p] = d.w_env[uidx(k)] if k >= 0 else 0.0
    for e in range(m.asm_row.shape[0]):
        i = uidx(m.asm_row[e])
        a[uidx(m.asm_pos[e])] += (bq * d.alpha[i] * m.asm_mult[e] * d.jac[i, uidx(m.asm_s[e])]
                                  * d.jac[i, uidx(m.asm_u[e])])
    return cholesky(a, m.fcolptr, m.frowidx, m.fuptr, m.fupos, m.fuend, d.l_env, d.work)


@stage_kernel
def refresh_factor(m, d, bq):
    """Factorize the tangent at the current Jacobian and W; ERR_FACTOR (row in stats) if not SPD."""
    row = factorize(m, d, bq)
    d.stats[ST_FACTORIZATIONS] += 1
    if row >= 0:
        d.flags[HAVE_FACTOR] = 0
        d.stats[ST_FAIL_INDEX] = m.fperm[row]
        return ERR_FACTOR
    d.flags[HAVE_FACTOR] = 1
    d.flags[NEED_FACTOR] = 0
    return OK


@inline_kernel
def _max_abs(x, n):
    s = 0.0
    for i in range(n):
        a = abs(x[i])
        if a > s:
            s = a
    return s


@kernel
def _dot_alpha(d, a, b, nc):
    s = 0.0
    for i in range(nc):
        s += a[i] * d.alpha[i] * b[i]
    return s


@stage_kernel
def solve_constrained(m, d, b, c, bq, x, tol, tol_fail):
    """x = A^-1 (b - bq Phi_q^T (alpha c + mu)) with the multipliers mu chosen so that
    g = Phi_q x + c = 0 (mu is left in d.mu).

    mu solves S mu = g(0), S = bq Phi_q A^-1 Phi_q^T, by conjugate gradients preconditioned with
    alpha (S ~ alpha^-1 where the penalty dominates), one back-substitution per iteration. With
    mu = 0 this is the classical one-solve penalty step of ALI3-P; CG then removes what is left, also
    along nearly singular directions of Phi_q at bifurcations, where the plain multiplier update
    (mu += alpha g) contracts only at the rate 1 / (1 + p s^2). Returns (iterations, max|g|),
    iterations < 0 if max|g| is still above tol_fail."""
    nq = m.nq
    nc = m.nc
    for i in range(nc):
        d.z[i] = d.alpha[i] * c[i]
        d.mu[i] = 0.0
    jac_t_matvec_add(m, d, d.z, b, -bq)
    solve(d.l_env, m.fcolptr, m.frowidx, m.fperm, m.fpinv, b, x, d.work)
    r = d.g           # CG residual = g(mu)
    p = d.sig         # search direction
    sp = d.sp         # S p
    jac_matvec(m, d, x, r)
    gmax = 0.0
    for i in range(nc):
        r[i] += c[i]
        if abs(r[i]) > gmax:
            gmax = abs(r[i])
    for i in range(nc):
        p[i] = d.alpha[i] * r[i]
    rz = _dot_alpha(d, r, r, nc)
    k = 0
    while gmax > tol and k < m.iset[IS_MAX_PROJ]:
        k += 1
        for i in range(nq):
            d.r[i] = 0.0
        jac_t_matvec_add(m, d, p, d.r, bq)
        solve(d.l_env, m.fcolptr, m.frowidx, m.fperm, m.fpinv, d.r, d.x, d.work)
        jac_matvec(m, d, d.x, sp)
        psp = 0.0
        for i in range(nc):
            psp += p[i] * sp[i]
        if not (psp > 0.0):
            break
        a = rz / psp
        for i in range(nq):
            x[i] -= a * d.x[i]
        gmax = 0.0
        for i in range(nc):
            d.mu[i] += a * p[i]
            r[i] -= a * sp[i]
            if abs(r[i]) > gmax:
                gmax = abs(r[i])
        rz_new = _dot_alpha(d, r, r, nc)
        beta = rz_new / rz
        rz = rz_new
        for i in range(nc):
            p[i] = d.alpha[i] * r[i] + beta * p[i]
    if k > 0:       # the true residual, not the recursively updated one (without CG: gmax is that)
        jac_matvec(m, d, x, r)
        gmax = 0.0
        for i in range(nc):
            a = abs(r[i] + c[i])
            if a > gmax:
                gmax = a
    if gmax <= tol_fail:
        return k, gmax
    return -1, gmax


@stage_kernel
def project(m, d, x, c, bq, tol, tol_fail):
    """Projection of x (in place) onto Phi_q x + c = 0 in the metric W, minimising
    (x - x*)^T W (x - x*) / 2 with the factor of A = W + bq Phi_q^T alpha Phi_q: the penalty projection
    of ALI3-P, A x = W x* - bq Phi_q^T (alpha c + sigma), repeated with the multiplier update
    sigma += alpha g (g = Phi_q x + c) until max|g| <= tol.

    It is solved for the correction x - x* = A^-1 (-bq Phi_q^T (alpha g* + sigma)), g* = Phi_q x* + c,
    which is the same in exact arithmetic (A x* = W x* + bq Phi_q^T alpha Phi_q x*) and needs no product
    with W. With a factor made at another q (Newton's, at its first iterate: IS_PROJECTION_FACTOR = 0)
    the fixed point is then the projection in the metric A_factor - bq Phi_q^T alpha Phi_q, close to W,
    of the small correction only; solved for x itself, the stale penalty part (alpha is 1e4 times the
    mass scale) acted on the whole of x. Measured over 3 s of a 35 deg step steer at 80 km/h: the cars'
    q were 5e-6 (xbw) and 1e-4 (EPS car) off those projected with a fresh factor, now 2e-7 and 1e-8.

    Deliberately not solved exactly (no CG here): near a singular position the exact projection
    divides the small leftover g along the vanishing singular direction by the singular value and
    throws the velocities off the branch; the penalty form regularises exactly those directions.
    Returns (iterations, max|g|), iterations < 0 if max|g| is still above tol_fail."""
    nq = m.nq
    nc = m.nc
    y = d.y
    gs = d.sp
    for i in range(nq):
        y[i] = x[i]
    jac_matvec(m, d, x, gs)
    for i in range(nc):
        gs[i] += c[i]
        d.sig[i] = 0.0
    gmax = np.inf
    k = 0
    while k < m.iset[IS_MAX_PROJ]:
        k += 1
        for i in range(nq):
            d.r[i] = 0.0
        for i in range(nc):
            d.z[i] = d.alpha[i] * gs[i] + d.sig[i]
        jac_t_matvec_add(m, d, d.z, d.r, -bq)
        solve(d.l_env, m.fcolptr, m.frowidx, m.fperm, m.fpinv, d.r, d.x, d.work)
        for i in range(nq):
            x[i] = y[i] + d.x[i]
        jac_matvec(m, d, d.x, d.g)
        gmax = 0.0
        for i in range(nc):
            g = d.g[i] + gs[i]
            d.sig[i] += d.alpha[i] * g
            if abs(g) > gmax:
                gmax = abs(g)
        if gmax <= tol:
            break
    if gmax <= tol_fail:
        return k, gmax
    return -1, gmax


# Newton bookkeeping carried between the stages of a step (Data.newton).
NW_PREV = 0     # previous increment norm
NW_AGE = 1      # iterations done on the current factor
NW_NRM = 2      # last increment norm
NW_IT = 3       # iterations done in this step
NW_STEP = 4     # fraction of the increment the next iteration applies (step control; 1: a full Newton step)
NW_JMAX = 5     # coordinate of the last increment's largest component
NW_YMAX = 6     # that component
NW_CORR = 7     # predictor: corrections of extrapolated steps in the history (0-4); -1 - the count the step
#                 will leave while a step is under way (a step that fails leaves it negative: none)
CONVERGED = 1
CONTINUE = 0


@kernel
def wants_tangent(m, d):
    """True when this Newton iteration refactors, so force kernels must add their K and C to W."""
    return d.flags[HAVE_FACTOR] == 0 or d.flags[NEED_FACTOR] == 1


@kernel
def _can_extrapolate(m, d, h):
    """True when the last step ended in the current state with the same h, so that the accelerations it
    started and ended with extrapolate to this step's end (a state set from outside, a failed step or a
    new h falls back to the Taylor predictor)."""
    if m.iset[IS_PREDICTOR] == 0 or d.dt[0] != h:
        return False
    for i in range(m.nq):
        if d.pred[m.nq + i] != d.qdd[i]:
            return False
    return True


@stage_kernel
def step_begin(m, d, h):
    """Stage 1: drivers at t + h, predictor, reset of the Newton bookkeeping.

    The predictor is the Taylor one, q + h qd + h^2/2 qdd (IS_PREDICTOR = 0), or (IS_PREDICTOR = 1) the
    trapezoidal rule itself, base = q + h qd + h^2/4 (qdd + qdd_end) with qdd_end = 2 qdd - qdd_prev
    extrapolated from the last two steps, plus the correction Newton made to the last steps' bases,
    extrapolated in time. The correction is mostly systematic: the velocity projection puts qd on the
    tangent of a spinning body's unit vectors, and the trapezoidal chord then falls short of the arc by
    about (omega h)^3 / 12 a step (8e-5 rad for a wheel at 100 rad/s and h = 1 ms), which Newton would
    otherwise remove anew every step. It turns with the body (by omega h a step): the last correction
    alone leaves about omega h of it, the motorcycle's first increment at 20 m/s 3e-7 (2e-4 without it).
    After k = 2, 3, 4 extrapolated steps in a row the corrections c1..ck (newest first) extrapolate with
    the polynomial through them: 2 c1 - c2; 3 c1 - 3 c2 + c3; 4 c1 - 6 c2 + 4 c3 - c4. The motorcycle's
    first increment at 20 m/s drops to about 9e-11 with the cubic (1.4e-9 with the quadratic) and Newton
    mostly meets its tolerance after one iteration. A step accepted after one iteration keeps what a
    second would have removed, so the start also sets the accuracy: over 0.35 s of that run q ended 2.2e-8
    off the fully converged steps with the quadratic, 1.4e-10 with the cubic (6.2e-9 with the last
    correction alone and two iterations). Newton's stopping test is the same either way."""
    ext = _can_extrapolate(m, d, h)
    if d.dt[0] != h or m.iset[IS_REUSE_STEPS] == 0:
        d.dt[0] = h
        d.flags[NEED_FACTOR] = 1
    eval_drivers(m, d, d.t[0] + h)
    c1 = 2.0 / h
    c2 = 4.0 / (h * h)
    b = 0.25 * h * h
    hist = d.pred
    n = m.nq
    ncorr = d.newton[NW_CORR] if ext else 0.0
    for i in range(n):
        qn = d.q[i]
        d.qhd[i] = -(c1 * qn + d.qd[i])
        d.qhdd[i] = -(c2 * qn + 4.0 / h * d.qd[i] + d.qdd[i])
        if ext:
            base = qn + h * d.qd[i] + b * (3.0 * d.qdd[i] - hist[i])
            if ncorr >= 4.0:
                d.q[i] = (base + 4.0 * (hist[2 * n + i] + hist[4 * n + i]) - 6.0 * hist[3 * n + i]
                          - hist[5 * n + i])
            elif ncorr >= 3.0:
                d.q[i] = base + 3.0 * (hist[2 * n + i] - hist[3 * n + i]) + hist[4 * n + i]
            elif ncorr >= 2.0:
                d.q[i] = base + 2.0 * hist[2 * n + i] - hist[3 * n + i]
            else:
                d.q[i] = base + hist[2 * n + i]
        else:
            base = qn + h * d.qd[i] + 2.0 * b * d.qdd[i]
            d.q[i] = base
        if m.iset[IS_PREDICTOR] == 1:
            hist[i] = d.qdd[i]
            hist[5 * n + i] = hist[4 * n + i]
            hist[4 * n + i] = hist[3 * n + i]
            hist[3 * n + i] = hist[2 * n + i]
            hist[2 * n + i] = base
    d.newton[NW_CORR] = -1.0 - (min(ncorr + 1.0, 4.0) if ext else 0.0)
    d.newton[NW_PREV] = np.inf
    d.newton[NW_AGE] = 0.0
    d.newton[NW_NRM] = np.inf
    d.newton[NW_IT] = 0.0
    d.newton[NW_STEP] = 1.0
    d.newton[NW_JMAX] = 0.0
    d.newton[NW_YMAX] = 0.0


@stage_kernel
def newton_prepare(m, d, h):
    """Stage 2 (each iteration): velocities and accelerations from q, constraints, the multiplier
    update lambda* += alpha Phi, and the model's own forces (into d.force; with wants_tangent also
    W = M + h/2 C + h^2/4 K into d.w_env). A caller may add further forces after this stage."""
    c1 = 2.0 / h
    c2 = 4.0 / (h * h)
    for i in range(m.nq):
        d.qd[i] = c1 * d.q[i] + d.qhd[i]
        d.qdd[i] = c2 * d.q[i] + d.qhdd[i]
    eval_constraints(m, d, d.q)
    if d.newton[NW_IT] > 0:
        for i in range(m.nc):
            d.lam[i] += d.alpha[i] * d.phi[i]
    bad = eval_forces(m, d, d.q, d.qd, wants_tangent(m, d), 0.25 * h * h, 0.5 * h)
    if bad >= 0:
        d.stats[ST_FAIL_INDEX] = bad
        return ERR_NONFINITE_FORCE
    return OK


@stage_kernel
def newton_update(m, d, h):
    """Stage 3 (each iteration): the Newton increment and its convergence test. Returns CONVERGED,
    CONTINUE or an error status (negative codes are never used: errors are > 1)."""
    newton_residual(m, d, h)
    if newton_factor(m, d, h) != OK:
        return ERR_FACTOR
    return newton_increment(m, d, h)


@inline_kernel
def newton_residual(m, d, h):
    """Stage 3a: the right-hand side -bq [M qdd + Phi_q^T lambda* - Q] into d.r."""
    nq = m.nq
    bq = 0.25 * h * h
    # Newton increment dq = -A^-1 f with f = bq [M qdd + Phi_q^T (alpha Phi + lambda*) - Q],
    # corrected by multipliers mu so that the linearised constraints Phi + Phi_q dq = 0 hold
    # (mu = 0 away from singular positions). solve_constrained adds the -bq Phi_q^T alpha Phi
    # part itself, so the right-hand side here is -bq [M qdd + Phi_q^T lambda* - Q].
    r = d.r
    for i in range(nq):
        r[i] = 0.0
    matvec_add(m.m_env, m.first, m.ptr, m.perm, m.pinv, d.qdd, r, 1.0)
    jac_t_matvec_add(m, d, d.lam, r, 1.0)
    for i in range(nq):
        r[i] = -bq * (r[i] - d.force[i])


@inline_kernel
def newton_factor(m, d, h):
    """Stage 3b: the tangent's factor when this iteration refactors (wants_tangent). Returns OK or ERR_FACTOR."""
    if wants_tangent(m, d):
        if refresh_factor(m, d, 0.25 * h * h) != OK:
            return ERR_FACTOR
        d.newton[NW_AGE] = 0.0
    return OK


@inline_kernel
def newton_increment(m, d, h):
    """Stage 3c: the increment from d.r (stage 3a) and the factor (stage 3b), the step control and the
    convergence test. Returns CONVERGED, CONTINUE or an error status."""
    nq = m.nq
    nc = m.nc
    bq = 0.25 * h * h
    r = d.r
    solve_constrained(m, d, r, d.phi, bq, d.y, 0.1 * m.fset[FS_TOL_PHI], np.inf)
    # step control: a fraction lam_s of the increment (1 unless the iteration stopped contracting)
    lam_s = d.newton[NW_STEP]
    for i in range(nc):
        d.lam[i] += lam_s * d.mu[i]
    nrm = 0.0
    qmax = 1.0
    for i in range(nq):
        d.q[i] += lam_s * d.y[i]
        a = abs(d.y[i])
        if a > nrm:
            nrm = a
        a = abs(d.q[i])
        if a > qmax:
            qmax = a
    d.newton[NW_IT] += 1.0
    d.newton[NW_NRM] = nrm
    if not np.isfinite(nrm):
        d.stats[ST_LAST_RESIDUAL] = nrm
        return ERR_NONFINITE_STATE
    tol_phi = m.fset[FS_TOL_PHI]
    tol_dq = m.fset[FS_TOL_DQ] * (1.0 if m.iset[IS_ABSOLUTE_DQ] == 1 else qmax)
    if m.iset[IS_ERROR_TEST] == 0:
        # the last increment and the constraints at the iterate it was computed from
        if _max_abs(d.phi, nc) <= tol_phi and nrm <= tol_dq:
            return CONVERGED
    else:
        # the error of the new iterate: |dq| on the first iteration; afterwards, with the observed
        # contraction rate theta = |dq_k| / |dq_k-1| < 1, theta / (1 - theta) |dq_k| (the increments
        # left form a geometric series); and the constraints at the new iterate
        err = nrm
        if d.newton[NW_IT] >= 2.0 and nrm < d.newton[NW_PREV]:
            theta = nrm / d.newton[NW_PREV]
            err = theta / (1.0 - theta) * nrm
        if err <= tol_dq:
            if _max_abs(d.phi, nc) <= tol_phi:
                return CONVERGED
            c1 = 2.0 / h
            for i in range(nq):     # velocity rows (rolling) are stated on qd = (2/h) q + qhd
                d.qd[i] = c1 * d.q[i] + d.qhd[i]
            eval_constraints(m, d, d.q)
            if _max_abs(d.phi, nc) <= tol_phi:
                return CONVERGED
    # A slowly contracting modified Newton means the reused factor is too stale: refresh it
    # (not when it was just made: then the slowness is the problem's, not the factor's).
    d.newton[NW_AGE] += 1.0
    if d.newton[NW_AGE] >= 2 and d.newton[NW_IT] >= 2 and nrm > m.fset[FS_REUSE_RATE] * d.newton[NW_PREV]:
        d.flags[NEED_FACTOR] = 1
    _step_control(m, d, nrm)
    d.newton[NW_PREV] = nrm
    return CONTINUE


@inline_kernel
def _step_control(m, d, nrm):
    """The fraction of the next increment to apply. An iteration whose increment turns back on the last
    one (its largest component reverses) without contracting (|dq| at least FS_STALL_RATE of the last
    one) is cycling across a kink of the forces (a friction band, a tyre past its peak, a transmission
    switching between driving and driven): the next increments are halved (down to FS_MIN_STEP), which
    puts a two-point cycle's iterate between its two points, where the full increment shrinks. The
    fraction doubles back to 1 when the increment keeps its direction (a slow but monotone iteration
    keeps full steps) or halves in size; a cycle that merely shrinks slowly keeps its damping. The convergence
    test is always on the full increment, so a damped step accepts the same solution as a full one."""
    j = int(d.newton[NW_JMAX])
    turned = d.y[j] * d.newton[NW_YMAX] < 0.0
    jn = 0
    for i in range(m.nq):
        if abs(d.y[i]) > abs(d.y[jn]):
            jn = i
    d.newton[NW_JMAX] = jn
    d.newton[NW_YMAX] = d.y[jn]
    if d.newton[NW_IT] < 2.0:
        return
    lam_s = d.newton[NW_STEP]
    if turned and nrm >= m.fset[FS_STALL_RATE] * d.newton[NW_PREV]:
        lam_s *= 0.5
        if lam_s < m.fset[FS_MIN_STEP]:
            lam_s = m.fset[FS_MIN_STEP]
    elif lam_s < 1.0 and (not turned or nrm < 0.5 * d.newton[NW_PREV]):
        lam_s *= 2.0
        if lam_s > 1.0:
            lam_s = 1.0
    d.newton[NW_STEP] = lam_s


@kernel
def newton_failed(m, d):
    """Bookkeeping of a step whose Newton iterations ran out."""
    d.stats[ST_LAST_RESIDUAL] = d.newton[NW_NRM]
    d.flags[NEED_FACTOR] = 1
    d.stats[ST_LAST_ITER] = d.newton[NW_IT]
    d.stats[ST_ITER_TOTAL] += d.newton[NW_IT]
    return ERR_NEWTON


@stage_kernel
def finish_prepare(m, d, h):
    """Stage 4: the converged step's velocities, accelerations, constraints, multipliers, and the
    model's forces, with their tangent when the projections refactor (finish_refactors: W for their
    factor). A caller adds its own forces (and then their tangent to d.w_env) after this stage."""
    c1 = 2.0 / h
    c2 = 4.0 / (h * h)
    for i in range(m.nq):
        d.qd[i] = c1 * d.q[i] + d.qhd[i]
        d.qdd[i] = c2 * d.q[i] + d.qhdd[i]
    d.stats[ST_LAST_ITER] = d.newton[NW_IT]
    d.stats[ST_ITER_TOTAL] += d.newton[NW_IT]
    eval_constraints(m, d, d.q)
    phimax = 0.0
    for i in range(m.nc):
        d.lam[i] += d.alpha[i] * d.phi[i]
        a = abs(d.phi[i])
        if a > phimax:
            phimax = a
    if phimax > d.stats[ST_MAX_PHI]:
        d.stats[ST_MAX_PHI] = phimax
    if m.iset[IS_TANGENT_FORCES] == 1 and finish_evaluates(m, d):
        bad = eval_forces(m, d, d.q, d.qd, finish_refactors(m, d), 0.25 * h * h, 0.5 * h)
        if bad >= 0:
            d.stats[ST_FAIL_INDEX] = bad
            return ERR_NONFINITE_FORCE
    return OK


@kernel
def finish_evaluates(m, d):
    """True when stage 4 evaluates the forces at the converged q."""
    return m.iset[IS_FINISH_FORCES] == 1 or finish_refactors(m, d)


@kernel
def finish_refactors(m, d):
    """True when stage 5a makes a factor of its own at the converged q, so the finishing force evaluation
    must add its K and C to W; a model that keeps Newton's factor for the projections skips the tangent
    there (nothing reads that W: every refactorisation re-evaluates it first)."""
    return m.iset[IS_PROJECTION_FACTOR] == 1 or d.flags[HAVE_FACTOR] == 0


@stage_kernel
def finish_project(m, d, h):
    """Stage 5: refactor at the converged q, project velocities and accelerations, advance time."""
    if finish_factor(m, d, h) != OK:
        return ERR_FACTOR
    return finish_projections(m, d, h)


@inline_kernel
def finish_factor(m, d, h):
    """Stage 5a: the factor the projections use. Returns OK or ERR_FACTOR."""
    # The projections need the tangent at the converged q: the Newton factor was made at an earlier
    # iterate, and near singular positions the projection is sensitive to that difference. Models
    # without singular positions (a vehicle) may keep the Newton factor (IS_PROJECTION_FACTOR = 0).
    if finish_refactors(m, d):
        return refresh_factor(m, d, 0.25 * h * h)
    return OK


@inline_kernel
def finish_projections(m, d, h):
    """Stage 5b: project velocities and accelerations with the factor of stage 5a, advance time."""
    bq = 0.25 * h * h
    st = d.stats
    k1, gv = project(m, d, d.qd, d.phit, bq, m.fset[FS_TOL_VEL], m.fset[FS_TOL_VEL_FAIL])
    if k1 < 0:
        st[ST_LAST_RESIDUAL] = gv
        d.flags[NEED_FACTOR] = 1
        return ERR_PROJECTION
    hqd_rows(m, d, d.q, d.qd, False)    # the polynomial paths are finish_prepare's, at this q
    for i in range(m.nc):
        d.phit[i] = d.hqd[i] + d.phitt[i]  # phit now holds the acceleration right-hand side c
    k2, ga = project(m, d, d.qdd, d.phit, bq, m.fset[FS_TOL_ACC], m.fset[FS_TOL_ACC_FAIL])
    if k2 < 0:
        st[ST_LAST_RESIDUAL] = ga
        d.flags[NEED_FACTOR] = 1
        return ERR_PROJECTION
    for i in range(m.nq):
        if not (np.isfinite(d.qd[i]) and np.isfinite(d.qdd[i])):
            st[ST_FAIL_INDEX] = i
            return ERR_NONFINITE_STATE
    if m.iset[IS_PREDICTOR] == 1:
        for i in range(m.nq):
            d.pred[m.nq + i] = d.qdd[i]
            d.pred[2 * m.nq + i] = d.q[i] - d.pred[2 * m.nq + i]
        d.newton[NW_CORR] = -1.0 - d.newton[NW_CORR]
    d.t[0] += h
    st[ST_STEPS] += 1
    st[ST_PROJ_ITER] += k1 + k2
    if gv > st[ST_MAX_PHID]:
        st[ST_MAX_PHID] = gv
    if ga > st[ST_MAX_PHIDD]:
        st[ST_MAX_PHIDD] = ga
    return OK


@inline_kernel
def no_forces(m, d, args, tangent, bq, hc):
    """The applied forces of a model that has none besides its own (step_with's add_forces)."""
    return -1


@inline_kernel
def step_with(m, d, h, add_forces, args):
    """Advance d by one ALI3-P step of h seconds with the caller's applied forces inside the Newton
    iteration: ``add_forces(m, d, args, tangent, bq, hc)`` adds generalized forces to d.force (and, when
    `tangent`, their stiffness scaled by bq = h^2/4 and damping by hc = h/2 to d.w_env), and returns
    the index of a non-finite force or -1. `add_forces` is a compiled function fixed at compile time
    (an assembly's force kernel), `args` a tuple of its arrays. Returns a status code (model.OK)."""
    return step_with_forces(m, d, h, add_forces, add_forces, args)


@inline_kernel
def step_with_forces(m, d, h, newton_forces, finish_forces, args):
    """step_with with one force function for the Newton iterations and another for the evaluation at the
    converged q (the same forces: `finish_forces` is a call of the compiled force kernel where
    `newton_forces` may be its body inlined, so that the body is compiled once per step).

    The step's stages (newton_prepare, newton_update, finish_prepare, finish_project) and most kernels
    they call with the model and the state (step_begin, eval_constraints, eval_forces, refresh_factor,
    solve_constrained, project) are stage kernels (rtsim.jit.stage_kernel), compiled into the step: a call
    copies every array of its tuples into its arguments (rtsim.jit says what that cost). The factorisation
    itself and the substitutions, the Jacobian products and the drivers stay calls."""
    bq = 0.25 * h * h
    hc = 0.5 * h
    step_begin(m, d, h)
    for _ in range(m.iset[IS_MAX_ITER]):
        status = newton_prepare(m, d, h)
        if status != OK:
            return status
        bad = newton_forces(m, d, args, wants_tangent(m, d), bq, hc)
        if bad >= 0:
            d.stats[ST_FAIL_INDEX] = bad
            return ERR_NONFINITE_FORCE
        status = newton_update(m, d, h)
        if status == CONVERGED:
            break
        if status != CONTINUE:
            return status
    else:
        return newton_failed(m, d)
    status = finish_prepare(m, d, h)
    if status != OK:
        return status
    if finish_evaluates(m, d):
        bad = finish_forces(m, d, args, finish_refactors(m, d), bq, hc)
        if bad >= 0:
            d.stats[ST_FAIL_INDEX] = bad
            return ERR_NONFINITE_FORCE
    return finish_project(m, d, h)


@kernel
def step(m, d, h):
    """Advance d by one ALI3-P step of h seconds. Returns a status code (model.OK on success)."""
    return step_with(m, d, h, no_forces, ())


@kernel
def advance(m, d, h, nsteps, stride, out_t, out_q, out_qd):
    """Run nsteps steps, storing t, q, qd every `stride` steps (row 0 = the initial state) into the
    preallocated outputs. Returns (status, steps done)."""
    nrec = out_t.shape[0]
    if nrec > 0:
        out_t[0] = d.t[0]
        for i in range(m.nq):
            out_q[0, i] = d.q[i]
            out_qd[0, i] = d.qd[i]
    rec = 1
    for n in range(nsteps):
        status = step(m, d, h)
        if status != OK:
            return status, n
        if (n + 1) % stride == 0 and rec < nrec:
            out_t[rec] = d.t[0]
            for i in range(m.nq):
                out_q[rec, i] = d.q[i]
                out_qd[rec, i] = d.qd[i]
            rec += 1
    return OK, nsteps
