"""Magic Formula 5.2 tyre kernels (steady state, combined slip) and the transient-slip contact model
that makes them usable from standstill in a fixed-step 1 ms loop.

All kernels are `rtsim.jit.kernel`s (numba, NRT off): they take the packed parameter array `p` of
`rtsim.vehicle.kit.tyre.tir` (indices `P_*`) and scalars, and return tuples of floats or write into
caller-provided arrays; none allocates.

Axes and signs: ISO 8855 / TYDEX W-axes of the wheel: x forward along the wheel heading (in the road
plane), y left, z up (road normal).
- Longitudinal slip  kappa = -(Vx - omega*Re)/|Vx|          (> 0 driving, -1 locked wheel)
- Slip angle         alpha = atan(Vsy/|Vx|)                  (> 0 when the contact point slides to the
                                                             left of the heading; gives Fy < 0)
- Inclination gamma: rotation of the wheel about its x axis (rad).
- Outputs: Fx (forward), Fy (left), Mz (about the road normal, positive turning left), My (about the
  wheel spin axis y, positive in the sense of forward rolling, so rolling resistance is negative
  when rolling forward). Forces act on the wheel at the contact point.

Steady-state MF 5.2 (`mf52_forces`)
-----------------------------------
Pacejka, Tyre and Vehicle Dynamics (2nd ed., ch. 4, eqs. 4.E1-4.E78) in the MF-Tyre 5.2 form:
pure slip Fx0 (PCX1, PDX*, PEX*, PKX*, PHX*, PVX*), Fy0 (PCY1, PDY*, PEY*, PKY*, PHY*, PVY*),
combined slip by the cosine weighting functions Gxa (RBX*, RCX1, REX*, RHX1) and Gyk (RBY*, RCY1, REY*,
RHY*) plus the kappa-induced side force SVyk (RVY*), aligning moment Mz = -t (Fy - SVyk) + Mzr + s Fx
(QBZ*, QCZ1, QDZ*, QEZ*, QHZ*, SSZ*, equivalent slips alpha_eq), rolling resistance
My = -R0 Fz (QSY1 + QSY2 Fx/Fz0 + QSY3 |Vx/V0| + QSY4 (Vx/V0)^4) LMY. The slip angle enters as
alpha* = tan(alpha). The road friction scale `mu` multiplies LMUX and LMUY (the MF's LMUX*, LMUY*):
it scales the peaks and leaves the slip stiffnesses unchanged. Missing combined-slip coefficients
(RBX1 = RBY1 = 0) mean no interaction (Gxa = Gyk = 1).

Low-speed factors of the steady formula: below VXLOW ([MODEL], default 1 m/s) the force offsets
(SHx, SVx, SHy, SVy, SVyk) are faded out with r = sin(pi/2 |Vx|/VXLOW), and the trail/residual parts
of Mz and the rolling-resistance moment follow s = sin(pi/2 Vx/VXLOW) (a smooth sign of Vx: they flip
when reversing and vanish at standstill). So a tyre at standstill with zero slip gives exactly zero
force and moment, and nothing switches discontinuously around Vx = 0.

Low speed: the transient-slip (contact deflection) model
--------------------------------------------------------
The steady slip kappa = -(Vx - omega Re)/max(|Vx|, V_low) is a damper of coefficient Kx/V_low at low
speed: about 60 kN s/m here, which against the ~10 kg equivalent mass of a wheel's spin inertia gives
a time constant of ~0.2 ms, far below a 1 ms explicit step (it chatters), and it cannot hold a car at
rest on a slope (it creeps at F/c). Instead, as in MF-Tyre's transient mode (Pacejka ch. 7-8), each
tyre has two states, the contact-point deflections u (longitudinal) and v (lateral), in m:

    du/dt = -Vsx - |Vx| u / sigma_kappa          Vsx = Vx - omega Re   (slip velocity)
    dv/dt =  Vsy - |Vx| v / sigma_alpha          Vsy = lateral velocity of the contact point

with relaxation lengths sigma_kappa, sigma_alpha. The slips fed to the force law are

    kappa' = (u + d du/dt) / sigma_kappa,    alpha' = atan((v + d dv/dt) / sigma_alpha)

In steady rolling u/sigma_kappa -> -Vsx/|Vx| = kappa and v/sigma_alpha -> tan(alpha): the steady MF is
recovered, reached with the time constant sigma/|Vx|. At standstill (Vx = 0) the deflections are the
integrals of the slip velocities: the tyre is a spring of stiffness C = K/sigma (Kxk/sigma_kappa
~350 kN/m, |Kya|/sigma_alpha ~130 kN/m at FNOMIN for the shipped tyre) with a parallel damper of
time constant d (c = C d): a damped spring in x and y, which holds a braked car on a slope without
creep and starts a driven wheel from rest without sign chatter. The damping acts on the deflection
rate, so it biases no steady state:
    d = DAMP_RESIDUAL + DAMP_VLOW * 0.5 (1 + cos(pi |Vx| / VXLOW))  for |Vx| < VXLOW,
    d = DAMP_RESIDUAL                                            above
([STRUCTURAL] keys of MF 6.1; defaults 0.002 s and 0.001 s as in TNO's example file; the shipped
155/80 R13 file uses 0.002 s and 0.006 s, i.e. c ~ 2.8 kN s/m longitudinally at standstill:
damping ratio ~0.16 for the 850 kg car on its four tyres, ~0.75 for a wheel's spin mode).

Relaxation lengths (`relaxation_lengths`):
- MF 5.2 when PTX1 > 0: sigma_kappa = Fz (PTX1 + PTX2 dfz) exp(-PTX3 dfz) R0/FNOMIN LSGKP; else
  Kxk/LONGITUDINAL_STIFFNESS when that is > 0 (MF 6.1); else Kxk/C with C chosen so that
  sigma_kappa(FNOMIN) = DEFAULT_SIGMA_KAPPA = 0.15 m.
- MF 5.2 when PTY1 > 0: sigma_alpha = PTY1 sin(2 atan(Fz/(PTY2 Fz0'))) (1 - PKY3 |gamma|) R0 LFZO LSGAL;
  else |Kya|/LATERAL_STIFFNESS when > 0; else sigma_alpha(FNOMIN) = DEFAULT_SIGMA_ALPHA = 0.30 m.
  Both are floored at SIGMA_MIN = 5 mm (they vanish with Fz in MF 5.2).

Wind-up limit: when the contact slides at (near) standstill, |u| would grow without bound (u' = -Vsx
with nothing to stop it) and take as long to unwind. `advance_deflections` therefore limits
|u| <= sigma_kappa max(kappa_peak, |Vsx|/max(|Vx|, VXLOW)) and likewise v, where kappa_peak (tan
alpha_peak) is the pure-slip slip at which the MF force peaks: the deflection never exceeds what the
available friction can hold, and the limit never binds in rolling (the steady state lies inside it).

Use in a fixed-step loop (state = float64 array (n_tyres, N_SLIP_STATES), zeros at rest):
    1. kappa, alpha = transient_slip(p, state, i, Fz, gamma, Vx, Vsy, omega, Re)
    2. Fx, Fy, Mz, My = mf52_forces(p, Fz, kappa, alpha, gamma, Vx, mu)   (or linear.linear_forces)
    3. advance the mechanics by dt
    4. advance_deflections(p, state, i, Fz, gamma, Vx, Vsy, omega, Re, dt)   (with the new velocities)
`advance_deflections` integrates the deflection equations exactly for inputs frozen over the step
(exponential update), so it is stable at any speed and step; `deflection_rates` gives the right-hand
sides for callers that integrate the states themselves.

Radii: `loaded_radius` = R0 - Fz/Cz; `effective_rolling_radius` (MF 6.1 eq.):
Re = R0 - (FNOMIN/Cz) (DREFF atan(BREFF Fz/FNOMIN) + FREFF Fz/FNOMIN) (with no BREFF/DREFF/FREFF
in the file, FREFF = 1/3: Re = R0 - rho/3).
"""
from __future__ import annotations

from math import atan, cos, exp, pi, sin, sqrt, tan

import numpy as np

from rtsim.jit import inline_kernel, kernel

from .low_speed import low_speed_damping, low_speed_fade
from .tir import (P_BREFF, P_DAMP_RESIDUAL, P_DAMP_VLOW, P_DREFF, P_FNOMIN, P_FREFF, P_LATERAL_STIFFNESS,
                  P_LCX, P_LCY, P_LEX, P_LEY, P_LFZO, P_LGAX, P_LGAY, P_LGAZ, P_LHX, P_LHY, P_LKX, P_LKY,
                  P_LMUX, P_LMUY, P_LMY, P_LONGITUDINAL_STIFFNESS, P_LONGVL, P_LRES, P_LS, P_LSGAL,
                  P_LSGKP, P_LTR, P_LVX, P_LVY, P_LVYKA, P_LXAL, P_LYKA, P_PCX1, P_PCY1, P_PDX1, P_PDX2,
                  P_PDX3, P_PDY1, P_PDY2, P_PDY3, P_PEX1, P_PEX2, P_PEX3, P_PEX4, P_PEY1, P_PEY2, P_PEY3,
                  P_PEY4, P_PHX1, P_PHX2, P_PHY1, P_PHY2, P_PHY3, P_PKX1, P_PKX2, P_PKX3, P_PKY1, P_PKY2,
                  P_PKY3, P_PTX1, P_PTX2, P_PTX3, P_PTY1, P_PTY2, P_PVX1, P_PVX2, P_PVY1, P_PVY2, P_PVY3,
                  P_PVY4, P_QBZ1, P_QBZ2, P_QBZ3, P_QBZ4, P_QBZ5, P_QBZ9, P_QBZ10, P_QCZ1, P_QDZ1, P_QDZ2,
                  P_QDZ3, P_QDZ4, P_QDZ6, P_QDZ7, P_QDZ8, P_QDZ9, P_QEZ1, P_QEZ2, P_QEZ3, P_QEZ4, P_QEZ5,
                  P_QHZ1, P_QHZ2, P_QHZ3, P_QHZ4, P_QSY1, P_QSY2, P_QSY3, P_QSY4, P_RBX1, P_RBX2, P_RBX3,
                  P_RBY1, P_RBY2, P_RBY3, P_RCX1, P_RCY1, P_REX1, P_REX2, P_REY1, P_REY2, P_RHX1, P_RHY1,
                  P_RHY2, P_RVY1, P_RVY2, P_RVY3, P_RVY4, P_RVY5, P_RVY6, P_SSZ1, P_SSZ2, P_SSZ3, P_SSZ4,
                  P_UNLOADED_RADIUS, P_VERTICAL_DAMPING, P_VERTICAL_STIFFNESS, P_VXLOW)

#: transient-slip state slots (per tyre row of the caller's state array)
S_U = 0            # longitudinal contact deflection u [m]
S_V = 1            # lateral contact deflection v [m]
N_SLIP_STATES = 2

DEFAULT_SIGMA_KAPPA = 0.15     # m, when the file has neither PTX1 nor LONGITUDINAL_STIFFNESS
DEFAULT_SIGMA_ALPHA = 0.30     # m, when the file has neither PTY1 nor LATERAL_STIFFNESS
SIGMA_MIN = 0.005              # m
ALPHA_MAX = 1.5                # rad: |alpha| is clipped here before tan()
_EPS = 1e-9
_BIG = 1e3                     # "no peak" slip limit


# ---- small helpers --------------------------------------------------------------------------------
@inline_kernel
def _sgn(x):
    return 1.0 if x >= 0.0 else -1.0


@inline_kernel
def _mf_sin(b, c, d, e, x):
    bx = b * x
    return d * sin(c * atan(bx - e * (bx - atan(bx))))


@inline_kernel
def _mf_cos(b, c, e, x):
    bx = b * x
    return cos(c * atan(bx - e * (bx - atan(bx))))


@inline_kernel
def _cos_atan(x):
    """cos(atan(x)) = 1 / sqrt(1 + x^2), without the two transcendental calls."""
    return 1.0 / sqrt(1.0 + x * x)


@inline_kernel
def _sin_2atan(x):
    """sin(2 atan(x)) = 2 x / (1 + x^2)."""
    return 2.0 * x / (1.0 + x * x)


@inline_kernel
def _kxk(p, fz, dfz):
    return fz * (p[P_PKX1] + p[P_PKX2] * dfz) * exp(p[P_PKX3] * dfz) * p[P_LKX]


@inline_kernel
def _kya(p, fz, fz0, gy):
    return (p[P_PKY1] * fz0 * _sin_2atan(fz / (p[P_PKY2] * fz0))
            * (1.0 - p[P_PKY3] * abs(gy)) * p[P_LKY])


@inline_kernel
def _rolling_moment(p, fz, fx, vx, s_low):
    q = vx / p[P_LONGVL]
    mag = fz * p[P_UNLOADED_RADIUS] * (p[P_QSY1] + p[P_QSY2] * fx / p[P_FNOMIN] + p[P_QSY3] * abs(q)
                                       + p[P_QSY4] * q * q * q * q) * p[P_LMY]
    return -s_low * mag


@kernel
def rolling_resistance_moment(p, fz, fx, vx):
    """My [N m] (MF 5.2, QSY1..QSY4): opposes rolling; -Fz R0 QSY1 LMY when rolling forward slowly
    (QSY3/4 terms are speed dependent), smoothly zero at Vx = 0."""
    if not fz > 0.0:
        return 0.0
    _, s_low = low_speed_fade(vx, p[P_VXLOW])
    return _rolling_moment(p, fz, fx, vx, s_low)


# ---- steady-state Magic Formula 5.2 ---------------------------------------------------------------
@kernel
def mf52_forces(p, fz, kappa, alpha, gamma, vx, mu):
    """(Fx, Fy, Mz, My) [N, N, N m, N m] of the steady-state MF 5.2 with combined slip.

    fz: vertical load [N] (<= 0: airborne, all zero); kappa: longitudinal slip; alpha: slip angle [rad]
    (clipped to +-ALPHA_MAX); gamma: inclination [rad]; vx: forward speed of the wheel centre along the
    heading [m/s] (only for the low-speed factors and My); mu: road friction scale (1 nominal)."""
    if not fz > 0.0:
        return 0.0, 0.0, 0.0, 0.0
    if mu < 0.0:
        mu = 0.0
    if alpha > ALPHA_MAX:
        alpha = ALPHA_MAX
    elif alpha < -ALPHA_MAX:
        alpha = -ALPHA_MAX
    r_low, s_low = low_speed_fade(vx, p[P_VXLOW])
    fz0 = p[P_FNOMIN] * p[P_LFZO]
    dfz = (fz - fz0) / fz0
    r0 = p[P_UNLOADED_RADIUS]
    lmux = p[P_LMUX] * mu
    lmuy = p[P_LMUY] * mu
    gx = gamma * p[P_LGAX]
    gy = gamma * p[P_LGAY]
    gz = gamma * p[P_LGAZ]
    ta = tan(alpha)              # alpha*
    ca = cos(alpha)

    # -- longitudinal, pure slip (4.E9-4.E18)
    shx = (p[P_PHX1] + p[P_PHX2] * dfz) * p[P_LHX] * r_low
    kx = kappa + shx
    cx = p[P_PCX1] * p[P_LCX]
    mux = (p[P_PDX1] + p[P_PDX2] * dfz) * (1.0 - p[P_PDX3] * gx * gx) * lmux
    dx = mux * fz
    kxk = _kxk(p, fz, dfz)
    ex = (p[P_PEX1] + p[P_PEX2] * dfz + p[P_PEX3] * dfz * dfz) * (1.0 - p[P_PEX4] * _sgn(kx)) * p[P_LEX]
    if ex > 1.0:
        ex = 1.0
    bx = kxk / (cx * dx + _EPS * _sgn(dx))
    svx = fz * (p[P_PVX1] + p[P_PVX2] * dfz) * p[P_LVX] * lmux * r_low
    fx0 = _mf_sin(bx, cx, dx, ex, kx) + svx

    # -- lateral, pure slip (4.E19-4.E30, MF 5.2 camber terms)
    kya = _kya(p, fz, fz0, gy)
    shy = ((p[P_PHY1] + p[P_PHY2] * dfz) * p[P_LHY] + p[P_PHY3] * gy) * r_low
    ay = ta + shy
    cy = p[P_PCY1] * p[P_LCY]
    muy = (p[P_PDY1] + p[P_PDY2] * dfz) * (1.0 - p[P_PDY3] * gy * gy) * lmuy
    dy = muy * fz
    ey = (p[P_PEY1] + p[P_PEY2] * dfz) * (1.0 - (p[P_PEY3] + p[P_PEY4] * gy) * _sgn(ay)) * p[P_LEY]
    if ey > 1.0:
        ey = 1.0
    by = kya / (cy * dy + _EPS * _sgn(dy))
    svy = fz * ((p[P_PVY1] + p[P_PVY2] * dfz) * p[P_LVY] + (p[P_PVY3] + p[P_PVY4] * dfz) * gy) * lmuy * r_low
    fy0 = _mf_sin(by, cy, dy, ey, ay) + svy

    # -- combined slip (4.E50-4.E67)
    bxa = (p[P_RBX1] + p[P_RBX3] * gx * gx) * _cos_atan(p[P_RBX2] * kappa) * p[P_LXAL]
    cxa = p[P_RCX1]
    exa = p[P_REX1] + p[P_REX2] * dfz
    if exa > 1.0:
        exa = 1.0
    shxa = p[P_RHX1]
    gxa = _mf_cos(bxa, cxa, exa, ta + shxa) / _mf_cos(bxa, cxa, exa, shxa)
    fx = gxa * fx0

    dvyk = muy * fz * (p[P_RVY1] + p[P_RVY2] * dfz + p[P_RVY3] * gy) * _cos_atan(p[P_RVY4] * ta)
    svyk = dvyk * sin(p[P_RVY5] * atan(p[P_RVY6] * kappa)) * p[P_LVYKA] * r_low
    shyk = p[P_RHY1] + p[P_RHY2] * dfz
    cyk = p[P_RCY1]
    eyk = p[P_REY1] + p[P_REY2] * dfz
    if eyk > 1.0:
        eyk = 1.0
    byk = p[P_RBY1] * _cos_atan(p[P_RBY2] * (ta - p[P_RBY3])) * p[P_LYKA]
    gyk = _mf_cos(byk, cyk, eyk, kappa + shyk) / _mf_cos(byk, cyk, eyk, shyk)
    fy = gyk * fy0 + svyk

    # -- aligning moment (4.E31-4.E49, combined 4.E71-4.E78, MF 5.2 form)
    lmuy_g = lmuy if lmuy > _EPS else _EPS
    kya_p = kya + _EPS * _sgn(kya)
    sht = p[P_QHZ1] + p[P_QHZ2] * dfz + (p[P_QHZ3] + p[P_QHZ4] * dfz) * gz
    at = ta + sht
    ar = ta + shy + svy / kya_p
    bt = ((p[P_QBZ1] + p[P_QBZ2] * dfz + p[P_QBZ3] * dfz * dfz)
          * (1.0 + p[P_QBZ4] * gz + p[P_QBZ5] * abs(gz)) * p[P_LKY] / lmuy_g)
    ct = p[P_QCZ1]
    dt = fz * (p[P_QDZ1] + p[P_QDZ2] * dfz) * (1.0 + p[P_QDZ3] * gz + p[P_QDZ4] * gz * gz) * (r0 / fz0) * p[P_LTR]
    et = ((p[P_QEZ1] + p[P_QEZ2] * dfz + p[P_QEZ3] * dfz * dfz)
          * (1.0 + (p[P_QEZ4] + p[P_QEZ5] * gz) * (2.0 / pi) * atan(bt * ct * at)))
    if et > 1.0:
        et = 1.0
    br = p[P_QBZ9] * p[P_LKY] / lmuy_g + p[P_QBZ10] * by * cy
    dr = fz * ((p[P_QDZ6] + p[P_QDZ7] * dfz) * p[P_LRES] + (p[P_QDZ8] + p[P_QDZ9] * dfz) * gz) * r0 * lmuy
    kk = kxk / kya_p * kappa
    at_eq = sqrt(at * at + kk * kk) * _sgn(at)
    ar_eq = sqrt(ar * ar + kk * kk) * _sgn(ar)
    t = dt * _mf_cos(bt, ct, et, at_eq) * ca
    mzr = dr * _cos_atan(br * ar_eq) * ca
    s = r0 * (p[P_SSZ1] + p[P_SSZ2] * (fy / fz0) + (p[P_SSZ3] + p[P_SSZ4] * dfz) * gz) * p[P_LS]
    mz = s_low * (-t * (fy - svyk) + mzr) + s * fx

    my = _rolling_moment(p, fz, fx, vx, s_low)
    return fx, fy, mz, my


# ---- derived quantities ---------------------------------------------------------------------------
@kernel
def slip_stiffnesses(p, fz, gamma):
    """(Kxk, Kya): dFx/dkappa [N] and dFy/dalpha [N/rad] at zero slip (no offsets) at load fz:
    Kxk = Fz (PKX1 + PKX2 dfz) exp(PKX3 dfz) LKX,
    Kya = PKY1 Fz0' sin(2 atan(Fz/(PKY2 Fz0'))) (1 - PKY3 |gamma|) LKY  (< 0: ISO sign)."""
    if not fz > 0.0:
        return 0.0, 0.0
    fz0 = p[P_FNOMIN] * p[P_LFZO]
    dfz = (fz - fz0) / fz0
    return _kxk(p, fz, dfz), _kya(p, fz, fz0, gamma * p[P_LGAY])


@kernel
def relaxation_lengths(p, fz, gamma):
    """(sigma_kappa, sigma_alpha) [m] at load fz (see the module docstring), >= SIGMA_MIN."""
    if fz < 0.0:
        fz = 0.0
    fnom = p[P_FNOMIN]
    fz0 = fnom * p[P_LFZO]
    dfz = (fz - fz0) / fz0
    r0 = p[P_UNLOADED_RADIUS]
    if p[P_PTX1] > 0.0:
        sk = fz * (p[P_PTX1] + p[P_PTX2] * dfz) * exp(-p[P_PTX3] * dfz) * r0 / fnom * p[P_LSGKP]
    else:
        c = p[P_LONGITUDINAL_STIFFNESS]
        if not c > 0.0:
            c = _kxk(p, fz0, 0.0) / DEFAULT_SIGMA_KAPPA
        sk = abs(_kxk(p, fz, dfz)) / c
    if p[P_PTY1] > 0.0:
        sa = (p[P_PTY1] * _sin_2atan(fz / (p[P_PTY2] * fz0)) * (1.0 - p[P_PKY3] * abs(gamma * p[P_LGAY]))
              * r0 * p[P_LFZO] * p[P_LSGAL])
    else:
        c = p[P_LATERAL_STIFFNESS]
        if not c > 0.0:
            c = abs(_kya(p, fz0, fz0, 0.0)) / DEFAULT_SIGMA_ALPHA
        sa = abs(_kya(p, fz, fz0, gamma * p[P_LGAY])) / c
    if not sk > SIGMA_MIN:
        sk = SIGMA_MIN
    if not sa > SIGMA_MIN:
        sa = SIGMA_MIN
    return sk, sa


@inline_kernel
def _peak_input(b, c, e):
    """|x| >= 0 where D sin(C atan(Bx - E(Bx - atan Bx))) first peaks, or _BIG when it never does
    (C <= 1 or B = 0)."""
    if c <= 1.0 or b == 0.0:
        return _BIG
    target = tan(0.5 * pi / c)
    if e > 1.0:
        e = 1.0
    y = target                                 # solve y - e (y - atan y) = target, monotone in y
    for _ in range(30):
        g = y - e * (y - atan(y)) - target
        dg = 1.0 - e + e / (1.0 + y * y)
        if dg <= 1e-12:
            return _BIG
        step = g / dg
        y -= step
        if y < 0.0:
            y = 0.0
        if abs(step) <= 1e-12 * (1.0 + y):
            break
    x = y / abs(b)
    return x if x < _BIG else _BIG


@kernel
def peak_slips(p, fz, gamma):
    """(kappa_peak, tan_alpha_peak): pure-slip slips of the peak |Fx| and |Fy| at load fz (mu = 1,
    driving side for Fx, positive alpha for Fy; offsets ignored)."""
    return peak_kappa(p, fz, gamma), peak_alpha(p, fz, gamma)


@inline_kernel
def peak_kappa(p, fz, gamma):
    """The first of peak_slips: the pure longitudinal slip of the peak |Fx| (an iterative solve)."""
    b, c, e = _kappa_shape(p, fz, gamma)
    return _peak_input(b, c, e)


@inline_kernel
def peak_alpha(p, fz, gamma):
    """The second of peak_slips: tan of the pure slip angle of the peak |Fy| (an iterative solve)."""
    b, c, e = _alpha_shape(p, fz, gamma)
    return _peak_input(b, c, e)


@inline_kernel
def _kappa_shape(p, fz, gamma):
    """(B, C, E) of the pure longitudinal force at load fz (B = 0 without load: no peak)."""
    if not fz > 0.0:
        return 0.0, 0.0, 0.0
    fz0 = p[P_FNOMIN] * p[P_LFZO]
    dfz = (fz - fz0) / fz0
    gx = gamma * p[P_LGAX]
    cx = p[P_PCX1] * p[P_LCX]
    dx = (p[P_PDX1] + p[P_PDX2] * dfz) * (1.0 - p[P_PDX3] * gx * gx) * p[P_LMUX] * fz
    ex = (p[P_PEX1] + p[P_PEX2] * dfz + p[P_PEX3] * dfz * dfz) * (1.0 - p[P_PEX4]) * p[P_LEX]
    bx = _kxk(p, fz, dfz) / (cx * dx + _EPS * _sgn(dx))
    return bx, cx, ex


@inline_kernel
def _alpha_shape(p, fz, gamma):
    """(B, C, E) of the pure lateral force at load fz (B = 0 without load: no peak)."""
    if not fz > 0.0:
        return 0.0, 0.0, 0.0
    fz0 = p[P_FNOMIN] * p[P_LFZO]
    dfz = (fz - fz0) / fz0
    gy = gamma * p[P_LGAY]
    cy = p[P_PCY1] * p[P_LCY]
    dy = (p[P_PDY1] + p[P_PDY2] * dfz) * (1.0 - p[P_PDY3] * gy * gy) * p[P_LMUY] * fz
    ey = (p[P_PEY1] + p[P_PEY2] * dfz) * (1.0 - (p[P_PEY3] + p[P_PEY4] * gy)) * p[P_LEY]
    by = _kya(p, fz, fz0, gy) / (cy * dy + _EPS * _sgn(dy))
    return by, cy, ey


@inline_kernel
def _peak_input_floor(b, c, e):
    """A lower bound of _peak_input(b, c, e) without its iterations. With y = B |x| the peak solves
    f(y) = (1 - E) y + E atan y = tan(pi / (2 C)) =: T, and 0 <= atan y <= y for y >= 0: for E <= 0,
    f(y) <= (1 - E) y, so y >= T / (1 - E); for 0 < E <= 1, f(y) <= y, so y >= T. Less a relative 1e-9 (the
    iterations stop within 1e-12 of the root)."""
    if c <= 1.0 or b == 0.0:
        return _BIG
    target = tan(0.5 * pi / c)
    if e > 1.0:
        e = 1.0
    y = target / (1.0 - e) if e <= 0.0 else target
    x = y / abs(b)
    return (x if x < _BIG else _BIG) * (1.0 - 1e-9)


@inline_kernel
def _clip_limit(p, fz, gamma, x, lim, sigma, longitudinal):
    """The wind-up limit sigma x max(lim, peak slip) of a deflection x, the peak solved only when x can
    reach it: x within sigma x lim is never clipped (the peak is not needed), nor is x within sigma times
    a lower bound of the peak (_peak_input_floor; its limit is then |x| itself: the same result, since
    sigma x max(lim, peak) >= |x|)."""
    if abs(x) <= sigma * lim:
        return sigma * lim
    if longitudinal:
        b, c, e = _kappa_shape(p, fz, gamma)
    else:
        b, c, e = _alpha_shape(p, fz, gamma)
    if abs(x) <= sigma * _peak_input_floor(b, c, e):
        return abs(x)
    peak = _peak_input(b, c, e)
    return sigma * (peak if lim < peak else lim)


@kernel
def loaded_radius(p, fz):
    """R0 - Fz/Cz [m] (linear vertical stiffness; Fz < 0 counts as 0)."""
    if fz < 0.0:
        fz = 0.0
    return p[P_UNLOADED_RADIUS] - fz / p[P_VERTICAL_STIFFNESS]


@kernel
def effective_rolling_radius(p, fz):
    """Re [m] = R0 - (FNOMIN/Cz)(DREFF atan(BREFF Fz/FNOMIN) + FREFF Fz/FNOMIN)."""
    if fz < 0.0:
        fz = 0.0
    rho0 = p[P_FNOMIN] / p[P_VERTICAL_STIFFNESS]
    fr = fz / p[P_FNOMIN]
    return p[P_UNLOADED_RADIUS] - rho0 * (p[P_DREFF] * atan(p[P_BREFF] * fr) + p[P_FREFF] * fr)


@kernel
def vertical_force(p, deflection, deflection_rate):
    """Fz [N] = Cz rho + Kz rho_dot for a tyre in contact (rho > 0), never pulling (>= 0)."""
    if not deflection > 0.0:
        return 0.0
    f = p[P_VERTICAL_STIFFNESS] * deflection + p[P_VERTICAL_DAMPING] * deflection_rate
    return f if f > 0.0 else 0.0


# ---- slip kinematics and the transient (contact deflection) model ----------------------------------
@kernel
def steady_slip(p, vx, vsy, omega, re):
    """(kappa, alpha) from the kinematics without state, with V_low = VXLOW blending:
    kappa = (omega Re - Vx)/max(|Vx|, VXLOW), alpha = atan(Vsy/max(|Vx|, VXLOW)). For quasi-static
    evaluations; at low speed in a time loop use transient_slip (see the module docstring)."""
    den = abs(vx)
    if den < p[P_VXLOW]:
        den = p[P_VXLOW]
    return (omega * re - vx) / den, atan(vsy / den)


@inline_kernel
def _damping_time(p, vx):
    """d [s] = DAMP_RESIDUAL + DAMP_VLOW 0.5 (1 + cos(pi |Vx|/VXLOW)) below VXLOW."""
    return low_speed_damping(p[P_DAMP_RESIDUAL], p[P_DAMP_VLOW], p[P_VXLOW], vx)


@kernel
def deflection_rates(p, fz, gamma, vx, vsy, omega, re, u, v):
    """(du/dt, dv/dt) [m/s] of the contact deflections (u, v) [m]."""
    sk, sa = relaxation_lengths(p, fz, gamma)
    avx = abs(vx)
    return -(vx - omega * re) - avx * u / sk, vsy - avx * v / sa


@kernel
def transient_slip(p, state, i, fz, gamma, vx, vsy, omega, re):
    """(kappa', alpha') for the force kernels from the deflections state[i, S_U], state[i, S_V]:
    kappa' = (u + d du/dt)/sigma_kappa, alpha' = atan((v + d dv/dt)/sigma_alpha).
    vx: wheel-centre speed along the heading; vsy: lateral velocity of the contact point (left);
    omega: wheel spin rate (positive rolling forward) [rad/s]; re: effective rolling radius [m]."""
    return _transient_slip(p, state, i, fz, gamma, vx, vsy, omega, re, 0.0)


@kernel
def transient_slip_relaxed(p, state, i, fz, gamma, vx, vsy, omega, re, extra):
    """transient_slip with both relaxation lengths lengthened by `extra` (m): the tyre_relaxation
    effect (rtsim.vehicle.car.effects)."""
    return _transient_slip(p, state, i, fz, gamma, vx, vsy, omega, re, extra)


@inline_kernel
def _transient_slip(p, state, i, fz, gamma, vx, vsy, omega, re, extra):
    if not fz > 0.0:
        return 0.0, 0.0
    sk, sa = relaxation_lengths(p, fz, gamma)
    sk += extra
    sa += extra
    u = state[i, S_U]
    v = state[i, S_V]
    avx = abs(vx)
    du = -(vx - omega * re) - avx * u / sk
    dv = vsy - avx * v / sa
    d = _damping_time(p, vx)
    return (u + d * du) / sk, atan((v + d * dv) / sa)


@inline_kernel
def _relax_step(x, rate_in, a, dt):
    """Exact step of x' = rate_in - a x over dt for constant inputs (a >= 0)."""
    h = a * dt
    if h < 1e-8:
        return x + (rate_in - a * x) * dt
    e = exp(-h)
    return x * e + rate_in * (1.0 - e) / a


@inline_kernel
def wind_up_limit(u, v, ulim, vlim):
    """Contact deflections (m) clipped to +-ulim, +-vlim: they never wind up past the sliding limit."""
    return min(max(u, -ulim), ulim), min(max(v, -vlim), vlim)


@kernel
def advance_deflections(p, state, i, fz, gamma, vx, vsy, omega, re, dt):
    """Advance state[i, S_U], state[i, S_V] by dt (exact for inputs frozen over the step), then apply
    the wind-up limit; airborne (fz <= 0): both reset to 0."""
    _advance_deflections(p, state, i, fz, gamma, vx, vsy, omega, re, dt, 0.0)


@kernel
def advance_deflections_relaxed(p, state, i, fz, gamma, vx, vsy, omega, re, dt, extra):
    """advance_deflections with both relaxation lengths lengthened by `extra` (m)."""
    _advance_deflections(p, state, i, fz, gamma, vx, vsy, omega, re, dt, extra)


@inline_kernel
def _advance_deflections(p, state, i, fz, gamma, vx, vsy, omega, re, dt, extra):
    if not fz > 0.0:
        state[i, S_U] = 0.0
        state[i, S_V] = 0.0
        return
    sk, sa = relaxation_lengths(p, fz, gamma)
    sk += extra
    sa += extra
    avx = abs(vx)
    vsx = vx - omega * re
    u = _relax_step(state[i, S_U], -vsx, avx / sk, dt)
    v = _relax_step(state[i, S_V], vsy, avx / sa, dt)
    den = avx if avx > p[P_VXLOW] else p[P_VXLOW]
    lim_k = abs(vsx) / den
    lim_a = abs(vsy) / den
    # the limits are sigma x max(slip, peak slip), each peak an iterative solve made only where its
    # deflection can reach it (_clip_limit): in the benchmark's 35 deg step steer at 80 km/h the lateral
    # deflections pass sigma x slip in every tyre commit but stay below a third of sigma x peak
    ulim = _clip_limit(p, fz, gamma, u, lim_k, sk, True)
    vlim = _clip_limit(p, fz, gamma, v, lim_a, sa, False)
    state[i, S_U], state[i, S_V] = wind_up_limit(u, v, ulim, vlim)


def new_slip_state(n_tyres: int) -> np.ndarray:
    """Zero deflections for n tyres at rest: float64 (n_tyres, N_SLIP_STATES)."""
    return np.zeros((n_tyres, N_SLIP_STATES))
