"""The car's size and key parameters in SI units, derived from its model (`rtsim describe`)."""
from __future__ import annotations

import math

import numpy as np

from ..kit.brake import brake_gains
from ..kit.linkages import OUT_AXIS
from ..kit.tyre.magic_formula import effective_rolling_radius, slip_stiffnesses
from .build import VehicleModel
from .sim import VehicleSim


def describe(model: VehicleModel, sim: VehicleSim) -> dict:
    """The model's size and key parameters in SI units (`rtsim describe`)."""
    cfg = model.config
    mech = model.mech
    loads = model.static_loads
    w = model.design_wheel_centre
    cg = np.array(cfg.chassis.cg_m)
    m_total = cfg.chassis.mass_kg + 2 * cfg.front.unsprung_mass_kg + 2 * cfg.rear.unsprung_mass_kg
    cg_total_z = (cfg.chassis.mass_kg * cg[2] + 2 * cfg.front.unsprung_mass_kg * w[0, 2]
                  + 2 * cfg.rear.unsprung_mass_kg * w[2, 2]) / m_total
    cg_total_x = (cfg.chassis.mass_kg * cg[0] + 2 * cfg.front.unsprung_mass_kg * w[0, 0]
                  + 2 * cfg.rear.unsprung_mass_kg * w[2, 0]) / m_total
    kf = slip_stiffnesses(sim.tp, loads[0], 0.0)
    kr = slip_stiffnesses(sim.tp, loads[2], 0.0)
    gains = brake_gains(sim.bcfg)
    return {
        "name": cfg.name,
        "id": cfg.id,
        "n_coordinates": mech.model.nq,
        "n_constraints": mech.model.nc,
        "n_dof": mech.model.nq - mech.model.nc,
        "mass": m_total,
        "wheelbase": float(w[0, 0] - w[2, 0]),
        "track_front": float(2 * w[0, 1]),
        "track_rear": float(2 * w[2, 1]),
        "cg_height": float(cg_total_z),
        "cg_to_front_axle": float(w[0, 0] - cg_total_x),
        "wheel_radius": float(effective_rolling_radius(sim.tp, loads[0])),
        "wheel_inertia": cfg.front.wheel_spin_inertia_kgm2,
        "cornering_stiffness_front": float(abs(kf[1])),
        "cornering_stiffness_rear": float(abs(kr[1])),
        "slip_stiffness": float(kf[0]),
        "rolling_resistance_coefficient": float(sim.tyre.coefficients.get("QSY1", 0.0)),
        "drag_area": cfg.aero.drag_area_m2,
        "brake_gain_front": gains["front_Nm_per_kPa"],
        "brake_gain_rear": gains["rear_Nm_per_kPa"],
        "steering_ratio": _steering_ratio(model, sim),
        "static_wheel_loads": [float(x) for x in loads],
        "suspension_fit_error": max(k.fit_error for k in model.corners),
    }


def _steering_ratio(model: VehicleModel, sim: VehicleSim) -> float:
    """Steering-wheel angle per mean front road-wheel angle around straight ahead. With electric power
    steering the fitted corners are functions of the knuckle's own angle (the tie rods are constraints),
    so the ratio is the front linkage's with the EPS rack (as the config's check computes it)."""
    cfg = model.config
    if cfg.eps is not None:
        from ..kit.linkage_checks import steering_ratio
        from ..kit.linkages import DoubleWishbone, VerticalSlider
        hp = {k: None if v is None else np.array(v, dtype=float) for k, v in cfg.front.hardpoints.model_dump().items()}
        geom = (DoubleWishbone if cfg.front.suspension == "double_wishbone" else VerticalSlider)(
            spin_axis=cfg.front.spin_axis(), **hp)
        return float(steering_ratio(geom, cfg.eps.rack_travel_per_rad_m))
    rp = sim.stcfg.rack_travel_per_rad
    ds = 1e-3
    angles = []
    for k in model.corners[:2]:
        a = k.evaluate(OUT_AXIS, 0.0, ds)
        angles.append(math.atan2(-a[0], a[1]))
    road_per_rack = float(np.mean(angles)) / ds
    return 1.0 / (rp * road_per_rack)
