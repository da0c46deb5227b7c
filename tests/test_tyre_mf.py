"""Magic Formula 5.2 kernels against analytic properties of the formula (not printed numbers), and the
transient-slip contact model in tiny 1 ms simulation loops (standstill, start from rest)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rtsim.vehicle.kit.tyre import (advance_deflections, deflection_rates, describe, effective_rolling_radius, load_tir,
                                loaded_radius, mf52_forces, new_slip_state, peak_slips, relaxation_lengths,
                                rolling_resistance_moment, slip_stiffnesses, steady_slip, transient_slip,
                                vertical_force)
from rtsim.vehicle.kit.tyre import tir as T
from rtsim.vehicle.kit.tyre.magic_formula import S_U, S_V

SHIPPED = Path(__file__).resolve().parents[1] / "configs" / "tyres" / "michelin_155_80_r13.tir"
TYRE = load_tir(SHIPPED)
P = TYRE.params
C = TYRE.coefficients
FZ0 = TYRE.fnomin
G = 9.81

# offsets and the asymmetric (sign-dependent) coefficients of the shipped file; zeroed where a test
# needs the formula's symmetric form
OFFSETS = ("PHX1 PHX2 PVX1 PVX2 PEX4 PHY1 PHY2 PHY3 PVY1 PVY2 PVY3 PVY4 PEY3 PEY4 RHX1 RHY1 RHY2 RVY1 "
           "RVY2 RVY3 QHZ1 QHZ2 QHZ3 QHZ4 QDZ6 QDZ7 QDZ8 QDZ9 QEZ4 QEZ5").split()


def with_params(p=P, **changes) -> np.ndarray:
    q = np.array(p, dtype=np.float64)
    for key, value in changes.items():
        q[getattr(T, "P_" + key)] = value
    return q


CLEAN = with_params(**{k: 0.0 for k in OFFSETS})


def mf(p, fz, kappa=0.0, alpha=0.0, gamma=0.0, vx=20.0, mu=1.0):
    return mf52_forces(p, fz, kappa, alpha, gamma, vx, mu)


def kx_formula(fz, lkx=1.0):
    dfz = (fz - FZ0) / FZ0
    return fz * (C["PKX1"] + C["PKX2"] * dfz) * math.exp(C["PKX3"] * dfz) * lkx


def kya_formula(fz, gamma=0.0, lky=1.0):
    return (C["PKY1"] * FZ0 * math.sin(2 * math.atan(fz / (C["PKY2"] * FZ0)))
            * (1 - C["PKY3"] * abs(gamma)) * lky)


# ---- steady state, pure slip ----------------------------------------------------------------------
@pytest.mark.parametrize("fz", [800.0, FZ0, 4500.0])
def test_zero_slip_gives_zero_force_without_offsets(fz):
    fx, fy, mz, _ = mf(CLEAN, fz)
    assert abs(fx) < 1e-9 and abs(fy) < 1e-9 and abs(mz) < 1e-9


def test_airborne_tyre_gives_nothing():
    assert mf(P, 0.0, 0.1, 0.1) == (0.0, 0.0, 0.0, 0.0)
    assert mf(P, -50.0, 0.1, 0.1) == (0.0, 0.0, 0.0, 0.0)


def test_odd_symmetry_without_offsets():
    for s in np.linspace(0.001, 0.6, 40):
        fx_p, fy_p, mz_p, _ = mf(CLEAN, FZ0, alpha=s)
        fx_m, fy_m, mz_m, _ = mf(CLEAN, FZ0, alpha=-s)
        assert fy_m == pytest.approx(-fy_p, rel=1e-12) and mz_m == pytest.approx(-mz_p, rel=1e-12, abs=1e-12)
        kx_p = mf(CLEAN, FZ0, kappa=s)[0]
        kx_m = mf(CLEAN, FZ0, kappa=-s)[0]
        assert kx_m == pytest.approx(-kx_p, rel=1e-12)


@pytest.mark.parametrize("fz", [0.5 * FZ0, FZ0, 1.5 * FZ0])
def test_initial_slopes_equal_the_analytic_slip_stiffnesses(fz):
    h = 1e-6
    dfx = (mf(CLEAN, fz, kappa=h)[0] - mf(CLEAN, fz, kappa=-h)[0]) / (2 * h)
    assert dfx == pytest.approx(kx_formula(fz), rel=1e-6)
    for gamma in (0.0, 0.03):
        dfy = (mf(CLEAN, fz, alpha=h, gamma=gamma)[1] - mf(CLEAN, fz, alpha=-h, gamma=gamma)[1]) / (2 * h)
        assert dfy == pytest.approx(kya_formula(fz, gamma), rel=1e-6)
        kx, ky = slip_stiffnesses(P, fz, gamma)
        assert kx == pytest.approx(kx_formula(fz), rel=1e-12) and ky == pytest.approx(kya_formula(fz, gamma), rel=1e-12)
    # the scaling factors scale the slopes
    scaled = with_params(CLEAN, LKX=0.7, LKY=1.2)
    dfx = (mf(scaled, fz, kappa=h)[0] - mf(scaled, fz, kappa=-h)[0]) / (2 * h)
    dfy = (mf(scaled, fz, alpha=h)[1] - mf(scaled, fz, alpha=-h)[1]) / (2 * h)
    assert dfx == pytest.approx(kx_formula(fz, 0.7), rel=1e-6)
    assert dfy == pytest.approx(kya_formula(fz, lky=1.2), rel=1e-6)
    assert kya_formula(fz) < 0          # ISO: positive slip angle, negative lateral force


@pytest.mark.parametrize("fz", [FZ0, 1.5 * FZ0])
def test_peak_friction_is_pdx_pdy(fz):
    dfz = (fz - FZ0) / FZ0
    s = np.linspace(0.0, 0.6, 30001)
    fx = np.array([mf(CLEAN, fz, kappa=k)[0] for k in s])
    fy = np.array([mf(CLEAN, fz, alpha=a)[1] for a in s])
    fxn = np.array([mf(CLEAN, fz, kappa=-k)[0] for k in s])
    assert fx.max() / fz == pytest.approx(C["PDX1"] + C["PDX2"] * dfz, rel=1e-6)
    assert -fxn.min() / fz == pytest.approx(C["PDX1"] + C["PDX2"] * dfz, rel=1e-6)
    assert -fy.min() / fz == pytest.approx(C["PDY1"] + C["PDY2"] * dfz, rel=1e-6)
    # the kernel's peak slips are where those peaks are
    kpk, apk = peak_slips(CLEAN, fz, 0.0)
    assert kpk == pytest.approx(s[fx.argmax()], abs=1e-3)
    assert math.atan(apk) == pytest.approx(s[fy.argmin()], abs=1e-3)


def test_fx_saturates():
    dx = C["PDX1"] * FZ0
    fx = np.array([mf(P, FZ0, kappa=k)[0] for k in np.linspace(0.0, 10.0, 2001)])
    assert fx.max() <= dx * (1 + 1e-3)
    after = fx[np.argmax(fx):]
    assert np.all(np.diff(after) <= 1e-9)                          # falls monotonically after the peak
    assert 0.5 * dx < fx[-1] < fx.max()                             # to a sliding level
    assert abs(mf(P, FZ0, kappa=5.0)[0] - mf(P, FZ0, kappa=10.0)[0]) < 0.03 * dx   # flat: saturated
    assert abs(mf(P, FZ0, kappa=-1.0)[0]) <= dx * (1 + 1e-3)          # locked wheel


def test_combined_slip_reduces_each_force():
    alphas = np.linspace(0.0, 0.3, 31)
    for kappa in (0.03, 0.1, -0.1):
        fx = np.array([mf(CLEAN, FZ0, kappa=kappa, alpha=a)[0] for a in alphas])
        gxa = fx / fx[0]
        assert np.all((gxa > 0) & (gxa <= 1 + 1e-12)) and np.all(np.diff(np.abs(fx)) < 0)
        fxm = np.array([mf(CLEAN, FZ0, kappa=kappa, alpha=-a)[0] for a in alphas])
        np.testing.assert_allclose(fxm, fx, rtol=1e-12)
    kappas = np.linspace(0.0, 1.0, 41)
    for alpha in (0.02, 0.08, -0.08):
        fy = np.array([mf(CLEAN, FZ0, kappa=k, alpha=alpha)[1] for k in kappas])
        gyk = fy / fy[0]
        assert np.all((gyk > 0) & (gyk <= 1 + 1e-12)) and np.all(np.diff(np.abs(fy)) < 0)
        fyb = np.array([mf(CLEAN, FZ0, kappa=-k, alpha=alpha)[1] for k in kappas])   # braking too
        assert np.all(np.diff(np.abs(fyb)) < 0)
    # with the shipped coefficients the combined force stays near the friction ellipse (the MF
    # weighting functions are fitted shapes, not an ellipse law: a few % outside is normal)
    for kappa in np.linspace(-1, 1, 41):
        for alpha in np.linspace(-0.4, 0.4, 41):
            fx, fy, _, _ = mf(P, FZ0, kappa, alpha)
            assert (fx / (C["PDX1"] * FZ0)) ** 2 + (fy / (C["PDY1"] * FZ0)) ** 2 <= 1.1


def test_friction_scale_halves_the_peaks_not_the_slopes():
    s = np.linspace(0.0, 0.8, 8001)
    for fz in (0.6 * FZ0, FZ0):
        fx1 = max(mf(CLEAN, fz, kappa=k)[0] for k in s)
        fx2 = max(mf(CLEAN, fz, kappa=k, mu=0.5)[0] for k in s)
        fy1 = min(mf(CLEAN, fz, alpha=a)[1] for a in s)
        fy2 = min(mf(CLEAN, fz, alpha=a, mu=0.5)[1] for a in s)
        assert fx2 == pytest.approx(0.5 * fx1, rel=1e-6) and fy2 == pytest.approx(0.5 * fy1, rel=1e-6)
        h = 1e-7
        assert mf(CLEAN, fz, kappa=h, mu=0.5)[0] / h == pytest.approx(kx_formula(fz), rel=1e-5)
    assert mf(P, FZ0, 0.1, 0.1, mu=0.0)[:2] == (0.0, 0.0)


def test_aligning_moment_restores():
    for alpha in np.linspace(0.005, 0.08, 16):
        _, fy, mz, _ = mf(P, FZ0, alpha=alpha)
        _, fyn, mzn, _ = mf(P, FZ0, alpha=-alpha)
        assert fy < 0 < mz and mzn < 0 < fyn               # Mz turns the wheel towards its velocity
        # pneumatic trail behind the contact centre: -Mz/Fy ~ 1-4 cm
        assert 0.005 < -mz / fy < 0.04
        # reversing: the trail is on the other side
        assert mf(CLEAN, FZ0, alpha=alpha, vx=-20.0)[2] == pytest.approx(-mf(CLEAN, FZ0, alpha=alpha)[2])


def test_rolling_resistance_opposes_rolling():
    r0, q1 = TYRE.unloaded_radius, C["QSY1"]
    no_speed = with_params(QSY3=0.0, QSY4=0.0)
    for vx in (1.5, 5.0, 30.0):
        assert mf(no_speed, FZ0, vx=vx)[3] == pytest.approx(-FZ0 * r0 * q1, rel=1e-12)
        assert mf(no_speed, FZ0, vx=-vx)[3] == pytest.approx(FZ0 * r0 * q1, rel=1e-12)
    assert mf(P, FZ0, vx=1.5)[3] == pytest.approx(-FZ0 * r0 * q1, rel=0.03)       # low speed
    assert mf(P, FZ0, vx=30.0)[3] < mf(P, FZ0, vx=5.0)[3] < 0                        # grows with speed
    assert rolling_resistance_moment(P, FZ0, 0.0, 5.0) == mf(P, FZ0, vx=5.0)[3]
    # smooth through standstill: zero at rest, no jump
    v = np.linspace(-2.0, 2.0, 4001)
    my = np.array([mf(P, FZ0, vx=x)[3] for x in v])
    assert my[2000] == 0.0 and np.max(np.abs(np.diff(my))) < 0.02 * FZ0 * r0 * q1
    assert np.all(my[v > 0] < 0) and np.all(my[v < 0] > 0)


def test_radii_and_vertical_force():
    cz = TYRE.vertical_stiffness
    assert loaded_radius(P, FZ0) == pytest.approx(TYRE.unloaded_radius - FZ0 / cz)
    re = [effective_rolling_radius(P, f) for f in (0.0, 1000.0, FZ0, 5000.0)]
    assert re[0] == TYRE.unloaded_radius and all(np.diff(re) < 0)
    # Re lies between the loaded and the free radius (MF: deflection at Re ~ 1/3..1/2 of the total)
    assert loaded_radius(P, FZ0) < re[2] < TYRE.unloaded_radius
    assert vertical_force(P, 0.01, 0.0) == pytest.approx(cz * 0.01)
    assert vertical_force(P, -0.01, 0.0) == 0.0 and vertical_force(P, 0.001, -10.0) == 0.0


def test_describe_reports_the_derived_values():
    d = describe(TYRE)
    assert d["longitudinal_slip_stiffness_n"] == pytest.approx(kx_formula(FZ0))
    assert d["cornering_stiffness_n_per_rad"] == pytest.approx(kya_formula(FZ0))
    assert d["contact_stiffness_long_n_per_m"] == pytest.approx(C["LONGITUDINAL_STIFFNESS"], rel=0.01)
    assert d["contact_stiffness_lat_n_per_m"] == pytest.approx(C["LATERAL_STIFFNESS"], rel=0.01)
    assert d["mu_x_peak"] == C["PDX1"] and d["mu_y_peak"] == C["PDY1"]
    assert 0.05 < d["peak_slip_long"] < 0.25 and 0.05 < d["peak_slip_angle_rad"] < 0.25
    low = describe(TYRE, 0.5 * FZ0)
    assert low["mu_x_peak"] == pytest.approx(C["PDX1"] - 0.5 * C["PDX2"])
    assert low["relaxation_length_long_m"] < d["relaxation_length_long_m"]


# ---- low speed: the transient-slip contact model ---------------------------------------------------
def test_wheel_at_rest_with_zero_spin_gives_zero_force():
    st = new_slip_state(1)
    re = effective_rolling_radius(P, FZ0)
    kappa, alpha = transient_slip(P, st, 0, FZ0, 0.0, 0.0, 0.0, 0.0, re)
    assert (kappa, alpha) == (0.0, 0.0)
    assert mf(P, FZ0, kappa, alpha, 0.0, vx=0.0) == (0.0, 0.0, 0.0, 0.0)      # shipped offsets faded out
    assert mf(P, FZ0, kappa, alpha, 0.03, vx=0.0) == (0.0, 0.0, 0.0, 0.0)     # camber thrust too
    assert steady_slip(P, 0.0, 0.0, 0.0, re) == (0.0, 0.0)
    for _ in range(100):
        advance_deflections(P, st, 0, FZ0, 0.0, 0.0, 0.0, 0.0, re, 1e-3)
    assert np.all(st == 0.0)


@pytest.mark.parametrize("dt", [1e-3, 1e-2])
def test_transient_slip_relaxes_with_time_constant_sigma_over_vx(dt):
    fz, vx, kappa_ss, alpha_ss = FZ0, 10.0, 0.02, 0.015
    re = effective_rolling_radius(P, fz)
    omega = vx * (1 + kappa_ss) / re
    vsy = vx * math.tan(alpha_ss)
    sk, sa = relaxation_lengths(P, fz, 0.0)
    assert 0.1 <= sk <= 0.3 and 0.1 <= sa <= 0.4
    st = new_slip_state(2)            # use row 1: rows are independent
    n = int(round(10 * sa / vx / dt)) + 1
    for k in range(1, n + 1):
        advance_deflections(P, st, 1, fz, 0.0, vx, vsy, omega, re, dt)
        t = k * dt
        assert st[1, S_U] / sk == pytest.approx(kappa_ss * (1 - math.exp(-vx * t / sk)), rel=1e-9)
        assert st[1, S_V] / sa == pytest.approx(vsy / vx * (1 - math.exp(-vx * t / sa)), rel=1e-9)
    assert np.all(st[0] == 0.0)
    # after ten time constants the force-law input is the steady slip (the damping term has died out)
    kappa, alpha = transient_slip(P, st, 1, fz, 0.0, vx, vsy, omega, re)
    assert kappa == pytest.approx(kappa_ss, rel=1e-4) and alpha == pytest.approx(alpha_ss, rel=1e-3)
    assert steady_slip(P, vx, vsy, omega, re) == pytest.approx((kappa_ss, alpha_ss), rel=1e-12)


def test_deflection_rates_match_the_exact_step():
    fz, vx, vsy, dt = 0.8 * FZ0, 3.0, 0.1, 1e-3
    re = effective_rolling_radius(P, fz)
    omega = vx * 1.05 / re
    st = new_slip_state(1)
    u = v = 0.0
    h = dt / 20
    for _ in range(50):                       # RK4 on the rates, 20 sub-steps per step
        advance_deflections(P, st, 0, fz, 0.0, vx, vsy, omega, re, dt)
        for _ in range(20):
            k1 = deflection_rates(P, fz, 0.0, vx, vsy, omega, re, u, v)
            k2 = deflection_rates(P, fz, 0.0, vx, vsy, omega, re, u + h / 2 * k1[0], v + h / 2 * k1[1])
            k3 = deflection_rates(P, fz, 0.0, vx, vsy, omega, re, u + h / 2 * k2[0], v + h / 2 * k2[1])
            k4 = deflection_rates(P, fz, 0.0, vx, vsy, omega, re, u + h * k3[0], v + h * k3[1])
            u += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            v += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    assert st[0, S_U] == pytest.approx(u, rel=1e-10) and st[0, S_V] == pytest.approx(v, rel=1e-10)


def test_standstill_spin_does_not_wind_up():
    """A wheel spinning at standstill (burnout): the deflection stays bounded, and once the spin stops
    it is at once no larger than the peak-force slip, so no stored 'memory' pushes the car on."""
    fz = FZ0
    re = effective_rolling_radius(P, fz)
    sk, _ = relaxation_lengths(P, fz, 0.0)
    kpk, _ = peak_slips(P, fz, 0.0)
    st = new_slip_state(1)
    for _ in range(2000):
        advance_deflections(P, st, 0, fz, 0.0, 0.0, 0.0, 2.0 / re, re, 1e-3)
    assert st[0, S_U] == pytest.approx(sk * 2.0 / TYRE.vxlow)         # |Vsx|/VXLOW
    fx = mf(P, fz, *transient_slip(P, st, 0, fz, 0.0, 0.0, 0.0, 2.0 / re, re), 0.0, 0.0)[0]
    assert 0.5 * C["PDX1"] * fz < fx <= C["PDX1"] * fz * 1.001        # the sliding force, forward
    advance_deflections(P, st, 0, fz, 0.0, 0.0, 0.0, 0.0, re, 1e-3)
    assert st[0, S_U] == pytest.approx(sk * kpk)


# ---- 1 ms loops: a quarter car on one tyre ---------------------------------------------------------
M_QUARTER = 850.0 / 4                  # kg
I_WHEEL = 0.85                         # kg m^2, a driven rear wheel (configs/vehicles/xbw.toml)
DT = 1e-3


def sign_changes(x: np.ndarray, tol: float) -> tuple[int, int]:
    """(sign changes of the increments, step-to-step zigzags), increments below tol ignored."""
    d = np.diff(x)
    s = np.sign(np.where(np.abs(d) < tol, 0.0, d))
    s = s[s != 0]
    flips = np.flatnonzero(s[1:] != s[:-1])
    zigzags = int(np.sum(np.diff(flips) == 1))
    return len(flips), zigzags


def drive_from_rest(force_kernel, p, torque=150.0, slip="transient", steps=1000):
    """Wheel (spin omega, inertia I) + quarter-car mass (speed V) on one tyre, a drive torque applied
    at t = 0, semi-implicit Euler at 1 ms. Returns arrays of Fx and V."""
    fz = M_QUARTER * G
    re = effective_rolling_radius(p, fz)
    st = new_slip_state(1)
    w = v = 0.0
    fxs, vs = np.empty(steps), np.empty(steps)
    for k in range(steps):
        if slip == "transient":
            kappa, alpha = transient_slip(p, st, 0, fz, 0.0, v, 0.0, w, re)
        else:
            kappa, alpha = steady_slip(p, v, 0.0, w, re)
        fx, _, _, my = force_kernel(p, fz, kappa, alpha, 0.0, v, 1.0)
        w += DT * (torque - fx * re + my) / I_WHEEL
        v += DT * fx / M_QUARTER
        advance_deflections(p, st, 0, fz, 0.0, v, 0.0, w, re, DT)
        fxs[k], vs[k] = fx, v
    return fxs, vs


def test_driven_wheel_starts_from_rest_smoothly():
    torque = 150.0
    fx, v = drive_from_rest(mf52_forces, P, torque)
    assert np.all(fx >= 0.0) and np.all(np.diff(v) >= 0.0)              # never pulls back
    flips, zigzags = sign_changes(fx, 1e-6)
    assert zigzags == 0 and flips <= 6            # rises, overshoots once, settles: no chatter
    assert v[-1] > 2.0 * TYRE.vxlow                                      # crossed the low-speed band
    re = effective_rolling_radius(P, M_QUARTER * G)
    m_eq = M_QUARTER + I_WHEEL / re ** 2
    my = rolling_resistance_moment(P, M_QUARTER * G, fx[-1], v[-1])
    assert fx[-1] == pytest.approx((torque + my) / re * M_QUARTER / m_eq, rel=0.02)   # F = m a
    # builds up over the wheel's spin mode (a few ms), not in one step
    assert fx[0] == 0.0 and fx[1] < 0.5 * fx[-1] and np.argmax(fx > 0.9 * fx[-1]) >= 3


def test_steady_slip_at_low_speed_would_chatter():
    """The contrast that motivates the transient model: the same loop fed with the steady slip
    kappa = (omega Re - Vx)/max(|Vx|, VXLOW) oscillates step to step."""
    fx, _ = drive_from_rest(mf52_forces, P, slip="steady", steps=300)
    _, zigzags = sign_changes(fx, 1e-6)
    assert zigzags > 50


def test_braked_wheel_holds_the_car_on_a_slope_without_creep():
    """Locked wheel (a held brake) on a 10 % downhill: the tyre's contact spring takes the load; the
    car settles (damped), does not creep, and the force never changes sign."""
    fz = M_QUARTER * G
    re = effective_rolling_radius(P, fz)
    f_slope = M_QUARTER * G * math.sin(math.atan(0.10))
    st = new_slip_state(1)
    x = v = 0.0
    n = 1500
    fxs, xs, vs = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        kappa, alpha = transient_slip(P, st, 0, fz, 0.0, v, 0.0, 0.0, re)
        fx = mf52_forces(P, fz, kappa, alpha, 0.0, v, 1.0)[0]
        v += DT * (fx + f_slope) / M_QUARTER
        x += DT * v
        advance_deflections(P, st, 0, fz, 0.0, v, 0.0, 0.0, re, DT)
        fxs[k], xs[k], vs[k] = fx, x, v
    assert np.all(fxs[1:] < 0.0)                                         # always holding back
    assert fxs[-1] == pytest.approx(-f_slope, rel=1e-3)
    assert abs(vs[-1]) < 1e-4 and abs(xs[-1] - xs[-500]) < 1e-5          # at rest, no creep
    sk, _ = relaxation_lengths(P, fz, 0.0)
    kx, _ = slip_stiffnesses(P, fz, 0.0)
    assert xs[-1] == pytest.approx(f_slope / (kx / sk), rel=0.05)       # static contact spring
    flips, zigzags = sign_changes(fxs, 1e-6)
    assert zigzags == 0 and flips <= 20                                  # a few damped swings only
