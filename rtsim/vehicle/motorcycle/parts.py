"""The two-wheeler's force-element parameters as the arrays rtsim.vehicle.motorcycle.step reads
(model/data separation: parameters here, the states in the sim)."""
from __future__ import annotations

from collections import namedtuple

import numpy as np

from ..kit.spring_damper import characteristic_table, stroke_spring_table, two_rate_damper_table
from ..kit.tables import table_1d
from ..kit.tyre.two_wheel import new_two_wheel_slip_state, pack_two_wheel_tyre
from .build import MotorcycleModel
from .config import Damper, Spring
from .step import (MP_BRAKE_EPS, MP_CDA, MP_CHAIN_CX, MP_CHAIN_CZ, MP_CHAIN_RF, MP_CHAIN_RR, MP_CLA, MP_CP_X,
                   MP_CP_Z, MP_FREE_SUSPENSION, MP_HAS_CHAIN, MP_LOCK, MP_MU, MP_RHO, MP_SHOCK_C0, MP_SHOCK_FX,
                   MP_SHOCK_FZ, MP_SHOCK_L0, MP_SHOCK_SX, MP_SHOCK_SZ, MP_SIZE, MP_SLIP_TYRES, MP_SPIN_F, MP_SPIN_R, MP_STEER_DAMP,
                   MP_STOP_K, MP_THETA0, T_FORK_DAMPER, T_FORK_SPRING, T_SHOCK_DAMPER, T_SHOCK_SPRING, TO_SIZE, U_SIZE)

TwoWheelerParts = namedtuple("TwoWheelerParts", ["idx", "par", "tab", "u", "tp", "slip", "tyre"])
BIG = 10.0    # m or m/s: the tables' outer points (they continue linearly beyond)


def spring_table(sp: Spring) -> np.ndarray:
    """Force (N) against compression from full extension (m): top-out stop below 0, the spring with its
    preload over the stroke, the bottom-out stop beyond it."""
    if sp.table is not None:
        return characteristic_table(sp.table)
    return stroke_spring_table(sp.stiffness_n_per_m, sp.preload_n, sp.stroke_m, sp.top_out_n_per_m,
                               sp.bottom_out_n_per_m, BIG)


def damper_table(dp: Damper) -> np.ndarray:
    if dp.table is not None:
        return characteristic_table(dp.table)
    return two_rate_damper_table(dp.compression_ns_per_m, dp.rebound_ns_per_m, BIG)


def frame_coordinates(mm: MotorcycleModel, point) -> tuple[float, float]:
    """A design-frame (x, z) point in the rear frame's axes (e1, h) from the pivot, m."""
    d = mm.design
    rel = np.array([point[0], 0.0, point[1]]) - d.pivot
    return float(rel @ d.e1), float(rel @ d.h)


def make_parts(mm: MotorcycleModel, mu: float = 1.0) -> TwoWheelerParts:
    cfg, des = mm.config, mm.design
    par = np.zeros(MP_SIZE)
    tab = np.zeros((4, table_1d([0.0, 1.0], [0.0, 0.0]).size))
    sus = cfg.suspension
    if not sus.locked:
        par[MP_FREE_SUSPENSION] = 1.0
        tab[T_FORK_SPRING] = spring_table(sus.fork.spring)
        tab[T_FORK_DAMPER] = damper_table(sus.fork.damper)
        tab[T_SHOCK_SPRING] = spring_table(sus.shock.spring)
        tab[T_SHOCK_DAMPER] = damper_table(sus.shock.damper)
        par[MP_SHOCK_FX], par[MP_SHOCK_FZ] = frame_coordinates(mm, sus.shock.frame_mount_m)
        par[MP_SHOCK_SX], par[MP_SHOCK_SZ] = frame_coordinates(mm, sus.shock.swingarm_mount_m)
        par[MP_SHOCK_L0] = np.hypot(par[MP_SHOCK_FX] - par[MP_SHOCK_SX], par[MP_SHOCK_FZ] - par[MP_SHOCK_SZ])
        par[MP_SHOCK_C0] = sus.shock.design_travel_m
    par[MP_THETA0] = des.theta0
    par[MP_STEER_DAMP] = cfg.steering.damper_nms_per_rad
    par[MP_LOCK] = cfg.steering.lock_rad
    par[MP_STOP_K] = cfg.steering.stop_nm_per_rad
    if cfg.chain is not None:
        par[MP_HAS_CHAIN] = 1.0
        par[MP_CHAIN_CX], par[MP_CHAIN_CZ] = frame_coordinates(mm, cfg.chain.front_sprocket_m)
        par[MP_CHAIN_RF] = cfg.chain.front_sprocket_radius_m
        par[MP_CHAIN_RR] = cfg.chain.rear_sprocket_radius_m
    a = cfg.aero
    par[MP_CDA], par[MP_CLA], par[MP_RHO] = a.drag_area_m2, a.lift_area_m2, a.air_density_kg_m3
    par[MP_CP_X], par[MP_CP_Z] = frame_coordinates(mm, a.centre_of_pressure_m)
    par[MP_BRAKE_EPS] = cfg.brakes.slip_speed_rad_s if cfg.brakes is not None else 0.5
    # the brakes' regularisation (step.py) scales with 1 / spin inertia; none: the config's slip speed alone
    par[MP_SPIN_F] = cfg.front_wheel.spin_inertia_kgm2 if cfg.front_wheel.spin_inertia_kgm2 > 0 else np.inf
    par[MP_SPIN_R] = cfg.rear_wheel.spin_inertia_kgm2 if cfg.rear_wheel.spin_inertia_kgm2 > 0 else np.inf
    par[MP_SLIP_TYRES] = 0.0 if mm.knife_edge else 1.0
    par[MP_MU] = mu
    tp = np.zeros((2, pack_two_wheel_tyre(cfg.tyres.front).size))
    for w, (spec, wheel) in enumerate(((cfg.tyres.front, cfg.front_wheel), (cfg.tyres.rear, cfg.rear_wheel))):
        tp[w] = pack_two_wheel_tyre(spec.model_copy(update={"unloaded_radius_m": wheel.radius_m}))
    return TwoWheelerParts(idx=mm.bike.idx.copy(), par=par, tab=tab, u=np.zeros(U_SIZE), tp=tp,
                           slip=new_two_wheel_slip_state(2), tyre=np.zeros((2, TO_SIZE)))
