"""The linearised tyre: ISO signs, the same slopes as the Magic Formula at FNOMIN, saturation on the
friction ellipse at mu Fz, interchangeable with the MF kernel (also in the 1 ms start-from-rest loop)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rtsim.vehicle.kit.tyre import linear_forces, mf52_forces, rolling_resistance_moment, slip_stiffnesses
from rtsim.vehicle.kit.tyre.tir import P_LIN_CALPHA, P_LIN_CX, P_LIN_MUX, P_LIN_MUY
from test_tyre_mf import CLEAN, FZ0, P, TYRE, drive_from_rest, sign_changes

C = TYRE.coefficients


def lin(p, fz, kappa=0.0, alpha=0.0, gamma=0.0, vx=20.0, mu=1.0):
    return linear_forces(p, fz, kappa, alpha, gamma, vx, mu)


def test_parameters_come_from_the_same_tir_at_fnomin():
    kx, ky = slip_stiffnesses(P, FZ0, 0.0)
    assert P[P_LIN_CX] == pytest.approx(kx, rel=1e-12) and P[P_LIN_CALPHA] == pytest.approx(-ky, rel=1e-12)
    assert P[P_LIN_CALPHA] > 0
    assert P[P_LIN_MUX] == pytest.approx(C["PDX1"]) and P[P_LIN_MUY] == pytest.approx(abs(C["PDY1"]))


def test_iso_signs_and_zero_slip():
    assert lin(P, FZ0)[:3] == (0.0, 0.0, 0.0)
    assert lin(P, 0.0, 0.1, 0.1) == (0.0, 0.0, 0.0, 0.0)
    fx, fy, mz, _ = lin(P, FZ0, 0.01, 0.01)
    assert fx > 0 and fy < 0 and mz > 0          # drive forward; slide left -> pushed right; aligning
    fx, fy, mz, _ = lin(P, FZ0, -0.01, -0.01)
    assert fx < 0 and fy > 0 and mz < 0


def test_matches_the_magic_formula_slope_at_small_slip():
    h = 1e-5
    for name, i, kw in (("Fx", 0, "kappa"), ("Fy", 1, "alpha"), ("Mz", 2, "alpha")):
        d_lin = (lin(P, FZ0, **{kw: h})[i] - lin(P, FZ0, **{kw: -h})[i]) / (2 * h)
        d_mf = (mf52_forces(CLEAN, FZ0, *((h, 0.0) if kw == "kappa" else (0.0, h)), 0.0, 20.0, 1.0)[i]
                - mf52_forces(CLEAN, FZ0, *((-h, 0.0) if kw == "kappa" else (0.0, -h)), 0.0, 20.0, 1.0)[i]) / (2 * h)
        assert d_lin == pytest.approx(d_mf, rel=1e-6 if name != "Mz" else 1e-2), name
    # and the forces agree to within 2 % over the MF's near-linear range
    for s in (0.002, 0.005):
        assert lin(P, FZ0, kappa=s)[0] == pytest.approx(mf52_forces(CLEAN, FZ0, s, 0.0, 0.0, 20.0, 1.0)[0], rel=0.02)
        assert lin(P, FZ0, alpha=s)[1] == pytest.approx(mf52_forces(CLEAN, FZ0, 0.0, s, 0.0, 20.0, 1.0)[1], rel=0.02)


def test_saturates_at_mu_fz_on_the_friction_ellipse():
    mux, muy = P[P_LIN_MUX], P[P_LIN_MUY]
    for fz in (1000.0, FZ0, 4000.0):
        for mu in (1.0, 0.5):
            assert lin(P, fz, kappa=1.0, mu=mu)[0] == pytest.approx(mu * mux * fz, rel=1e-12)
            assert lin(P, fz, kappa=-1.0, mu=mu)[0] == pytest.approx(-mu * mux * fz, rel=1e-12)
            assert lin(P, fz, alpha=0.5, mu=mu)[1] == pytest.approx(-mu * muy * fz, rel=1e-12)
            for ang in np.linspace(0, 2 * math.pi, 13):
                kappa, alpha = 0.5 * math.cos(ang), 0.5 * math.sin(ang)
                fx, fy, _, _ = lin(P, fz, kappa, alpha, mu=mu)
                assert (fx / (mu * mux * fz)) ** 2 + (fy / (mu * muy * fz)) ** 2 == pytest.approx(1.0, rel=1e-12)
                # saturation keeps the direction of the linear force
                assert fx * (-P[P_LIN_CALPHA] * alpha) == pytest.approx(fy * P[P_LIN_CX] * kappa, abs=1e-6)
    # below saturation it is exactly linear
    assert lin(P, FZ0, kappa=0.01)[0] == pytest.approx(2 * lin(P, FZ0, kappa=0.005)[0], rel=1e-12)


def test_rolling_resistance_as_the_magic_formula():
    for vx in (-10.0, -0.3, 0.0, 0.4, 3.0, 25.0):
        fx = lin(P, FZ0, kappa=0.01, vx=vx)[0]
        assert lin(P, FZ0, kappa=0.01, vx=vx)[3] == rolling_resistance_moment(P, FZ0, fx, vx)


def test_interchangeable_in_the_start_from_rest_loop():
    fx_lin, v_lin = drive_from_rest(linear_forces, P, 150.0)
    fx_mf, v_mf = drive_from_rest(mf52_forces, P, 150.0)
    assert np.all(fx_lin >= 0.0)
    flips, zigzags = sign_changes(fx_lin, 1e-6)
    assert zigzags == 0 and flips <= 6
    # small slips: the two models drive the car alike (load 0.74 FNOMIN, so not identical)
    assert v_lin[-1] == pytest.approx(v_mf[-1], rel=0.02)
