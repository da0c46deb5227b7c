"""Tyre models of the vehicle: Pacejka property files (`tir`), the Magic Formula 5.2 with combined slip
and a transient-slip contact model for standstill (`magic_formula`), and the seed paper's linearised
tyre (`linear`). See each module's docstring for equations, signs (ISO 8855) and array layouts.
"""
from __future__ import annotations

import math

from .linear import linear_forces
from .magic_formula import (N_SLIP_STATES, S_U, S_V, advance_deflections, deflection_rates,
                            effective_rolling_radius, loaded_radius, mf52_forces, new_slip_state, peak_slips,
                            relaxation_lengths, rolling_resistance_moment, slip_stiffnesses, steady_slip,
                            transient_slip, vertical_force)
from .tir import PARAM_NAMES, TyreProperties, format_tir, load_tir, parse_tir

__all__ = [
    "TyreProperties", "load_tir", "parse_tir", "format_tir", "PARAM_NAMES",
    "mf52_forces", "linear_forces", "slip_stiffnesses", "relaxation_lengths", "peak_slips",
    "rolling_resistance_moment", "loaded_radius", "effective_rolling_radius", "vertical_force",
    "steady_slip", "transient_slip", "deflection_rates", "advance_deflections", "new_slip_state",
    "S_U", "S_V", "N_SLIP_STATES", "describe",
]


def describe(props: TyreProperties, fz: float | None = None) -> dict[str, float]:
    """Derived values at load `fz` (default FNOMIN), gamma = 0, for reports: slip stiffnesses,
    relaxation lengths, contact stiffnesses, low-speed damping, radii, peak friction and slips."""
    p = props.params
    fz = props.fnomin if fz is None else float(fz)
    kx, ky = slip_stiffnesses(p, fz, 0.0)
    sk, sa = relaxation_lengths(p, fz, 0.0)
    kpk, apk = peak_slips(p, fz, 0.0)
    c = props.coefficients
    d_low = c["DAMP_RESIDUAL"] + c["DAMP_VLOW"]
    fz0 = props.fnomin * c["LFZO"]
    dfz = (fz - fz0) / fz0
    return {
        "fz_n": fz,
        "longitudinal_slip_stiffness_n": kx,
        "cornering_stiffness_n_per_rad": ky,
        "relaxation_length_long_m": sk,
        "relaxation_length_lat_m": sa,
        "contact_stiffness_long_n_per_m": kx / sk,
        "contact_stiffness_lat_n_per_m": abs(ky) / sa,
        "standstill_damping_long_ns_per_m": kx / sk * d_low,
        "standstill_damping_lat_ns_per_m": abs(ky) / sa * d_low,
        "loaded_radius_m": loaded_radius(p, fz),
        "effective_rolling_radius_m": effective_rolling_radius(p, fz),
        "peak_slip_long": kpk,
        "peak_slip_angle_rad": math.atan(apk),
        "mu_x_peak": abs(c["PDX1"] + c["PDX2"] * dfz) * c["LMUX"],
        "mu_y_peak": abs(c["PDY1"] + c["PDY2"] * dfz) * c["LMUY"],
    }
