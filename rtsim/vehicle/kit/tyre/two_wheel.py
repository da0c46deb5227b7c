"""Motorcycle (two-wheel) tyre kernels: toroidal contact, a Magic-Formula-type force law with camber
thrust and the friction ellipse, a linear variant, first-order relaxation, and the wrench at the
wheel centre. Kernels are `rtsim.jit.kernel`s (NRT off): scalars in, tuples of floats out, the
packed parameter array `p` (indices `TW_*`, built by `pack_two_wheel_tyre`); none allocates.

Axes and signs (ISO 8855, as `magic_formula`): road normal n (up), axle a (to the wheel's left when
upright), heading t = unit(a x n), lateral l = n x t. Camber gamma = asin(a.n) [rad], > 0 when the
wheel leans to its right. Slips: kappa = -(Vx - omega Re)/|Vx| (> 0 driving), alpha = atan(Vsy/|Vx|)
(> 0 when the contact point slides left; gives Fy < 0). Outputs on the wheel at the contact point P:
Fx along t, Fy along l, Mx about t, My about the axle a (> 0 in the sense of forward rolling), Mz
about n (> 0 turning left). Force kernels return (Fx, Fy, Mx, My, Mz) [N, N, N m, N m, N m].

Toroidal contact (`toroidal_contact`; Cossalter, Motorcycle Dynamics, ch. 1-2)
----------------------------------------------------------------------------
The tyre cross-section is a circle of radius rho (crown radius) whose centre runs on a circle of
radius R - rho about the wheel centre W in the wheel plane. On a road plane (point Q, normal n):
    nu = (n - (n.a) a)/cos(gamma)         in-plane direction nearest to n; |n - (n.a) a| = cos(gamma)
    C  = W - (R - rho) nu                  crown-circle centre nearest to the road
    d  = rho - (C - Q).n = rho + (R - rho) cos(gamma) - (W - Q).n      penetration [m] (> 0: contact)
    P  = C - (rho - d) n                   the contact point, on the road surface
P lies (rho - d) sin(gamma) from the wheel plane on the side of the lean ((P - W).a =
-(rho - d) sin(gamma)): the contact point moves round the crown with camber, by rho sin(gamma) for a
just-touching tyre. In the road plane it lies (rho - d) tan(gamma) from the line where the wheel
plane cuts the road (the knife-edge contact of a disc). rho = 0 is the disc.
Effective rolling radius (`two_wheel_rolling_radius`): Re = (R - rho) + (rho - d/3) cos(gamma), the
distance from the axle to the contact with a third of the deflection (MF's FREFF = 1/3); it falls
with camber as the contact moves onto the shoulder.

Vertical force (`two_wheel_vertical_force`): Fz = kz d + kz2 d^2 + cz w d_dot for d > 0, else 0;
never negative (a tyre does not pull the wheel down). The damping builds up over the first
``DAMPING_ONSET`` of deflection, w = min(1, d / DAMPING_ONSET), as contact damping does (Hunt and
Crossley): the force is then continuous at touch-down. Without it a tyre landing at d_dot jumped from 0
to cz d_dot as d crossed 0, and Newton's iterates, crossing it, stalled (a lightly loaded tyre in a
crash or a fall, bouncing on its contact).

Steady force law (`two_wheel_forces`; Pacejka, Tyre and Vehicle Dynamics, 3rd ed., ch. 4.3 and 11)
----------------------------------------------------------------------------------------------------
Stiffnesses at load Fz, dfz = (Fz - Fz0)/Fz0:
    K_kappa = c_kappa Fz [N],   K_alpha = c_alpha Fz exp(-s_alpha dfz) [N/rad],   K_gamma = c_gamma Fz
    [N/rad] (normalised cornering stiffness falls with load, camber stiffness is about proportional
    to it: Cossalter ch. 2); friction mu_i(Fz) = mu mu_i exp(-s_mu dfz), Fi_max = mu_i(Fz) Fz.
Linear-range forces: y_k = K_kappa kappa, y_a = K_alpha tan(alpha), y_g = K_gamma gamma: camber
enters as an equivalent slip angle (K_gamma/K_alpha) gamma added to tan(alpha) (the camber shift of
Pacejka's motorcycle MF, ch. 11), so slip and camber saturate together.
Combined slip on the friction ellipse (normalised-slip similarity, Pacejka ch. 4): with
sx = y_k/Fx_max, sy = (y_a + y_g)/Fy_max, s = sqrt(sx^2 + sy^2),
    f(s) = sin(C atan(b - E (b - atan b))),  b = s/C   (the MF with unit slope at s = 0)
    Fx = q y_k,  Fy = -q (y_a + y_g),  q = f(s)/s   (q -> 1 at small slip: the linear limit)
so (Fx/Fx_max)^2 + (Fy/Fy_max)^2 = f(s)^2 <= 1: never outside the ellipse, on it at the peak slip
s_peak (f = 1). C and E are blended between the longitudinal and lateral values by the direction:
C = (sx^2 Cx + sy^2 Cy)/s^2, likewise E. Pure slip gives the usual MF curves with peaks mu_i Fz.
Moments:
    Mx = lambda_mx Fz Fy sigma_alpha/K_alpha      [N m]: the lateral carcass deflection Fy/C_ly
         (C_ly = K_alpha/sigma_alpha, Pacejka ch. 7) shifts the pressure centre; the camber part
         of the overturning moment is already in the contact point's position on the crown.
    My = -s_low R Fz (f0 + f2 Vx^2)               [N m]: rolling resistance (the fit quoted by
         Cossalter ch. 2: f = 0.0085 + 0.018/p + 1.59e-6 V^2/p, p in bar, V in km/h).
    Mz = s_low q (t y_a - c_tw Fz gamma)          [N m]: pneumatic trail t = t0/(1 + (2 s/s_peak)^2)
         times the slip part of Fy (t falls as sliding spreads in the patch, to t0/5 at the peak),
         and the twisting torque of camber (Cossalter ch. 2), toward the lean (< 0 for gamma > 0).
Low-speed factors (as `magic_formula`): s_low = sin(pi/2 Vx/V_low) (clipped to +-1) makes My and Mz
flip with the rolling direction and vanish at standstill.

Linear variant (`two_wheel_linear_forces`): Fx = K_kappa kappa, Fy = -(K_alpha tan(alpha) + K_gamma
gamma), Mz = s_low (t0 K_alpha tan(alpha) - c_tw Fz gamma), Mx, My as above, with the same
stiffnesses: the small-slip limit of the full law (same derivatives at zero slip), unsaturated, for
linear analyses. tan(alpha) (= alpha to first order) is the lateral slip the relaxation states carry,
so a leaned wheel at rest gives exactly zero force with either law.

Relaxation: contact deflections (as `magic_formula`, Pacejka ch. 7)
-------------------------------------------------------------------
Per wheel two states (same layout as `magic_formula`'s): u, v [m], with
    du/dt = -Vsx - |Vx| u/sigma_kappa                         Vsx = Vx - omega Re
    dv/dt =  Vsy + |Vx| g gamma - |Vx| v/sigma_alpha          g = K_gamma/K_alpha
Steady rolling: u/sigma_kappa = kappa and v/sigma_alpha = tan(alpha) + g gamma, so both slip and
camber force build up with distance constant sigma (1 - exp(-x/sigma) after a step); at standstill
the camber input vanishes (camber thrust is a rolling effect) and the deflections are springs of
stiffness K/sigma. The force law is fed (`two_wheel_transient_slip`)
    kappa' = (u + d du/dt)/sigma_kappa,   alpha' = atan((v + d dv/dt)/sigma_alpha - g gamma)
(alpha' is the slip angle that, with the present camber, gives the relaxed lateral slip), with the
damping time d = d0 + d_low 0.5 (1 + cos(pi |Vx|/V_low)) below V_low (d0 above): damping of the
contact springs near standstill that leaves the steady states and, for d0 = 0, the pure first-order
lag at speed unchanged. `advance_two_wheel_slip` integrates the states exactly for inputs frozen
over the step and limits the wind-up as `magic_formula` does (|u| <= sigma_kappa max(kappa_peak,
|Vsx|/max(|Vx|, V_low)), likewise v).

Use per step and wheel (state: float64 (n_wheels, TW_N_SLIP_STATES), zeros at rest):
    1. P, d, gamma, t, l = toroidal_contact(p, W, a, Q, n); Fz = two_wheel_vertical_force(p, d, d_dot)
    2. kappa, alpha = two_wheel_transient_slip(p, state, i, Fz, gamma, Vx, Vsy, omega, Re)
    3. Fx, Fy, Mx, My, Mz = two_wheel_tyre_forces(p, Fz, kappa, alpha, gamma, Vx, mu)  (model in p)
    4. F = contact_force_world(t, l, n, Fx, Fy, Fz); wrench_at_wheel_centre(W, P, F, t, a, n, Mx, My, Mz)
    5. after the step: advance_two_wheel_slip(p, state, i, Fz, gamma, Vx, Vsy, omega, Re, dt)
"""
from __future__ import annotations

import math
from math import asin, atan, cos, exp, pi, sin, sqrt, tan
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from rtsim.configfile import Range, Strict, bad
from rtsim.jit import inline_kernel, kernel
from rtsim.vehicle.kit.layout import offsets

from .low_speed import low_speed_damping, low_speed_fade
from .magic_formula import _relax_step, wind_up_limit

# ---- packed parameters ----------------------------------------------------------------------------
(TW_MODEL,          # 0: magic_formula, 1: linear
 TW_R0,             # m, unloaded radius R
 TW_RHO,            # m, crown radius rho
 TW_KZ,             # N/m, radial stiffness
 TW_KZ2,            # N/m^2, quadratic radial stiffness
 TW_CZ,             # N s/m, radial damping
 TW_FZ0,            # N, nominal load
 TW_CK,             # -, normalised longitudinal slip stiffness K_kappa/Fz
 TW_CA,             # 1/rad, normalised cornering stiffness K_alpha/Fz at Fz0
 TW_CA_FZ,          # -, load sensitivity s_alpha of the cornering stiffness
 TW_CG,             # 1/rad, normalised camber stiffness K_gamma/Fz
 TW_MUX,            # -, longitudinal peak friction at Fz0
 TW_MUY,            # -, lateral peak friction at Fz0
 TW_MU_FZ,          # -, load sensitivity s_mu of the friction
 TW_CX, TW_CY,      # -, MF shape factors
 TW_EX, TW_EY,      # -, MF curvature factors
 TW_TRAIL,          # m, pneumatic trail t0 at zero slip
 TW_TWIST,          # m/rad, camber twisting torque per unit load
 TW_MX,             # -, overturning-moment factor lambda_mx
 TW_RR0,            # -, rolling resistance f0
 TW_RR2,            # s^2/m^2, speed term f2
 TW_SIGMA_K,        # m, longitudinal relaxation length
 TW_SIGMA_A,        # m, lateral relaxation length
 TW_DAMP,           # s, contact damping time d0 at speed
 TW_DAMP_LOW,       # s, extra damping time d_low at standstill
 TW_VXLOW,          # m/s, low-speed blending speed V_low
 TW_SPK_X,          # -, normalised peak slip s_peak (derived from CX, EX)
 TW_SPK_Y,          # -, likewise from CY, EY
 TW_SIZE) = offsets(*(1,) * 30)

MODEL_MAGIC_FORMULA = 0.0
MODEL_LINEAR = 1.0

# ---- transient-slip states (same layout as magic_formula's S_U, S_V) -------------------------------
TW_S_U = 0             # longitudinal contact deflection u [m]
TW_S_V = 1             # lateral contact deflection v [m]
TW_N_SLIP_STATES = 2

ALPHA_MAX = 1.5        # rad, |alpha| clipped before tan()
NO_PEAK = 1e3          # normalised peak slip when the curve never peaks (C <= 1)
_COS_MIN = 1e-9        # wheel lying flat on the road: no contact


# ---- config ---------------------------------------------------------------------------------------
# ranges of the keys with units (module-level: a unit string inside an annotation would read as a
# forward reference)
_RADIUS = Range(0.1, 0.6, "m")
_CROWN = Range(0.0, 0.3, "m")
_KZ = Range(1e4, 1e7, "N/m", lo_open=True)
_KZ2 = Range(0.0, 1e9, "N/m^2")
_CZ = Range(0.0, 1e5, "N s/m")
_LOAD = Range(100.0, 2e4, "N")
_K_SLIP = Range(1.0, 100.0, "1/unit slip")
_K_ALPHA = Range(1.0, 50.0, "1/rad")
_K_GAMMA = Range(0.0, 3.0, "1/rad")
_TRAIL = Range(0.0, 0.1, "m")
_TWIST = Range(0.0, 0.1, "m/rad")
_RR_SPEED = Range(0.0, 1e-3, "s^2/m^2")
_SIGMA = Range(0.01, 1.0, "m")
_D_TIME = Range(0.0, 0.05, "s")
_D_TIME_LOW = Range(0.0, 0.1, "s")
_V_LOW = Range(0.05, 10.0, "m/s")


class TwoWheelTyreSpec(Strict):
    """One motorcycle tyre (units in the key names). Defaults: a sport 120/70 ZR17 front
    (`sport_front`); `sport_rear` gives the 180/55 ZR17 rear."""
    model: Literal["magic_formula", "linear"] = Field(
        default="magic_formula", description="saturating force law, or the linear one for linear analyses")
    # 17 in rim (0.2159 m) + 0.70 x 120 mm sidewall
    unloaded_radius_m: _RADIUS = 0.300
    # about half the 120 mm tread arc: a round sport profile
    crown_radius_m: _CROWN = 0.060
    # radial tyres at 2.3-2.5 bar: typically 120-200 kN/m
    radial_stiffness_n_per_m: _KZ = 140e3
    radial_stiffness_quadratic_n_per_m2: _KZ2 = 0.0
    # ~7 % of critical for a 12 kg wheel on 140 kN/m
    radial_damping_ns_per_m: _CZ = 200.0
    # static share of a 200 kg sport bike with a 75 kg rider
    nominal_load_n: _LOAD = 1300.0
    # motorcycle radials: 15-30 per unit slip
    longitudinal_stiffness_per_load: _K_SLIP = 20.0
    # Pacejka's ch. 11 motorcycle example: 14 Fz0 + 9 (Fz - Fz0) front, 13 Fz0 + 4 (Fz - Fz0) rear,
    # i.e. K_alpha/Fz falls by 0.36 (front) and 0.69 (rear) per unit dfz at Fz0
    cornering_stiffness_per_load: _K_ALPHA = 14.0
    cornering_stiffness_load_sensitivity: Range(-2.0, 2.0) = 0.35
    # 0.8-1.1 Fz per rad (Cossalter ch. 2); rounder (front) profiles at the high end
    camber_stiffness_per_load: _K_GAMMA = 0.90
    mu_x: Range(0.1, 3.0, lo_open=True) = 1.30
    mu_y: Range(0.1, 3.0, lo_open=True) = 1.20
    friction_load_sensitivity: Range(0.0, 1.0) = 0.10
    # no published MF fit of these sizes at hand: C and E put the peaks of pure slip near kappa = 0.14
    # and alpha = 11 deg (motorcycle radials peak late) with sliding at 60-70 % of the peak
    shape_x: Range(1.0, 1.95, lo_open=True) = 1.6
    shape_y: Range(1.0, 1.95, lo_open=True) = 1.5
    curvature_x: Range(-5.0, 1.0) = -0.5
    curvature_y: Range(-5.0, 1.0) = -0.5
    # about a sixth of a ~90 mm contact patch
    pneumatic_trail_m: _TRAIL = 0.015
    # ~10 N m at 45 deg and 1.3 kN (order of Cossalter's ch. 2 data)
    twisting_torque_m_per_rad: _TWIST = 0.010
    overturning_factor: Range(0.0, 5.0) = 1.0
    # Cossalter's fit at 2.5 bar: f = 0.0157 + 8.2e-6 V^2 (V in m/s)
    rolling_resistance: Range(0.0, 0.1) = 0.0157
    rolling_resistance_speed_s2_per_m2: _RR_SPEED = 8.2e-6
    # lateral contact stiffness K_alpha/sigma ~ 120 kN/m at Fz0
    relaxation_length_long_m: _SIGMA = 0.12
    relaxation_length_lat_m: _SIGMA = 0.15
    damping_time_s: _D_TIME = 0.0
    damping_time_standstill_s: _D_TIME_LOW = 0.01
    low_speed_mps: _V_LOW = 1.0

    @model_validator(mode="after")
    def _crown_inside(self):
        if self.crown_radius_m >= self.unloaded_radius_m:
            raise bad("crown_radius_m", self.crown_radius_m, "must be below unloaded_radius_m")
        return self


def sport_front() -> TwoWheelTyreSpec:
    """120/70 ZR17 front of a sport motorcycle (the class defaults)."""
    return TwoWheelTyreSpec()


def sport_rear() -> TwoWheelTyreSpec:
    """180/55 ZR17 rear: 0.2159 m + 0.55 x 180 mm; flatter, wider crown (lower camber stiffness per
    load), stiffer carcass, longer contact patch (trail, relaxation), more load (Fz0)."""
    return TwoWheelTyreSpec(
        unloaded_radius_m=0.315, crown_radius_m=0.085, radial_stiffness_n_per_m=180e3,
        radial_damping_ns_per_m=250.0, nominal_load_n=1500.0, longitudinal_stiffness_per_load=22.0,
        cornering_stiffness_per_load=13.0, cornering_stiffness_load_sensitivity=0.7,
        camber_stiffness_per_load=0.80, pneumatic_trail_m=0.020, twisting_torque_m_per_rad=0.012,
        relaxation_length_long_m=0.14, relaxation_length_lat_m=0.20)


class MotorcycleTyres(Strict):
    """The front and rear tyre of a motorcycle (each with its own model choice); keys not given take
    the values of `sport_front` and `sport_rear` respectively."""
    front: TwoWheelTyreSpec = Field(default_factory=sport_front)
    rear: TwoWheelTyreSpec = Field(default_factory=sport_rear)

    @model_validator(mode="before")
    @classmethod
    def _rear_defaults(cls, data):
        if isinstance(data, dict) and isinstance(data.get("rear"), dict):
            data = {**data, "rear": {**sport_rear().model_dump(), **data["rear"]}}
        return data


def peak_slip(c: float, e: float) -> float:
    """Normalised slip s where sin(C atan(b - E (b - atan b))), b = s/C, first reaches 1 (NO_PEAK
    when C <= 1)."""
    if c <= 1.0:
        return NO_PEAK
    target = math.tan(0.5 * math.pi / c)
    lo, hi = 0.0, 1.0
    while hi - e * (hi - math.atan(hi)) < target:      # monotone in b for E <= 1
        hi *= 2.0
        if hi > NO_PEAK:
            return NO_PEAK
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid - e * (mid - math.atan(mid)) < target:
            lo = mid
        else:
            hi = mid
    return min(c * 0.5 * (lo + hi), NO_PEAK)


def pack_two_wheel_tyre(spec: TwoWheelTyreSpec) -> np.ndarray:
    """The parameter array (float64, TW_SIZE) of one tyre."""
    p = np.zeros(TW_SIZE)
    p[TW_MODEL] = MODEL_LINEAR if spec.model == "linear" else MODEL_MAGIC_FORMULA
    p[TW_R0] = spec.unloaded_radius_m
    p[TW_RHO] = spec.crown_radius_m
    p[TW_KZ] = spec.radial_stiffness_n_per_m
    p[TW_KZ2] = spec.radial_stiffness_quadratic_n_per_m2
    p[TW_CZ] = spec.radial_damping_ns_per_m
    p[TW_FZ0] = spec.nominal_load_n
    p[TW_CK] = spec.longitudinal_stiffness_per_load
    p[TW_CA] = spec.cornering_stiffness_per_load
    p[TW_CA_FZ] = spec.cornering_stiffness_load_sensitivity
    p[TW_CG] = spec.camber_stiffness_per_load
    p[TW_MUX] = spec.mu_x
    p[TW_MUY] = spec.mu_y
    p[TW_MU_FZ] = spec.friction_load_sensitivity
    p[TW_CX] = spec.shape_x
    p[TW_CY] = spec.shape_y
    p[TW_EX] = spec.curvature_x
    p[TW_EY] = spec.curvature_y
    p[TW_TRAIL] = spec.pneumatic_trail_m
    p[TW_TWIST] = spec.twisting_torque_m_per_rad
    p[TW_MX] = spec.overturning_factor
    p[TW_RR0] = spec.rolling_resistance
    p[TW_RR2] = spec.rolling_resistance_speed_s2_per_m2
    p[TW_SIGMA_K] = spec.relaxation_length_long_m
    p[TW_SIGMA_A] = spec.relaxation_length_lat_m
    p[TW_DAMP] = spec.damping_time_s
    p[TW_DAMP_LOW] = spec.damping_time_standstill_s
    p[TW_VXLOW] = spec.low_speed_mps
    p[TW_SPK_X] = peak_slip(spec.shape_x, spec.curvature_x)
    p[TW_SPK_Y] = peak_slip(spec.shape_y, spec.curvature_y)
    return p


def new_two_wheel_slip_state(n_wheels: int = 2) -> np.ndarray:
    """Zero contact deflections: float64 (n_wheels, TW_N_SLIP_STATES)."""
    return np.zeros((n_wheels, TW_N_SLIP_STATES))


# ---- contact geometry -----------------------------------------------------------------------------
@kernel
def toroidal_contact(p, wx, wy, wz, ax, ay, az, qx, qy, qz, nx, ny, nz):
    """(px, py, pz, d, gamma, tx, ty, tz, lx, ly, lz): contact point P on the road [m], penetration d
    [m] (> 0 in contact), camber [rad], heading t and lateral l (unit) of the toroidal tyre with
    centre W, unit axle a, on the road plane through Q with unit normal n (module docstring). A wheel
    lying flat (cos(gamma) < 1e-9) gives d = -1 (no contact), t = l = 0."""
    r0 = p[TW_R0]
    rho = p[TW_RHO]
    an = ax * nx + ay * ny + az * nz
    if an > 1.0:
        an = 1.0
    elif an < -1.0:
        an = -1.0
    gamma = asin(an)
    ux, uy, uz = nx - an * ax, ny - an * ay, nz - an * az
    cg = sqrt(ux * ux + uy * uy + uz * uz)
    if cg < _COS_MIN:
        return wx, wy, wz, -1.0, gamma, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    k = (r0 - rho) / cg
    cx, cy, cz = wx - k * ux, wy - k * uy, wz - k * uz            # crown-circle centre C
    h = (cx - qx) * nx + (cy - qy) * ny + (cz - qz) * nz         # height of C above the road
    px, py, pz = cx - h * nx, cy - h * ny, cz - h * nz
    tx, ty, tz = (ay * nz - az * ny) / cg, (az * nx - ax * nz) / cg, (ax * ny - ay * nx) / cg
    lx, ly, lz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
    return px, py, pz, rho - h, gamma, tx, ty, tz, lx, ly, lz


@kernel
def two_wheel_rolling_radius(p, d, gamma):
    """Effective rolling radius Re = (R - rho) + (rho - d/3) cos(gamma) [m] (d < 0 counts as 0)."""
    if d < 0.0:
        d = 0.0
    return p[TW_R0] - p[TW_RHO] + (p[TW_RHO] - d / 3.0) * cos(gamma)


DAMPING_ONSET = 0.002       # m: the deflection over which the radial damping builds up (module docstring)


@kernel
def two_wheel_vertical_force(p, d, d_rate):
    """Fz = kz d + kz2 d^2 + cz w d_rate [N] for d > 0 (penetration [m], its rate [m/s]), else 0; >= 0;
    w = min(1, d / DAMPING_ONSET) (module docstring)."""
    if not d > 0.0:
        return 0.0
    w = d / DAMPING_ONSET if d < DAMPING_ONSET else 1.0
    f = (p[TW_KZ] + p[TW_KZ2] * d) * d + p[TW_CZ] * w * d_rate
    return f if f > 0.0 else 0.0


# ---- force laws -----------------------------------------------------------------------------------
@inline_kernel
def _ca_norm(p, fz):
    """K_alpha/Fz [1/rad] at load fz."""
    return p[TW_CA] * exp(-p[TW_CA_FZ] * (fz - p[TW_FZ0]) / p[TW_FZ0])


@inline_kernel
def _mu_scale(p, fz):
    return exp(-p[TW_MU_FZ] * (fz - p[TW_FZ0]) / p[TW_FZ0])


@kernel
def two_wheel_stiffnesses(p, fz):
    """(K_kappa [N], K_alpha [N/rad], K_gamma [N/rad]) at load fz [N] (zeros when fz <= 0)."""
    if not fz > 0.0:
        return 0.0, 0.0, 0.0
    return p[TW_CK] * fz, _ca_norm(p, fz) * fz, p[TW_CG] * fz


@kernel
def two_wheel_friction(p, fz, mu):
    """(Fx_max, Fy_max) [N]: the friction ellipse's half axes at load fz, road friction scale mu."""
    if not fz > 0.0 or not mu > 0.0:
        return 0.0, 0.0
    m = _mu_scale(p, fz) * mu * fz
    return p[TW_MUX] * m, p[TW_MUY] * m


@inline_kernel
def _saturation(p, sx, sy):
    """(q, s/s_peak): q = f(s)/s of the blended MF curve at normalised slips (sx, sy)."""
    sx2 = sx * sx
    sy2 = sy * sy
    s2 = sx2 + sy2
    if s2 < 1e-20:
        return 1.0, 0.0
    wx = sx2 / s2
    wy = 1.0 - wx
    c = wx * p[TW_CX] + wy * p[TW_CY]
    e = wx * p[TW_EX] + wy * p[TW_EY]
    spk = wx * p[TW_SPK_X] + wy * p[TW_SPK_Y]
    s = sqrt(s2)
    b = s / c
    q = sin(c * atan(b - e * (b - atan(b)))) / s
    return q, s / spk


@inline_kernel
def _moments(p, fz, fy, ya, gamma, vx, q, trail):
    """(Mx, My, Mz) from the forces (module docstring); ya = K_alpha tan(alpha) [N]."""
    _, s_low = low_speed_fade(vx, p[TW_VXLOW])
    mx = p[TW_MX] * fy * p[TW_SIGMA_A] / _ca_norm(p, fz)
    my = -s_low * fz * p[TW_R0] * (p[TW_RR0] + p[TW_RR2] * vx * vx)
    mz = s_low * q * (trail * ya - p[TW_TWIST] * fz * gamma)
    return mx, my, mz


@kernel
def two_wheel_forces(p, fz, kappa, alpha, gamma, vx, mu):
    """(Fx, Fy, Mx, My, Mz) [N, N, N m, N m, N m] of the saturating law on the friction ellipse.
    fz: load [N] (<= 0: all zero); kappa: longitudinal slip; alpha: slip angle [rad] (clipped to
    +-ALPHA_MAX); gamma: camber [rad]; vx: wheel-centre speed along t [m/s] (low-speed factors, My);
    mu: road friction scale (1 nominal; <= 0: no grip)."""
    if not fz > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    if alpha > ALPHA_MAX:
        alpha = ALPHA_MAX
    elif alpha < -ALPHA_MAX:
        alpha = -ALPHA_MAX
    yk = p[TW_CK] * fz * kappa
    ya = _ca_norm(p, fz) * fz * tan(alpha)
    yg = p[TW_CG] * fz * gamma
    fxm, fym = two_wheel_friction(p, fz, mu)
    if fxm > 0.0 and fym > 0.0:
        q, ratio = _saturation(p, yk / fxm, (ya + yg) / fym)
    else:
        q, ratio = 0.0, 0.0
    fx = q * yk
    fy = -q * (ya + yg)
    trail = p[TW_TRAIL] / (1.0 + 4.0 * ratio * ratio)
    mx, my, mz = _moments(p, fz, fy, ya, gamma, vx, q, trail)
    return fx, fy, mx, my, mz


@kernel
def two_wheel_linear_forces(p, fz, kappa, alpha, gamma, vx, mu):
    """(Fx, Fy, Mx, My, Mz) of the linear variant (no saturation; mu unused): the small-slip limit
    of `two_wheel_forces` with the same stiffnesses. Same arguments."""
    if not fz > 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    if alpha > ALPHA_MAX:
        alpha = ALPHA_MAX
    elif alpha < -ALPHA_MAX:
        alpha = -ALPHA_MAX
    ya = _ca_norm(p, fz) * fz * tan(alpha)
    fx = p[TW_CK] * fz * kappa
    fy = -(ya + p[TW_CG] * fz * gamma)
    mx, my, mz = _moments(p, fz, fy, ya, gamma, vx, 1.0, p[TW_TRAIL])
    return fx, fy, mx, my, mz


@kernel
def two_wheel_tyre_forces(p, fz, kappa, alpha, gamma, vx, mu):
    """`two_wheel_forces` or `two_wheel_linear_forces`, as p[TW_MODEL] selects."""
    if p[TW_MODEL] == MODEL_LINEAR:
        return two_wheel_linear_forces(p, fz, kappa, alpha, gamma, vx, mu)
    return two_wheel_forces(p, fz, kappa, alpha, gamma, vx, mu)


# ---- relaxation -----------------------------------------------------------------------------------
@inline_kernel
def _damping_time(p, vx):
    return low_speed_damping(p[TW_DAMP], p[TW_DAMP_LOW], p[TW_VXLOW], vx)


@kernel
def two_wheel_slip_rates(p, fz, gamma, vx, vsy, omega, re, u, v):
    """(du/dt, dv/dt) [m/s] of the contact deflections u, v [m]; vsy: lateral velocity of the
    contact point along l [m/s]; omega: spin rate [rad/s]; re: rolling radius [m]."""
    avx = abs(vx)
    g = p[TW_CG] / _ca_norm(p, fz)
    return (-(vx - omega * re) - avx * u / p[TW_SIGMA_K],
            vsy + avx * (g * gamma - v / p[TW_SIGMA_A]))


@kernel
def two_wheel_transient_slip(p, state, i, fz, gamma, vx, vsy, omega, re):
    """(kappa', alpha') for the force kernels from state[i, TW_S_U], state[i, TW_S_V] (module
    docstring); (0, 0) when fz <= 0. Evaluate inside the Newton iteration with the current
    velocities; the states stay fixed until `advance_two_wheel_slip`."""
    if not fz > 0.0:
        return 0.0, 0.0
    u = state[i, TW_S_U]
    v = state[i, TW_S_V]
    du, dv = two_wheel_slip_rates(p, fz, gamma, vx, vsy, omega, re, u, v)
    d = _damping_time(p, vx)
    g = p[TW_CG] / _ca_norm(p, fz)
    return (u + d * du) / p[TW_SIGMA_K], atan((v + d * dv) / p[TW_SIGMA_A] - g * gamma)


@kernel
def advance_two_wheel_slip(p, state, i, fz, gamma, vx, vsy, omega, re, dt):
    """Advance state[i, :] by dt [s] (exact for inputs frozen over the step), then limit the wind-up;
    airborne (fz <= 0): both reset to 0."""
    if not fz > 0.0:
        state[i, TW_S_U] = 0.0
        state[i, TW_S_V] = 0.0
        return
    sk = p[TW_SIGMA_K]
    sa = p[TW_SIGMA_A]
    avx = abs(vx)
    can = _ca_norm(p, fz)
    g = p[TW_CG] / can
    vsx = vx - omega * re
    u = _relax_step(state[i, TW_S_U], -vsx, avx / sk, dt)
    v = _relax_step(state[i, TW_S_V], vsy + avx * g * gamma, avx / sa, dt)
    mus = _mu_scale(p, fz)
    den = avx if avx > p[TW_VXLOW] else p[TW_VXLOW]
    lim_k = abs(vsx) / den
    kpk = p[TW_SPK_X] * p[TW_MUX] * mus / p[TW_CK]
    if lim_k < kpk:
        lim_k = kpk
    lim_a = abs(vsy + avx * g * gamma) / den
    apk = p[TW_SPK_Y] * p[TW_MUY] * mus / can
    if lim_a < apk:
        lim_a = apk
    state[i, TW_S_U], state[i, TW_S_V] = wind_up_limit(u, v, sk * lim_k, sa * lim_a)


# ---- wrench -------------------------------------------------------------------------------------
@kernel
def contact_force_world(tx, ty, tz, lx, ly, lz, nx, ny, nz, fx, fy, fz):
    """(Fx, Fy, Fz) in world axes [N] of the contact-frame force fx t + fy l + fz n."""
    return (fx * tx + fy * lx + fz * nx, fx * ty + fy * ly + fz * ny, fx * tz + fy * lz + fz * nz)


@kernel
def wrench_at_wheel_centre(wx, wy, wz, px, py, pz, fwx, fwy, fwz, tx, ty, tz, ax, ay, az, nx, ny, nz,
                           mx, my, mz):
    """(Fx, Fy, Fz, Mx, My, Mz) in world axes: the force F (world, [N]) acting at P and the moments
    mx about t, my about the axle a, mz about n [N m] moved to the wheel centre W:
    M_W = (P - W) x F + mx t + my a + mz n."""
    rx, ry, rz = px - wx, py - wy, pz - wz
    return (fwx, fwy, fwz,
            ry * fwz - rz * fwy + mx * tx + my * ax + mz * nx,
            rz * fwx - rx * fwz + mx * ty + my * ay + mz * ny,
            rx * fwy - ry * fwx + mx * tz + my * az + mz * nz)
