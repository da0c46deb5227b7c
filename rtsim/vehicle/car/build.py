"""Building the four-wheel car's multibody model from its configuration and the kit's parts.

Mixed natural coordinates, 16 degrees of freedom:
- chassis (sprung mass): its centre of mass r and the unit vectors u, v, w of its axes (12
  coordinates, 6 rigid-body constraints; 6 dof);
- per corner: the wheel centre W (3 coordinates, carrying the unsprung mass), the suspension travel z
  (m, a relative distance) and the wheel spin angle phi (rad, relative to the knuckle, with the wheel's
  spin inertia); W moves along the linkage path W = r + [u v w] p(z, s) (3 constraints; 1 dof per
  corner for travel, 1 for spin);
- the steering (rtsim.vehicle.kit.steering): the rack travel s (m), which the front wheels' paths
  depend on, so each front wheel gets its own, geometrically exact steer angle, and the column angle
  (rad), joined to the rack by the torsion bar and driven by the steer-by-wire motor.
In all 12 + 4 x 5 + 2 = 34 coordinates and 6 + 4 x 3 = 18 constraints: 16 dof. The rear fits
depend on z only; all corners share one exponent table (rtsim.mbs poly_point).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rtsim.channels import ChannelDictionary, car_channels
from rtsim.mbs import Mechanism, MechanismBuilder, Settings
from rtsim.mbs.model import IS_TANGENT_FORCES

from .config import VehicleConfig
from .layout import (NSP, SP_ARB, SP_BS_K, SP_BS_LEN, SP_C_BUMP, SP_C_REB, SP_FREE,
                     SP_K, SP_PARTNER, TYRE_LINEAR, TYRE_MAGIC_FORMULA, G, Vehicle, FRONT_AXLE,
                     REAR_AXLE, WHEELS)
from ..kit.steering import add_steering, steering_config, steering_params
from ..kit.linkage_cache import cached_corner_kinematics
from ..kit.linkages import (
    OUT_AXIS, OUT_CENTRE, OUT_ROT_S, OUT_ROT_Z, CornerKinematics, DoubleWishbone, MacPherson, VerticalSlider, mirror,
    solve_corner,
)



@dataclass
class VehicleModel:
    config: VehicleConfig
    base: Path
    mech: Mechanism
    vehicle: Vehicle
    corners: list[CornerKinematics]
    static_loads: np.ndarray       # N, per wheel, from the weight split
    design_wheel_centre: np.ndarray
    channels: ChannelDictionary    # its interface: sensor, command and state channels
    dbc: Path                      # its DBC (the channels' CAN frames)


def _geometry(cfg_axle, right: bool):
    hp = {k: None if v is None else np.array(v, dtype=float) for k, v in cfg_axle.hardpoints.model_dump().items()}
    camber, toe = cfg_axle.static_camber_rad, cfg_axle.static_toe_rad
    # left wheel: axis points left (+y); toe-in turns the front of the wheel inwards (axis tilts back),
    # positive camber tilts the top outwards (axis tilts down).
    axis = np.array([-np.sin(toe), np.cos(toe) * np.cos(camber), -np.sin(camber)])
    hp["spin_axis"] = axis / np.linalg.norm(axis)
    geom = {"double_wishbone": DoubleWishbone, "macpherson": MacPherson,
            "vertical_slider": VerticalSlider}[cfg_axle.suspension](**hp)
    return mirror(geom) if right else geom


def corner_kinematics(cfg: VehicleConfig) -> list[CornerKinematics]:
    out = []
    for axle, right in ((cfg.front, False), (cfg.front, True), (cfg.rear, False), (cfg.rear, True)):
        out.append(solve_corner(_geometry(axle, right), z_range=axle.travel_m))
    return out


def build_vehicle(cfg: VehicleConfig, base: Path, corners: list[CornerKinematics] | None = None) -> VehicleModel:
    corners = corners or cached_corner_kinematics(cfg, corner_kinematics)
    # no singular positions in a car's suspension: the projections reuse the Newton factor; the
    # position tolerance is 5x under the 1e-8 bar (a tighter one costs a second Newton iteration on
    # most steps on a mesh road, for no visible change of the motion)
    b = MechanismBuilder(dim=3, name=cfg.id, settings=Settings(projection_factor=False, tol_phi=2e-9))
    cg = np.array(cfg.chassis.cg_m, dtype=float)
    r = b.point("chassis", cg, velocity=(None, None, None))
    u = b.unit_vector("chassis.u", (1, 0, 0))
    v = b.unit_vector("chassis.v", (0, 1, 0))
    w = b.unit_vector("chassis.w", (0, 0, 1))
    ixx, iyy, izz = cfg.chassis.inertia_kgm2
    ixz = cfg.chassis.ixz_kgm2
    b.body("chassis", r, [u, v, w], cfg.chassis.mass_kg, cg, np.array([[ixx, 0, -ixz], [0, iyy, 0], [-ixz, 0, izz]]))
    rack = b.length("rack", 0.0, velocity=0.0)
    column = add_steering(b, steering_params(steering_config(cfg.steering or None, "steering")), rack)
    full_exps = _common_exponents(corners)
    corner_idx = np.zeros((4, 6), dtype=np.int64)
    axis_coef = np.zeros((4, 3, full_exps.shape[0]))
    rotz_coef = np.zeros_like(axis_coef)
    rots_coef = np.zeros_like(axis_coef)
    spring_coef = np.zeros((4, full_exps.shape[0]))
    susp = np.zeros((4, NSP))
    design_w = np.zeros((4, 3))
    zs = []
    for i, (name, kin) in enumerate(zip(WHEELS, corners)):
        axle = cfg.front if i < 2 else cfg.rear
        vec = _pad(kin, full_exps)
        w0 = vec[OUT_CENTRE] @ _basis(full_exps, 0.0, 0.0)
        design_w[i] = w0
        z = b.length(f"z_{name}", 0.0, velocity=0.0)
        wc = b.point(f"wheel_{name}", w0)
        b.point_mass(wc, axle.unsprung_mass_kg)
        path = vec[OUT_CENTRE].copy()
        path[:, 0] -= cg      # relative to the chassis origin r (constant term of the polynomial)
        b.poly_point(wc, r, (u, v, w), path, full_exps, z, rack if kin.steered else None, name=f"suspension {name}")
        phi = b.angle(f"spin_{name}", 0.0, velocity=0.0)
        b.scalar_inertia(phi, axle.wheel_spin_inertia_kgm2)
        zs.append(z)
        b.couple(wc)           # the tyre's 3x3 stiffness/damping block on the wheel centre
        corner_idx[i] = [*wc.idx, z.index, phi.index, rack.index if kin.steered else -1]
        axis_coef[i], rotz_coef[i], rots_coef[i] = vec[OUT_AXIS], vec[OUT_ROT_Z], vec[OUT_ROT_S]
        spring_coef[i] = _pad_scalar(kin, full_exps)
    # the tangent entries rtsim.vehicle.car.step adds: each wheel centre's 3x3 block (tyre stiffness
    # and damping, already coupled by its mass), each spin and travel diagonal, and the anti-roll bars
    # between the travels of an axle
    for a, b_ in (FRONT_AXLE, REAR_AXLE):
        b.couple(zs[a], zs[b_])
    b.gravity((0.0, 0.0, -G))
    mech = b.compile()
    mech.model.iset[IS_TANGENT_FORCES] = 1
    # static loads from the weight split (sprung + unsprung), N
    xf, xr = design_w[0, 0], design_w[2, 0]
    m_s = cfg.chassis.mass_kg
    front_share = (cg[0] - xr) / (xf - xr)
    sprung = np.array([front_share, front_share, 1 - front_share, 1 - front_share]) * 0.5 * m_s * G
    unsprung = np.array([cfg.front.unsprung_mass_kg] * 2 + [cfg.rear.unsprung_mass_kg] * 2) * G
    for i in range(4):
        axle = cfg.front if i < 2 else cfg.rear
        sp = axle.spring
        dl = _spring_slope(spring_coef[i], full_exps)
        length0 = spring_coef[i] @ _basis(full_exps, 0.0, 0.0)
        f_static = sprung[i] / max(-dl, 1e-6)          # spring compression force at design height
        free = sp.free_length_m if sp.free_length_m is not None else length0 + f_static / sp.stiffness_n_per_m
        susp[i, SP_K] = sp.stiffness_n_per_m
        susp[i, SP_FREE] = free
        susp[i, SP_BS_LEN] = length0 - sp.bump_stop_clearance_m
        susp[i, SP_BS_K] = sp.bump_stop_stiffness_n_per_m
        susp[i, SP_C_BUMP] = sp.damping_bump_ns_per_m
        susp[i, SP_C_REB] = sp.damping_rebound_ns_per_m
        susp[i, SP_ARB] = axle.anti_roll_bar_n_per_m
        susp[i, SP_PARTNER] = i ^ 1
    driven = list(FRONT_AXLE if cfg.driven_axle == "front" else REAR_AXLE)
    veh = Vehicle(
        chassis_idx=np.array([*r.idx, *u.idx, *v.idx, *w.idx], dtype=np.int64),
        corner_idx=corner_idx, axis_coef=axis_coef, rotz_coef=rotz_coef, rots_coef=rots_coef,
        spring_coef=spring_coef, susp=susp, steer_idx=np.array([column.index, rack.index], dtype=np.int64),
        imu_local=np.array(cfg.sensors.imu_position_m, dtype=float) - cg,
        aero=np.array([cfg.aero.drag_area_m2, cfg.aero.air_density_kg_m3]),
        tyre_model=np.array([TYRE_LINEAR if cfg.tyres.model == "linear" else TYRE_MAGIC_FORMULA], dtype=np.int64),
        driven=np.array(driven, dtype=np.int64),
        drive_slot=np.array([driven.index(i) if i in driven else -1 for i in range(len(WHEELS))], dtype=np.int64),
        side=np.array([1.0 if i in (FRONT_AXLE[0], REAR_AXLE[0]) else -1.0 for i in range(len(WHEELS))]),
    )
    return VehicleModel(cfg, base, mech, veh, corners, sprung + unsprung, design_w, vehicle_channels(cfg),
                        (Path(base) / cfg.interface.dbc).resolve())


def vehicle_channels(cfg: VehicleConfig) -> ChannelDictionary:
    """The car's channel dictionary: its drive-torque sensors on the driven axle's wheels."""
    return car_channels(tuple(WHEELS[i] for i in (FRONT_AXLE if cfg.driven_axle == "front" else REAR_AXLE)))


def _basis(exps: np.ndarray, z: float, s: float) -> np.ndarray:
    return z ** exps[:, 0] * s ** exps[:, 1]


def _spring_slope(coef: np.ndarray, exps: np.ndarray) -> float:
    """dL/dz at z = s = 0."""
    return float(sum(c for c, (a, bexp) in zip(coef, exps) if a == 1 and bexp == 0))


def _common_exponents(corners: list[CornerKinematics]) -> np.ndarray:
    rows = {tuple(e) for k in corners for e in k.exponents}
    return np.array(sorted(rows), dtype=np.int64)


def _pad(kin: CornerKinematics, exps: np.ndarray) -> np.ndarray:
    out = np.zeros((kin.vec_coef.shape[0], 3, exps.shape[0]))
    pos = {tuple(e): j for j, e in enumerate(exps)}
    for j, e in enumerate(kin.exponents):
        out[:, :, pos[tuple(e)]] = kin.vec_coef[:, :, j]
    return out


def _pad_scalar(kin: CornerKinematics, exps: np.ndarray) -> np.ndarray:
    out = np.zeros(exps.shape[0])
    pos = {tuple(e): j for j, e in enumerate(exps)}
    for j, e in enumerate(kin.exponents):
        out[pos[tuple(e)]] = kin.spring_coef[j]
    return out
