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

import dataclasses
from dataclasses import dataclass
from pathlib import Path

from functools import lru_cache

import numpy as np

from rtsim.channels import ChannelDictionary, car_channels
from rtsim.mbs import Mechanism, MechanismBuilder, Settings
from rtsim.errors import ConfigError
from rtsim.mbs.model import IS_TANGENT_FORCES

from .config import VehicleConfig
from .layout import (NSP, STEER_BY_WIRE, STEER_EPS, TYRE_LINEAR, TYRE_MAGIC_FORMULA, G, Vehicle, FRONT_AXLE,
                     REAR_AXLE, WHEELS, Susp)
from ..kit.eps import add_eps, eps_params
from ..kit.steering import add_steering, steering_config, steering_params
from ..kit.spring_damper import bump_stop_spring_table, characteristic_table, two_rate_damper_table
from ..kit.tables import table_1d
from ..kit.linkage_cache import cached_corner_kinematics
from ..kit.linkages import (
    OUT_AXIS, OUT_CENTRE, OUT_ROT_S, OUT_ROT_Z, CornerKinematics, DoubleWishbone, MacPherson, VerticalSlider,
    crank_rod_constants, mirror, solve_corner,
)

# A car with EPS: the front knuckles' steer angle range of the fits (rad) and the polynomial degrees
# (the slider's travel is linear; sin and cos of the steer angle to 1e-9 over the range).
PIVOT_RANGE = (-0.75, 0.75)
PIVOT_DEGREES = dict(deg_z=1, deg_s=11, nz=5, ns=41)



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
    """The corners' fitted kinematics. With [eps] the front ones are functions of travel and the
    knuckle's own steer angle (the tie rods are constraints of the model), all of degree 1 in travel."""
    out = []
    for axle, right in ((cfg.front, False), (cfg.front, True), (cfg.rear, False), (cfg.rear, True)):
        if cfg.eps is None:
            out.append(solve_corner(_geometry(axle, right), z_range=axle.travel_m))
        else:
            steered = axle is cfg.front
            out.append(solve_corner(_geometry(axle, right), z_range=axle.travel_m, s_range=PIVOT_RANGE,
                                    steer_angle=steered, **PIVOT_DEGREES))
    return out


def _knuckle_angle(c: dict, x: float) -> float:
    """Steer angle (rad) of a crank-rod knuckle (crank_rod_constants) at rack travel x (m), on the
    assembled branch (bisection from 0 outwards; nan where the tie rod cannot reach). Kept per process for
    the constants and x it was asked for (a batch builds the same linkage again and again)."""
    key = tuple(sorted((k, tuple(np.ravel(v).tolist()) if isinstance(v, (np.ndarray, list, tuple)) else float(v))
                       for k, v in c.items()))
    return _knuckle_angle_of(key, float(x))


@lru_cache(maxsize=256)
def _knuckle_angle_of(key: tuple, x: float) -> float:
    c = dict(key)
    piv, arm, end = np.asarray(c["pivot"]), np.asarray(c["arm"]), np.asarray(c["rod_end"])

    def gap(phi):
        cs, sn = np.cos(phi), np.sin(phi)
        tip = piv + np.array([cs * arm[0] - sn * arm[1], sn * arm[0] + cs * arm[1]])
        return np.linalg.norm(tip - (end + np.array([0.0, x * c["direction"]]))) - c["length"]
    g0 = gap(0.0)
    for phi in np.linspace(0.0, 1.5, 301)[1:] * (1.0 if x >= 0 else -1.0):
        if np.sign(gap(phi)) != np.sign(g0):
            lo, hi = 0.0, phi
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if np.sign(gap(mid)) == np.sign(g0) else (lo, mid)
            return 0.5 * (lo + hi)
    return float("nan")


def _check_rack_travel(cfg: VehicleConfig, base: Path, corners: list[CornerKinematics]) -> None:
    """The rack's end stops must hold the linkage inside its fitted kinematics: the rack travel plus
    the stops' static deflection under the steering's largest rack force (steer-by-wire: the motor's
    full column torque; EPS: the assist motor's stall torque at the current limit plus the torsion bar
    twisted by one radian) within the fit's rack range, or (EPS) the knuckle's steer-angle range."""
    where = Path(base).name if base else "vehicle"
    if cfg.eps is None:
        st = steering_config(cfg.steering or None, "steering")
        f_max = st.motor_torque_limit * st.reduction_ratio * st.reduction_efficiency / st.rack_travel_per_rad
        reach = st.rack_travel + f_max / st.rack_stop_stiffness
        limit = min(max(abs(a) for a in k.s_range) for k in corners if k.steered)
        if reach > limit:
            raise ConfigError(f"steering.rack_travel = {st.rack_travel:g} m: with the end stops' static deflection "
                              f"({f_max / st.rack_stop_stiffness * 1e3:.1f} mm at {f_max:.0f} N) the rack reaches "
                              f"{reach:g} m, beyond the suspension fit's rack range +-{limit:g} m")
        return
    e = cfg.eps
    f_max = ((e.current_limit_a * e.motor_torque_constant_nm_per_a * e.gear_ratio + e.torsion_bar_nm_per_rad)
             / e.rack_travel_per_rad_m)
    reach = e.rack_travel_m + f_max / e.rack_stop_stiffness_n_per_m
    for i in (0, 1):
        for x in (reach, -reach):
            phi = _knuckle_angle(crank_rod_constants(_geometry(cfg.front, i == 1)), x)
            if not abs(phi) < PIVOT_RANGE[1]:
                raise ConfigError(f"eps.rack_travel_m = {e.rack_travel_m:g} m: with the end stops' static deflection "
                                  f"({f_max / e.rack_stop_stiffness_n_per_m * 1e3:.1f} mm at {f_max:.0f} N) the rack "
                                  f"reaches {reach:g} m, which steers a front knuckle to {phi:.3f} rad, beyond the "
                                  f"fitted range +-{PIVOT_RANGE[1]:g} rad")


def steered_inertia_at_rack(cfg: VehicleConfig, corners: list[CornerKinematics]) -> float:
    """kg: the steered wheels' own inertia about their steering axes, reflected to the rack of a
    steer-by-wire car. Turning the rack at s' turns each steered knuckle at omega = R_s s' (R_s: the
    linkage's rotation per rack travel, OUT_ROT_S, at design position); the wheel centre's motion is the
    unsprung point mass's, and the wheel, tyre, disc and hub add their inertia about a diameter,
    ``front.pivot_inertia_kgm2`` (I_d), for omega's part across the spin axis a:
    m = sum I_d (|R_s|^2 - (R_s . a)^2). The rate is taken at design (it varies by some per cent over the
    travel and the rack's range: the mass matrix stays constant)."""
    m = 0.0
    for i, kin in enumerate(corners):
        if not kin.steered:
            continue
        axle = cfg.front if i < 2 else cfg.rear
        rs = kin.evaluate(OUT_ROT_S, 0.0, 0.0)
        a = kin.evaluate(OUT_AXIS, 0.0, 0.0)
        a = a / np.linalg.norm(a)
        m += axle.pivot_inertia_kgm2 * (float(rs @ rs) - float(rs @ a) ** 2)
    return m


def build_vehicle(cfg: VehicleConfig, base: Path, corners: list[CornerKinematics] | None = None,
                  reuse: VehicleModel | None = None) -> VehicleModel:
    """The car's compiled model. ``reuse``: a model built before from a config that differs from ``cfg`` in
    plain parameters only (rtsim.vehicle.car.plain: the corner fits and the topology are the same): its
    corner fits and its symbolic analysis are taken (rtsim.mbs.builder compile's ``reuse``), every value
    is computed again by the same code, so the model equals a fresh build's bit for bit."""
    if reuse is not None:
        corners = reuse.corners
    corners = corners or cached_corner_kinematics(cfg, corner_kinematics)
    if any(k.steered for k in corners):
        _check_rack_travel(cfg, base, corners)
    # no singular positions in a car's suspension: the projections reuse the Newton factor; the
    # position tolerance is 5x under the 1e-8 bar (a tighter one costs a second Newton iteration on
    # most steps on a mesh road, for no visible change of the motion); the commits after the step (tyre
    # deflections, brake modes, signals) read the forces of the last Newton evaluation, one increment
    # within tolerance from the converged q (Settings.finish_forces: a car's chassis ends about 2e-6 m
    # and 3e-6 m/s apart after 3 s of a 35 deg step steer at 80 km/h, for one force evaluation a step less)
    b = MechanismBuilder(dim=3, name=cfg.id, settings=Settings(projection_factor=False, tol_phi=2e-9,
                                                               finish_forces=False))
    cg = np.array(cfg.chassis.cg_m, dtype=float)
    r = b.point("chassis", cg, velocity=(None, None, None))
    u = b.unit_vector("chassis.u", (1, 0, 0))
    v = b.unit_vector("chassis.v", (0, 1, 0))
    w = b.unit_vector("chassis.w", (0, 0, 1))
    b.body("chassis", r, [u, v, w], cfg.chassis.mass_kg, cg, chassis_inertia(cfg))
    rack = b.length("rack", 0.0, velocity=0.0)
    driver_row = -1
    if cfg.eps is None:
        column = add_steering(b, steering_params(steering_config(cfg.steering or None, "steering")), rack)
        b.scalar_inertia(rack, steered_inertia_at_rack(cfg, corners))
    else:
        column, drv = add_eps(b, eps_params(cfg.eps), rack)
        if drv >= 0:
            driver_row = b.constraint_count - 1     # the driver's constraint row, just added
    full_exps, vecs, springs, spring_at_design = _padded(corners)
    corner_idx = np.zeros((4, 6), dtype=np.int64)
    axis_coef = np.zeros((4, 3, full_exps.shape[0]))
    rotz_coef = np.zeros_like(axis_coef)
    rots_coef = np.zeros_like(axis_coef)
    spring_coef = np.zeros((4, full_exps.shape[0]))
    design_w = np.zeros((4, 3))
    zs = []
    for i, (name, kin) in enumerate(zip(WHEELS, corners)):
        axle = cfg.front if i < 2 else cfg.rear
        vec = vecs[i]
        w0 = vec[OUT_CENTRE] @ _basis(full_exps, 0.0, 0.0)
        design_w[i] = w0
        z = b.length(f"z_{name}", 0.0, velocity=0.0)
        wc = b.point(f"wheel_{name}", w0)
        b.point_mass(wc, axle.unsprung_mass_kg)
        path = vec[OUT_CENTRE].copy()
        path[:, 0] -= cg      # relative to the chassis origin r (constant term of the polynomial)
        steer = rack if kin.steered else None
        if kin.steered and cfg.eps is not None:       # the knuckle's steer angle, tied to the rack
            steer = b.angle(f"steer_{name}", 0.0, velocity=0.0)
            b.scalar_inertia(steer, axle.pivot_inertia_kgm2)
            b.crank_rod(steer, rack, name=f"tie rod {name}", **crank_rod_constants(_geometry(axle, i % 2 == 1)))
        b.poly_point(wc, r, (u, v, w), path, full_exps, z, steer, name=f"suspension {name}")
        if axle.rigid:                  # no suspension: the travel held at the design height
            b.linear([(1.0, z, 0)], 0.0, name=f"rigid mount {name}")
        phi = b.angle(f"spin_{name}", 0.0, velocity=0.0)
        b.scalar_inertia(phi, axle.wheel_spin_inertia_kgm2)
        zs.append(z)
        b.couple(wc)           # the tyre's 3x3 stiffness/damping block on the wheel centre
        corner_idx[i] = [*wc.idx, z.index, phi.index, steer.index if kin.steered else -1]
        axis_coef[i], rotz_coef[i], rots_coef[i] = vec[OUT_AXIS], vec[OUT_ROT_Z], vec[OUT_ROT_S]
        spring_coef[i] = springs[i]
    # the tangent entries rtsim.vehicle.car.step adds: each wheel centre's 3x3 block (tyre stiffness
    # and damping, already coupled by its mass), each spin and travel diagonal, and the anti-roll bars
    # between the travels of an axle
    for a, b_ in (FRONT_AXLE, REAR_AXLE):
        b.couple(zs[a], zs[b_])
    b.gravity((0.0, 0.0, -G))
    mech = b.compile(reuse=None if reuse is None else reuse.mech)
    mech.model.iset[IS_TANGENT_FORCES] = 1
    loads, susp, spring_tab, damper_tab = suspension_arrays(cfg, cg, design_w, spring_at_design)
    driven = list(FRONT_AXLE if cfg.driven_axle == "front" else REAR_AXLE)
    veh = Vehicle(
        chassis_idx=np.array([*r.idx, *u.idx, *v.idx, *w.idx], dtype=np.int64),
        corner_idx=corner_idx, axis_coef=axis_coef, rotz_coef=rotz_coef, rots_coef=rots_coef,
        spring_coef=spring_coef, susp=susp, spring_tab=spring_tab, damper_tab=damper_tab,
        steer_idx=np.array([column.index, rack.index], dtype=np.int64),
        steer_kind=np.array([STEER_BY_WIRE if cfg.eps is None else STEER_EPS], dtype=np.int64),
        driver_row=np.array([driver_row], dtype=np.int64),
        imu_local=np.array(cfg.sensors.imu_position_m, dtype=float) - cg,
        aero=aero_array(cfg),
        tyre_model=np.array([TYRE_LINEAR if cfg.tyres.model == "linear" else TYRE_MAGIC_FORMULA], dtype=np.int64),
        driven=np.array(driven, dtype=np.int64),
        drive_slot=np.array([driven.index(i) if i in driven else -1 for i in range(len(WHEELS))], dtype=np.int64),
        side=np.array([1.0 if i in (FRONT_AXLE[0], REAR_AXLE[0]) else -1.0 for i in range(len(WHEELS))]),
    )
    return VehicleModel(cfg, base, mech, veh, corners, loads, design_w, vehicle_channels(cfg),
                        (Path(base) / cfg.interface.dbc).resolve())


def apply_in_place(cfg: VehicleConfig, kept: VehicleModel) -> VehicleModel:
    """The model of ``cfg``, a config that differs from the built model ``kept``'s in keys applied in place
    only (rtsim.vehicle.car.plain, IN_PLACE): ``kept`` with copies of the arrays those keys reach, computed
    by the functions the build computes them with -- the chassis body's share of the mass matrix and the
    gravity vector (rtsim.mbs Mechanism.with_bodies, when its mass or inertia differ), the static wheel
    loads, the suspension's parameters and tables, the aero parameters -- and the config; every other
    array (corner fits, constraints, symbolic analysis) shared, read only. Equal to a fresh build of
    ``cfg`` bit for bit."""
    mech = kept.mech
    was = kept.config.chassis
    now = cfg.chassis
    if (now.mass_kg, tuple(now.inertia_kgm2), now.ixz_kgm2) != (was.mass_kg, tuple(was.inertia_kgm2), was.ixz_kgm2):
        mech = mech.with_bodies({"chassis": (now.mass_kg, chassis_inertia(cfg))})
    spring_at_design = _padded(kept.corners)[3]
    cg = np.array(cfg.chassis.cg_m, dtype=float)
    loads, susp, spring_tab, damper_tab = suspension_arrays(cfg, cg, kept.design_wheel_centre, spring_at_design)
    veh = kept.vehicle._replace(susp=susp, spring_tab=spring_tab, damper_tab=damper_tab, aero=aero_array(cfg))
    return dataclasses.replace(kept, config=cfg, mech=mech, vehicle=veh, static_loads=loads)


def chassis_inertia(cfg: VehicleConfig) -> np.ndarray:
    """The chassis' inertia tensor about its centre of mass in the car's axes (kg m^2)."""
    ixx, iyy, izz = cfg.chassis.inertia_kgm2
    ixz = cfg.chassis.ixz_kgm2
    return np.array([[ixx, 0, -ixz], [0, iyy, 0], [-ixz, 0, izz]])


def aero_array(cfg: VehicleConfig) -> np.ndarray:
    """The aero parameters of the step (rtsim.vehicle.car.forces): drag area (m^2), air density (kg/m^3)."""
    return np.array([cfg.aero.drag_area_m2, cfg.aero.air_density_kg_m3])


def suspension_arrays(cfg: VehicleConfig, cg: np.ndarray, design_w: np.ndarray,
                      spring_at_design: list) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(static wheel loads from the weight split, sprung + unsprung, N; the suspension parameters
    (Susp); the spring and damper tables) of the config, on the corners' design wheel centres
    (`design_w`, m) and each spring's (dL/dz, length) at design height (rtsim.vehicle.car.build._padded)."""
    susp = np.zeros((4, NSP))
    xf, xr = design_w[0, 0], design_w[2, 0]
    m_s = cfg.chassis.mass_kg
    front_share = (cg[0] - xr) / (xf - xr)
    sprung = np.array([front_share, front_share, 1 - front_share, 1 - front_share]) * 0.5 * m_s * G
    unsprung = np.array([cfg.front.unsprung_mass_kg] * 2 + [cfg.rear.unsprung_mass_kg] * 2) * G
    spring_tab = np.zeros((4, table_1d([0.0, 1.0], [0.0, 0.0]).size))
    damper_tab = np.zeros_like(spring_tab)
    r_wheel = float(np.mean(design_w[:, 2]))       # wheel radius for the axle reactions (design height)
    for i in range(4):
        axle = cfg.front if i < 2 else cfg.rear
        dl, length0 = spring_at_design[i]
        f_static = sprung[i] / max(-dl, 1e-6)          # spring compression force at design height
        susp[i, Susp.L0] = length0
        susp[i, Susp.PARTNER] = i ^ 1
        if axle.rigid:                  # no spring, damper, bar, axle reaction or stops: zero forces
            spring_tab[i] = damper_tab[i] = table_1d([-1.0, 1.0], [0.0, 0.0])
            continue
        spring_tab[i], damper_tab[i] = _spring_damper_tables(axle.spring, length0, f_static)
        susp[i, Susp.ARB] = axle.anti_roll_bar_n_per_m
        susp[i, Susp.BX] = r_wheel / axle.anti_pitch_arm_m if axle.anti_pitch_arm_m else 0.0
        susp[i, Susp.BY] = r_wheel / axle.anti_roll_arm_m if axle.anti_roll_arm_m else 0.0
        susp[i, Susp.CFY] = axle.compliance_steer_rad_per_n
        susp[i, Susp.CMZ] = axle.compliance_steer_rad_per_nm
        susp[i, Susp.Z_LO] = axle.travel_m[0] + axle.travel_stop_margin_m
        susp[i, Susp.Z_HI] = axle.travel_m[1] - axle.travel_stop_margin_m
        susp[i, Susp.STOP_K] = axle.travel_stop_stiffness_n_per_m
        susp[i, Susp.STOP_C] = axle.travel_stop_damping_ns_per_m
    return sprung + unsprung, susp, spring_tab, damper_tab


def _spring_damper_tables(sp, length0: float, f_static: float) -> tuple[np.ndarray, np.ndarray]:
    """The spring's force (N, compression positive) against compression from the design length (m),
    and the damper's force against compression speed (m/s), as tables. A linear spring with its bump
    stop and a two-rate damper are tables of three points each, exactly (the ends continue linearly)."""
    if sp.spring_table is not None:
        spring = characteristic_table(sp.spring_table, f_static)
    else:
        k = sp.stiffness_n_per_m
        pre = f_static if sp.free_length_m is None else k * (sp.free_length_m - length0)
        spring = bump_stop_spring_table(k, pre, sp.bump_stop_clearance_m, sp.bump_stop_stiffness_n_per_m)
    if sp.damper_table is not None:
        damper = characteristic_table(sp.damper_table)
    else:
        damper = two_rate_damper_table(sp.damping_bump_ns_per_m, sp.damping_rebound_ns_per_m, 1.0)
    return spring, damper


def vehicle_channels(cfg: VehicleConfig) -> ChannelDictionary:
    """The car's channel dictionary: its drive-torque sensors on the driven axle's wheels; a car with
    electric power steering has the EPS's sensors and its controller's command. One (immutable) dictionary
    per driven axle and steering kind in a process."""
    key = (cfg.driven_axle == "front", cfg.eps is not None)
    found = _CHANNELS.get(key)
    if found is None:
        found = _CHANNELS[key] = car_channels(tuple(WHEELS[i] for i in (FRONT_AXLE if key[0] else REAR_AXLE)),
                                              eps=key[1])
    return found


_CHANNELS: dict = {}


def _basis(exps: np.ndarray, z: float, s: float) -> np.ndarray:
    return z ** exps[:, 0] * s ** exps[:, 1]


def _spring_slope(coef: np.ndarray, exps: np.ndarray) -> float:
    """dL/dz at z = s = 0."""
    return float(sum(c for c, (a, bexp) in zip(coef, exps) if a == 1 and bexp == 0))


#: _padded's results by corner list (id -> (the list, its result)): a model built on a kept one shares its
#: corner list, so its padding is done once per worker process
_PADDED: dict = {}


def _padded(corners: list[CornerKinematics]) -> tuple[np.ndarray, list, list, list]:
    """(the corners' common exponent table, each corner's vector coefficients and spring-length
    coefficients on it, each spring's (dL/dz in m/m, length in m) at design height), kept for the same
    corner list (read only)."""
    hit = _PADDED.get(id(corners))
    if hit is not None and hit[0] is corners:
        return hit[1]
    exps = _common_exponents(corners)
    springs = [_pad_scalar(k, exps) for k in corners]
    design = [(_spring_slope(c, exps), c @ _basis(exps, 0.0, 0.0)) for c in springs]
    out = (exps, [_pad(k, exps) for k in corners], springs, design)
    if len(_PADDED) >= 32:
        _PADDED.clear()
    _PADDED[id(corners)] = (corners, out)
    return out


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
