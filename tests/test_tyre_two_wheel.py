"""Motorcycle tyre kernels against analytic references: toroidal contact geometry, the small-slip
limit (stiffnesses), camber thrust signs, the friction ellipse, relaxation as exp(-x/sigma),
standstill, the linear variant, the wrench at the wheel centre and the config."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from rtsim.vehicle.kit.tyre.two_wheel import (
    MODEL_LINEAR, TW_CA, TW_CG, TW_CK, TW_CX, TW_CY, TW_EX, TW_EY, TW_KZ, TW_KZ2, TW_CZ, TW_MODEL, TW_R0,
    TW_RHO, TW_S_U, TW_S_V, TW_SIGMA_A, TW_SIGMA_K, TW_SIZE, TW_TRAIL, TW_TWIST, MotorcycleTyres,
    TwoWheelTyreSpec, advance_two_wheel_slip, contact_force_world, new_two_wheel_slip_state,
    pack_two_wheel_tyre, peak_slip, sport_front, sport_rear, toroidal_contact, two_wheel_forces,
    two_wheel_friction, two_wheel_linear_forces, two_wheel_rolling_radius, two_wheel_stiffnesses,
    two_wheel_transient_slip, two_wheel_tyre_forces, two_wheel_vertical_force, wrench_at_wheel_centre)

FRONT = pack_two_wheel_tyre(sport_front())
REAR = pack_two_wheel_tyre(sport_rear())
TYRES = (FRONT, REAR)
LOADS = (300.0, 1300.0, 2500.0)


def leaned_axle(lean, yaw=0.0):
    """Axle of a wheel heading `yaw` and leaning `lean` (ISO roll, > 0 to the right) on a flat road."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([-s * math.cos(lean), c * math.cos(lean), math.sin(lean)])


def contact(p, w, a, q=(0.0, 0.0, 0.0), n=(0.0, 0.0, 1.0)):
    out = toroidal_contact(p, *w, *a, *q, *n)
    return np.array(out[:3]), out[3], out[4], np.array(out[5:8]), np.array(out[8:11])


def ellipse(p, fz, mu, fx, fy):
    fxm, fym = two_wheel_friction(p, fz, mu)
    return (fx / fxm) ** 2 + (fy / fym) ** 2


# ---- geometry -------------------------------------------------------------------------------------
@pytest.mark.parametrize("p", TYRES)
def test_leaned_wheel_contact_moves_round_the_crown(p):
    r0, rho = p[TW_R0], p[TW_RHO]
    n = np.array([0.0, 0.0, 1.0])
    for lean in (-0.9, -0.3, 0.0, 0.2, 0.7, 1.0):
        for d_set in (0.0, 0.012):
            a = leaned_axle(lean, yaw=0.4)
            h = rho + (r0 - rho) * math.cos(lean) - d_set         # centre height for penetration d_set
            w = np.array([1.0, 2.0, h])
            pt, d, gamma, t, l = contact(p, w, a)
            assert d == pytest.approx(d_set, abs=1e-12) and gamma == pytest.approx(lean, abs=1e-12)
            assert pt[2] == pytest.approx(0.0, abs=1e-12)                          # on the road
            assert (pt - w) @ a == pytest.approx(-(rho - d_set) * math.sin(lean), abs=1e-12)
            # in the road plane: (rho - d) tan(gamma) from the wheel plane's trace (knife-edge contact)
            knife = w + h / math.cos(lean) * (-(n - math.sin(lean) * a) / math.cos(lean))
            assert (pt - knife) @ l == pytest.approx(-(rho - d_set) * math.tan(lean), abs=1e-12)
            assert np.allclose([t @ t, l @ l, t @ n, t @ a, l @ n], [1, 1, 0, 0, 0], atol=1e-12)
            assert np.allclose(np.cross(n, t), l, atol=1e-12) and t[0] > 0    # heading forward
            assert two_wheel_rolling_radius(p, d_set, lean) == pytest.approx(
                r0 - rho + (rho - d_set / 3) * math.cos(lean), abs=1e-15)


def test_penetration_is_exact_on_a_tilted_road_and_negative_off_it():
    p = REAR
    r0, rho = p[TW_R0], p[TW_RHO]
    rng = np.random.default_rng(3)
    for _ in range(20):
        n = np.array([0.1, -0.15, 1.0]) + 0.1 * rng.standard_normal(3)
        n /= np.linalg.norm(n)
        a = rng.standard_normal(3)
        a -= 0.6 * (a @ n) * n                      # keep the wheel well away from lying flat
        a /= np.linalg.norm(a)
        q = rng.standard_normal(3)
        w = q + n * rng.uniform(0.1, 0.4) + rng.standard_normal(3) * 0.5
        pt, d, gamma, t, l = contact(p, w, a, q, n)
        h = (w - q) @ n
        assert gamma == pytest.approx(math.asin(a @ n), abs=1e-12)
        assert d == pytest.approx(rho + (r0 - rho) * math.cos(gamma) - h, abs=1e-12)
        assert (pt - q) @ n == pytest.approx(0.0, abs=1e-12)
        assert (pt - w) @ a == pytest.approx(-(rho - d) * math.sin(gamma), abs=1e-12)
        # the crown-circle centre: R - rho from W in the wheel plane, rho - d above the contact
        c = pt + (rho - d) * n
        assert np.linalg.norm(c - w) == pytest.approx(r0 - rho, abs=1e-12) and (c - w) @ a == pytest.approx(0, abs=1e-12)
        assert np.allclose(t, np.cross(a, n) / np.linalg.norm(np.cross(a, n)), atol=1e-12)
    # a flat-lying wheel: no contact, finite
    _, d, _, t, _ = contact(p, (0.0, 0.0, 0.1), (0.0, 0.0, 1.0))
    assert d < 0 and np.all(t == 0.0)


def test_vertical_force_pushes_only():
    p = FRONT.copy()
    p[TW_KZ2] = 2e6
    for d, rate in ((0.01, 0.0), (0.005, 0.3), (0.02, -0.1)):
        assert two_wheel_vertical_force(p, d, rate) == pytest.approx(p[TW_KZ] * d + p[TW_KZ2] * d * d + p[TW_CZ] * rate)
    assert two_wheel_vertical_force(p, -0.01, -1.0) == 0.0 and two_wheel_vertical_force(p, 0.0, 5.0) == 0.0
    assert two_wheel_vertical_force(p, 0.001, -100.0) == 0.0          # fast rebound: no pull


# ---- steady force law -----------------------------------------------------------------------------
def slope(f, i, h=1e-6):
    return (f(h)[i] - f(-h)[i]) / (2 * h)


@pytest.mark.parametrize("p", TYRES)
def test_small_slip_slopes_are_the_stiffnesses(p):
    for fz in LOADS:
        kk, ka, kg = two_wheel_stiffnesses(p, fz)
        assert kk == pytest.approx(p[TW_CK] * fz) and kg == pytest.approx(p[TW_CG] * fz)
        assert slope(lambda x: two_wheel_forces(p, fz, x, 0.0, 0.0, 20.0, 1.0), 0) == pytest.approx(kk, rel=1e-7)
        assert slope(lambda x: two_wheel_forces(p, fz, 0.0, x, 0.0, 20.0, 1.0), 1) == pytest.approx(-ka, rel=1e-7)
        assert slope(lambda x: two_wheel_forces(p, fz, 0.0, 0.0, x, 20.0, 1.0), 1) == pytest.approx(-kg, rel=1e-7)
        # aligning: trail times the slip force; twisting: toward the lean
        assert slope(lambda x: two_wheel_forces(p, fz, 0.0, x, 0.0, 20.0, 1.0), 4) == pytest.approx(p[TW_TRAIL] * ka, rel=1e-6)
        assert slope(lambda x: two_wheel_forces(p, fz, 0.0, 0.0, x, 20.0, 1.0), 4) == pytest.approx(
            -p[TW_TWIST] * fz, rel=1e-6)
    # the cornering stiffness falls per unit load as the load rises; the camber stiffness does not
    assert [two_wheel_stiffnesses(p, fz)[1] / fz for fz in LOADS] == sorted(
        [two_wheel_stiffnesses(p, fz)[1] / fz for fz in LOADS], reverse=True)


def test_camber_thrust_pushes_toward_the_lean():
    for p in TYRES:
        for fz in LOADS:
            fx, fy, mx, my, mz = two_wheel_forces(p, fz, 0.0, 0.0, 0.5, 15.0, 1.0)     # leaning right
            assert fx == 0.0 and fy < 0.0 and mz < 0.0 and mx < 0.0 and my < 0.0
            assert two_wheel_forces(p, fz, 0.0, 0.0, -0.5, 15.0, 1.0)[1] == pytest.approx(-fy, rel=1e-14)
            # slip to the left (alpha > 0) pushes right and aligns (Mz > 0); the law is odd
            f1 = two_wheel_forces(p, fz, 0.02, 0.03, 0.2, 15.0, 1.0)
            f2 = two_wheel_forces(p, fz, -0.02, -0.03, -0.2, 15.0, 1.0)
            assert f1[0] == pytest.approx(-f2[0]) and f1[1] == pytest.approx(-f2[1]) and f1[4] == pytest.approx(-f2[4])
            assert two_wheel_forces(p, fz, 0.0, 0.03, 0.0, 15.0, 1.0)[1] < 0
            assert two_wheel_forces(p, fz, 0.0, 0.03, 0.0, 15.0, 1.0)[4] > 0
    # a counter-steered slip angle cancels the camber thrust exactly: alpha_eq = tan(alpha) + g gamma
    fz = 1300.0
    _, ka, kg = two_wheel_stiffnesses(FRONT, fz)
    assert two_wheel_forces(FRONT, fz, 0.0, -math.atan(kg / ka * 0.4), 0.4, 15.0, 1.0)[1] == pytest.approx(0.0, abs=1e-9)


def test_friction_ellipse_never_exceeded_and_reached_at_the_peak():
    worst = 0.0
    for p in TYRES:
        for fz in (100.0, 1300.0, 3000.0):
            for mu in (1.0, 0.4):
                for kappa in np.linspace(-1.0, 1.0, 9):
                    for alpha in np.linspace(-0.6, 0.6, 9):
                        for gamma in (-0.9, 0.0, 0.5):
                            fx, fy, *_ = two_wheel_forces(p, fz, kappa, alpha, gamma, 20.0, mu)
                            worst = max(worst, ellipse(p, fz, mu, fx, fy))
    assert worst <= 1.0 + 1e-12
    # along any direction of (sx, sy) the force reaches the ellipse at the blended curve's peak slip
    p, fz, mu, gamma = REAR, 1800.0, 0.8, 0.3
    kk, ka, kg = two_wheel_stiffnesses(p, fz)
    fxm, fym = two_wheel_friction(p, fz, mu)
    for ang in np.linspace(0.0, 2 * math.pi, 11):
        cx, sy_ = math.cos(ang) ** 2, math.sin(ang) ** 2
        c = cx * p[TW_CX] + sy_ * p[TW_CY]
        s = peak_slip(c, cx * p[TW_EX] + sy_ * p[TW_EY])
        kappa = s * math.cos(ang) * fxm / kk
        alpha = math.atan((s * math.sin(ang) * fym - kg * gamma) / ka)
        fx, fy, *_ = two_wheel_forces(p, fz, kappa, alpha, gamma, 20.0, mu)
        assert ellipse(p, fz, mu, fx, fy) == pytest.approx(1.0, abs=1e-9)
        fx2, fy2, *_ = two_wheel_forces(p, fz, 1.3 * kappa, math.atan(1.3 * math.tan(alpha)), 0.0, 20.0, mu)
        assert ellipse(p, fz, mu, fx2, fy2) < 1.0                       # past the peak: sliding
    # pure slip peaks are mu_x Fz and mu_y Fz
    assert max(two_wheel_forces(p, fz, k, 0.0, 0.0, 20.0, mu)[0] for k in np.linspace(0, 0.5, 2001)) == pytest.approx(fxm, rel=1e-5)
    assert max(-two_wheel_forces(p, fz, 0.0, a, 0.0, 20.0, mu)[1] for a in np.linspace(0, 0.6, 2001)) == pytest.approx(fym, rel=1e-5)
    assert two_wheel_forces(p, fz, 0.3, 0.3, 0.3, 20.0, 0.0)[:2] == (0.0, 0.0)          # no grip


# ---- linear variant -------------------------------------------------------------------------------
@pytest.mark.parametrize("p", TYRES)
def test_linear_variant_is_the_small_slip_limit(p):
    lin = p.copy()
    lin[TW_MODEL] = MODEL_LINEAR
    for fz in LOADS:
        kk, ka, kg = two_wheel_stiffnesses(p, fz)
        fx, fy, mx, my, mz = two_wheel_linear_forces(p, fz, 0.1, 0.05, 0.4, 20.0, 1.0)
        assert fx == pytest.approx(kk * 0.1) and fy == pytest.approx(-(ka * math.tan(0.05) + kg * 0.4))   # unsaturated
        assert two_wheel_tyre_forces(lin, fz, 0.1, 0.05, 0.4, 20.0, 1.0) == (fx, fy, mx, my, mz)
        for i in range(5):
            for k in range(3):
                def full(x, i=i, k=k):
                    args = [0.0, 0.0, 0.0]
                    args[k] = x
                    return two_wheel_forces(p, fz, *args, 20.0, 1.0)

                def linear(x, i=i, k=k):
                    args = [0.0, 0.0, 0.0]
                    args[k] = x
                    return two_wheel_linear_forces(p, fz, *args, 20.0, 1.0)
                assert slope(linear, i) == pytest.approx(slope(full, i), rel=1e-6, abs=1e-6), (fz, i, k)
        small = (1e-5, -2e-5, 3e-5)
        assert np.allclose(two_wheel_linear_forces(p, fz, *small, 20.0, 1.0),
                           two_wheel_forces(p, fz, *small, 20.0, 1.0), rtol=1e-6)


# ---- relaxation and standstill --------------------------------------------------------------------
@pytest.mark.parametrize("dt", [1e-4, 2e-3])
def test_step_in_slip_relaxes_with_distance_constant_sigma(dt):
    p, fz, vx, re = FRONT, 1300.0, 12.0, 0.29
    alpha0, kappa0, gamma = 0.04, 0.03, 0.25
    _, ka, kg = two_wheel_stiffnesses(p, fz)
    g = kg / ka
    vsy = vx * math.tan(alpha0)
    omega = vx * (1 + kappa0) / re                  # kappa = (omega re - vx)/vx
    st = new_two_wheel_slip_state(2)
    sk, sa = p[TW_SIGMA_K], p[TW_SIGMA_A]
    for n in range(1, int(0.2 / dt) + 1):
        advance_two_wheel_slip(p, st, 1, fz, gamma, vx, vsy, omega, re, dt)
        x = n * dt * vx
        kap, alp = two_wheel_transient_slip(p, st, 1, fz, gamma, vx, vsy, omega, re)
        assert kap == pytest.approx(kappa0 * (1 - math.exp(-x / sk)), abs=1e-3 * kappa0)
        lat = math.tan(alp) + g * gamma                   # relaxed slip + camber equivalent
        assert lat == pytest.approx((math.tan(alpha0) + g * gamma) * (1 - math.exp(-x / sa)),
                                    abs=1e-3 * (math.tan(alpha0) + g * gamma))
    assert st[0, TW_S_U] == 0.0 and st[0, TW_S_V] == 0.0                        # other rows untouched
    assert st[1, TW_S_U] == pytest.approx(sk * kappa0, rel=1e-3) and st[1, TW_S_V] > 0


def test_standstill_gives_finite_zero_forces():
    for p in TYRES:
        st = new_two_wheel_slip_state(1)
        for gamma in (0.0, 0.3, -0.6):
            kap, alp = two_wheel_transient_slip(p, st, 0, 1300.0, gamma, 0.0, 0.0, 0.0, 0.3)
            for model in (two_wheel_forces, two_wheel_linear_forces):
                f = model(p, 1300.0, kap, alp, gamma, 0.0, 1.0)
                assert all(math.isfinite(x) for x in f)
                assert f == pytest.approx((0.0,) * 5, abs=1e-9)
            advance_two_wheel_slip(p, st, 0, 1300.0, gamma, 0.0, 0.0, 0.0, 0.3, 1e-3)
            assert st[0, TW_S_U] == 0.0 and st[0, TW_S_V] == 0.0
        # moments fade smoothly to zero as the speed does; zero slip gives zero force at any speed
        prev = None
        for vx in (1.0, 0.3, 0.1, 0.01, 1e-6, 0.0):
            f = two_wheel_forces(p, 1300.0, 0.0, 0.01, 0.2, vx, 1.0)
            assert all(math.isfinite(x) for x in f)
            if prev is not None:
                assert abs(f[3]) <= abs(prev[3]) and abs(f[4]) <= abs(prev[4])
            prev = f
        assert prev[3] == 0.0 and prev[4] == 0.0
        assert two_wheel_forces(p, 1300.0, 0.0, 0.0, 0.0, 0.0, 1.0) == (0.0, 0.0, 0.0, 0.0, 0.0)
        assert two_wheel_forces(p, 0.0, 0.2, 0.2, 0.2, 5.0, 1.0) == (0.0, 0.0, 0.0, 0.0, 0.0)
    # at rest a sideways push deflects the contact: a spring K_alpha/sigma_alpha (finite, no creep)
    p, fz = FRONT, 1300.0
    st = new_two_wheel_slip_state(1)
    for _ in range(10):
        advance_two_wheel_slip(p, st, 0, fz, 0.0, 0.0, 0.001, 0.0, 0.3, 1e-3)      # 1 mm/s for 10 ms
    assert st[0, TW_S_V] == pytest.approx(1e-5, rel=1e-12)
    kap, alp = two_wheel_transient_slip(p, st, 0, fz, 0.0, 0.0, 0.0, 0.0, 0.3)
    fy = two_wheel_forces(p, fz, kap, alp, 0.0, 0.0, 1.0)[1]
    assert fy == pytest.approx(-two_wheel_stiffnesses(p, fz)[1] / p[TW_SIGMA_A] * 1e-5, rel=1e-6)


# ---- wrench ---------------------------------------------------------------------------------------
def test_wrench_at_the_wheel_centre():
    p = REAR
    a = leaned_axle(0.6, yaw=-0.3)
    w = np.array([3.0, -1.0, 0.25])
    pt, d, gamma, t, l = contact(p, w, a)
    n = np.array([0.0, 0.0, 1.0])
    fx, fy, fz, mx, my, mz = 120.0, -900.0, 1500.0, 4.0, -7.0, 2.5
    f = np.array(contact_force_world(*t, *l, *n, fx, fy, fz))
    assert np.allclose(f, fx * t + fy * l + fz * n, atol=1e-12)
    out = wrench_at_wheel_centre(*w, *pt, *f, *t, *a, *n, mx, my, mz)
    assert np.allclose(out[:3], f, atol=1e-12)
    assert np.allclose(out[3:], np.cross(pt - w, f) + mx * t + my * a + mz * n, atol=1e-12)


# ---- config ---------------------------------------------------------------------------------------
def test_spec_packs_and_validates():
    assert FRONT.shape == (TW_SIZE,) and FRONT.dtype == np.float64 and np.all(np.isfinite(FRONT))
    assert FRONT[TW_R0] == 0.300 and REAR[TW_R0] == 0.315 and REAR[TW_RHO] > FRONT[TW_RHO]
    assert FRONT[TW_CA] == 14.0 and REAR[TW_CA] == 13.0 and FRONT[TW_MODEL] == 0.0
    pair = MotorcycleTyres.model_validate({"rear": {"model": "linear"}, "front": {"camber_stiffness_per_load": 1.0}})
    assert pack_two_wheel_tyre(pair.rear)[TW_MODEL] == MODEL_LINEAR
    assert pack_two_wheel_tyre(pair.front)[TW_CG] == 1.0 and pair.front.unloaded_radius_m == 0.300
    assert pack_two_wheel_tyre(pair.rear)[TW_SIGMA_K] == sport_rear().relaxation_length_long_m
    for bad in ({"crown_radius_m": 0.4}, {"mu_y": -1.0}, {"model": "brush"}, {"camber_stifness": 1.0}):
        with pytest.raises(ValidationError):
            TwoWheelTyreSpec.model_validate(bad)
    assert peak_slip(1.0, 0.0) >= 1e3 and peak_slip(1.6, 0.0) == pytest.approx(1.6 * math.tan(math.pi / 3.2))
    assert TW_SIGMA_A != TW_SIGMA_K and TW_S_U != TW_S_V


def test_vertical_force_is_continuous_at_touch_down():
    """A tyre landing fast: the force starts from zero at first contact (the damping builds up over the
    first DAMPING_ONSET of deflection) and is the full law beyond it."""
    from rtsim.vehicle.kit.tyre.two_wheel import DAMPING_ONSET

    p = FRONT.copy()
    rate = 3.0                                                          # m/s into the road
    assert two_wheel_vertical_force(p, 1e-9, rate) < 1e-3 * p[TW_CZ] * rate
    d = 0.5 * DAMPING_ONSET
    assert two_wheel_vertical_force(p, d, rate) == pytest.approx(p[TW_KZ] * d + p[TW_KZ2] * d * d + 0.5 * p[TW_CZ] * rate)
    d = DAMPING_ONSET
    assert two_wheel_vertical_force(p, d, rate) == pytest.approx(p[TW_KZ] * d + p[TW_KZ2] * d * d + p[TW_CZ] * rate)
