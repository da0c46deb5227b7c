"""The compiled multibody model and its state, as plain arrays (MuJoCo-style model/data separation).

`Model` is immutable after compilation: geometry, masses, constraint and force tables, the sparsity
layout of the tangent matrix. `Data` holds everything that changes: coordinates q, velocities qd,
accelerations qdd, multipliers, and the preallocated workspaces of the integrator. Several `Data`
may share one `Model`. Kernels are pure functions of (Model, Data) and never allocate per step.

Every constraint and force row refers to its coordinates through up to five *vector references*
(slots A..E), each three coordinate indices (or -1) plus three constants, so that a fixed ground point
is a reference with indices -1 and constant components, and a moving point is a reference to its
coordinates. Slots 15-17 are optional scalar coordinates (relative angles or distances). A linear row
uses all 18 slots as (coordinate index, coefficient) pairs.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np

# Slots of a constraint/force row: 5 vector refs x 3 components + 3 scalar coordinates.
NSLOT = 18
NREF = 5
SCALAR = 15
SCALAR2 = 16
SCALAR3 = 17

# Constraint kinds.
CON_LINEAR = 0   # sum_s cst[s] * q[idx[s]] + par[0] - f(t) = 0
CON_DOT = 1      # (A - B).(C - D) - par[0] - par[1] s - par[2] s^2 - f(t) = 0
CON_ANGLE2D = 2  # (A - B) x e(theta) = dx sin(theta) - dy cos(theta) = 0, theta = q[idx[12]]
CON_ANGLE3D = 3  # ((A x B).C) cos(theta) - (A.B) sin(theta) = 0: angle from A to B about axis C
CON_POLY_POINT = 4  # A_c - B_c - sum_k p_k(z, s) E_k,c = 0 with frame vectors E_0..2 = C, D, E,
#                     z = q[idx[SCALAR]], s = q[idx[SCALAR2]] (or 0), p = polynomial par[0], c = par[1]
CON_CRANK_ROD = 5   # (|d|^2 - L^2) / (2 L) = 0, planar crank and rod: a crank of angle theta = q[idx[SCALAR]]
#                     about its pivot, a rod of length L to a slider at travel x = q[idx[SCALAR2]];
#                     d = c + R(theta) a - (0, dir x), constants (c0, c1, a0) in slot A, (a1, dir, L) in B
CON_DISC_CONTACT = 6  # knife-edge disc on the plane z = h: A_z - R sqrt(1 - B_z^2) - h = 0, A the disc's centre,
#                       B its unit axle; par = (R, h)
CON_DISC_ROLL = 7     # velocity level (nonholonomic): component c = par[1] of the velocity of the disc's material
#                       point at the contact, A'_c + (rho.C) C'_c + (rho.D) D'_c = 0, with A the centre, B the
#                       axle, C and D the disc's in-plane unit vectors, rho = -R nu the contact point from the
#                       centre, nu = unit(e_z - B_z B); par = (R, c). Inside a step its Jacobian row is
#                       (2/h) times the velocity coefficients: the trapezoidal rule makes qd = (2/h) q + const,
#                       so the row is a function of q the Newton iteration can penalise like a position row.
CON_KIND_NAMES = ("linear", "dot", "angle2d", "angle3d", "poly_point", "crank_rod", "disc_contact", "disc_roll")
VELOCITY_KINDS = (CON_DISC_ROLL,)   # rows stated on velocities: not part of the position assembly

# Force kinds.
FRC_SPRING = 0      # point-to-point spring-damper-actuator between A and B: par = k, c, L0, F0
FRC_COORD = 1       # on scalar coordinate s: par = F0, k, s0, c, driver gain (F = F0 + g f(t) - k(s - s0) - c sdot)
FRC_KIND_NAMES = ("spring", "coordinate")

# Driver (rheonomic function of time) kinds: f(t), f'(t), f''(t).
DRV_POLY = 0       # par[0..3]: c0 + c1 t + c2 t^2 + c3 t^3
DRV_SINE = 1       # par[0..3]: offset + amplitude sin(omega t + phase)
DRV_EXTERNAL = 2   # value, rate, acceleration set by the caller in data.drv_ext before each step

EARTH_GRAVITY = 9.81   # m/s^2: the magnitude of the gravity every vehicle's model is built with (its vector
#                         (0, 0, -EARTH_GRAVITY), z up), and of the g in which accelerations are shown

# Integer settings (Model.iset) and float settings (Model.fset).
IS_MAX_ITER = 0        # Newton iterations per step before giving up
IS_MAX_PROJ = 1        # augmented-Lagrangian projection iterations
IS_TANGENT_FORCES = 2  # 1 if any force contributes stiffness/damping to the tangent
IS_REUSE_STEPS = 3     # 1: keep the factorization across steps while Newton contracts; 0: refactor each step
IS_PROJECTION_FACTOR = 4  # 1: refactor at the converged q for the projections; 0: reuse Newton's factor
IS_ERROR_TEST = 5      # Newton stops on 0: the last increment and the constraints it started from;
#                        1: the estimated error of the new iterate and the constraints there
IS_PREDICTOR = 6       # Newton's first iterate: 0 the Taylor predictor q + h qd + h^2/2 qdd; 1 the trapezoidal
#                        rule with qdd at the step's end extrapolated linearly from the last two steps
IS_ABSOLUTE_DQ = 7     # 1: Newton's increment tolerance FS_TOL_DQ is absolute (m, rad), not relative to max(1, max|q|)
IS_FINISH_FORCES = 8   # 1: the forces are evaluated again at the converged q; 0: the last Newton evaluation's
#                        stand (Settings.finish_forces)
NISET = 9
FS_TOL_DQ = 0          # Newton increment tolerance (coordinate units)
FS_TOL_PHI = 1         # position constraint tolerance
FS_TOL_VEL = 2         # velocity constraint tolerance
FS_TOL_ACC = 3         # acceleration constraint tolerance
FS_REUSE_RATE = 4      # Newton contraction rate above which the factorization is refreshed
FS_TOL_VEL_FAIL = 5    # velocity constraint residual above which a projection fails
FS_TOL_ACC_FAIL = 6    # acceleration constraint residual above which a projection fails
FS_STALL_RATE = 7      # Newton: an increment at least this fraction of the last one (no contraction) halves the step
FS_MIN_STEP = 8        # Newton: the smallest fraction of the increment a damped iteration applies
FS_GRAVITY = 9         # 3 slots: the gravity vector (m/s^2, world axes; z up: (0, 0, -9.81) on level ground)
#                        q_grav is formed from, for whoever reads gravity from the model (IMU, references)
NFSET = 12

# Status codes returned by kernels (mapped to typed exceptions by rtsim.mbs.simulation).
OK = 0
ERR_NEWTON = 1
ERR_NONFINITE_FORCE = 2
ERR_NONFINITE_STATE = 3
ERR_FACTOR = 4
ERR_PROJECTION = 5

# Statistics slots (Data.stats).
ST_STEPS = 0
ST_ITER_TOTAL = 1
ST_FACTORIZATIONS = 2
ST_LAST_ITER = 3
ST_LAST_RESIDUAL = 4
ST_MAX_PHI = 5
ST_MAX_PHID = 6
ST_MAX_PHIDD = 7
ST_PROJ_ITER = 8
ST_FAIL_INDEX = 9
NSTATS = 10

Model = namedtuple("Model", [
    "nq", "nc", "dim",
    # constraints
    "con_kind", "con_idx", "con_cst", "con_par", "con_drv",
    "con_nact", "con_act",   # per row: number of slots with a coordinate, and those slots first
    # drivers
    "drv_kind", "drv_par",
    # forces
    "frc_kind", "frc_idx", "frc_cst", "frc_par", "frc_drv",
    # constant generalized gravity force
    "q_grav",
    # polynomial paths p(z, s) of CON_POLY_POINT rows: coefficients (npoly, 3, nterm), exponents (nterm, 2)
    "poly_coef", "poly_exp",
    # tangent-matrix envelope layout and the constant mass matrix in it
    "perm", "pinv", "first", "ptr", "m_env",
    # the tangent's Cholesky factor (rtsim.mbs.sparse): ordering, pattern and update lists, the envelope
    # slot of W for each of its positions (-1: none), and the constraint rows' contributions
    # bq alpha_i Phi_q[i, s] Phi_q[i, u] mult (row, slots s and u, position in the factor's pattern, mult)
    "fperm", "fpinv", "fcolptr", "frowidx", "fuptr", "fupos", "fuend", "fw_map",
    "asm_row", "asm_s", "asm_u", "asm_pos", "asm_mult",
    # settings
    "iset", "fset",
])

# Kernels that are not inlined take Data by value, flattened into scalar arguments: one more array field
# (a 2-D history of the predictor, tried) made the motorcycle's force kernel about 0.7 us a call slower
# inside the step. Reuse or widen existing fields before adding one, and time the step when you do.
Data = namedtuple("Data", [
    "t",              # (1,) time, s
    "dt",             # (1,) step the factorization and alpha were made for, s
    "q", "qd", "qdd",
    "lam",            # (nc,) augmented-Lagrangian multipliers lambda*
    "alpha",          # (nc,) penalty factors (diagonal of alpha)
    "q_ext",          # (nq,) external generalized forces set by the caller (held over a step)
    "drv_ext",        # (nd, 3) external driver value, rate, acceleration
    "drv",            # (nd, 3) evaluated drivers at the current time
    "phi", "jac", "phit", "phitt", "hqd",   # constraint values, Jacobian values, time derivatives, (Phi_q)' qd
    "force", "w_env",  # forces, W = M + dt/2 C + dt^2/4 K (= M without K, C) in envelope storage
    "a_env", "l_env",  # the tangent A = W + bq Phi_q^T alpha Phi_q and its factor, in the factor's pattern
    "pred",           # (6 nq,) predictor history (IS_PREDICTOR): qdd at the start and at the end of the last
    #                   step, its predictor base (during a step) or Newton's correction to it (after), and the
    #                   corrections of the three steps before
    "qhd", "qhdd", "r", "x", "y", "z", "work", "sig", "g", "sp", "mu",
    "flags",          # int64 [have_factor, need_factor]
    "newton",         # float64 (8,) Newton bookkeeping between the stages of a step (and the predictor's
    #                   count of corrections, kept across steps)
    "poly_cache",     # float64 (npoly, 3, 6) polynomial paths and derivatives shared by a poly point's rows
    "stats",          # float64 (NSTATS,)
])


def gravity(model: Model) -> np.ndarray:
    """The model's gravity vector (3,), m/s^2 in world axes (the builder's ``gravity``; zeros without one)."""
    return np.array(model.fset[FS_GRAVITY:FS_GRAVITY + 3])


def make_data(model: Model, q0: np.ndarray, qd0: np.ndarray | None = None, t0: float = 0.0) -> Data:
    """Allocate a fresh state for `model` with coordinates q0 (not assembled here)."""
    nq, nc = model.nq, model.nc
    nd = model.drv_kind.shape[0]
    nfac = model.frowidx.shape[0]
    z = lambda n: np.zeros(n)  # noqa: E731
    return Data(
        t=np.array([t0]), dt=np.zeros(1),
        q=np.array(q0, dtype=np.float64).copy(),
        qd=z(nq) if qd0 is None else np.array(qd0, dtype=np.float64).copy(),
        qdd=z(nq), lam=z(nc), alpha=z(nc), q_ext=z(nq),
        drv_ext=np.zeros((nd, 3)), drv=np.zeros((nd, 3)),
        phi=z(nc), jac=np.zeros((nc, NSLOT)), phit=z(nc), phitt=z(nc), hqd=z(nc),
        force=z(nq), w_env=model.m_env.copy(), a_env=z(nfac), l_env=z(nfac),
        pred=np.full(6 * nq, np.nan), qhd=z(nq), qhdd=z(nq), r=z(nq), x=z(nq), y=z(nq), z=z(max(nq, nc)),
        work=z(nq), sig=z(nc), g=z(nc), sp=z(nc), mu=z(nc),
        flags=np.zeros(2, dtype=np.int64),
        newton=np.zeros(8),
        poly_cache=np.zeros((model.poly_coef.shape[0], 3, 6)),
        stats=np.zeros(NSTATS),
    )
