"""The vehicle configuration file (configs/vehicles/*.toml), validated on load.

Frame of all hardpoints and positions: the vehicle's design frame, ISO 8855 (x forward, y left,
z up), origin on the ground under the front axle centre at design ride height. Hardpoints are given
for the left corners; the right ones are their mirror images. SI units throughout (the unit is in each
key's name or comment).

Optional ``[effects.<name>]`` tables (sensor effects: ``[[effects.<name>]]`` arrays of tables, one per
channel) switch on effects of the catalogue rtsim.vehicle.car.effects; absent: none (the nominal model).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from rtsim.channels import SENSOR_NAMES
from rtsim.configfile import Range, Strict, bad, load_toml, problem, validate
from rtsim.errors import ConfigError, ModelError

from ..kit.actuators import over_defaults
from ..kit.brake import BrakeConfig
from ..kit.design_frame import Moments, Product, Vec3
from ..kit.eps import EpsConfig
from ..kit.inertia import inertia_problem
from ..kit.linkage_checks import STEERING_RATIO_RANGE, short_link, steering_arm, steering_ratio
from ..kit.linkages import DoubleWishbone, VerticalSlider
from ..kit.powertrain import PowertrainConfig
from ..kit.spring_damper import Characteristic
from ..kit.steering import SteeringConfig

from .effects import validate_effects

MAX_TRAVEL_M = 0.3       # m: wheel travel either way from design ride height


class Chassis(Strict):
    mass_kg: Range(50, 5000, "kg", lo_open=True) = Field(description="sprung mass")
    cg_m: Vec3 = Field(description="centre of mass of the sprung mass, design frame")
    inertia_kgm2: Moments = Field(description="Ixx, Iyy, Izz about the sprung CG")
    ixz_kgm2: Product = 0.0

    @model_validator(mode="after")
    def _positive_inertia(self):
        problem = inertia_problem(self.inertia_kgm2, self.ixz_kgm2, strict=True)
        if problem is not None:
            raise bad(problem[0], getattr(self, problem[0]), problem[1])
        return self


class DoubleWishboneHardpoints(Strict):
    lower_front: Vec3
    lower_rear: Vec3
    upper_front: Vec3
    upper_rear: Vec3
    lower_ball: Vec3
    upper_ball: Vec3
    tie_outer: Vec3
    tie_inner: Vec3
    spring_lower: Vec3
    spring_upper: Vec3
    wheel_centre: Vec3


class MacPhersonHardpoints(Strict):
    lower_front: Vec3
    lower_rear: Vec3
    lower_ball: Vec3
    strut_top: Vec3
    strut_lower: Vec3
    toe_outer: Vec3
    toe_inner: Vec3
    wheel_centre: Vec3


class VerticalSliderHardpoints(Strict):
    """The wheel slides along the body's vertical axis. Steered: it turns about the vertical kingpin
    axis through `kingpin`, the steering arm's end `tie_outer` held by a tie rod from `tie_inner` on the
    rack; unsteered: leave the three out."""
    wheel_centre: Vec3
    spring_lower: Vec3 = Field(description="spring/damper mount on the slider")
    spring_upper: Vec3 = Field(description="spring/damper mount on the body")
    kingpin: Vec3 | None = None
    tie_outer: Vec3 | None = None
    tie_inner: Vec3 | None = None

    @model_validator(mode="after")
    def _steering_points(self):
        given = [k for k in ("kingpin", "tie_outer", "tie_inner") if getattr(self, k) is not None]
        if given and len(given) != 3:
            raise ValueError("a steered slider needs kingpin, tie_outer and tie_inner (an unsteered one none)")
        return self

    @property
    def steered(self) -> bool:
        return self.tie_outer is not None


SUSPENSIONS = {"double_wishbone": DoubleWishboneHardpoints, "macpherson": MacPhersonHardpoints,
               "vertical_slider": VerticalSliderHardpoints}


class SpringDamper(Strict):
    """Along the spring/damper element. Force in compression positive. Linear spring with a bump stop
    and a two-rate damper, or tables: `spring_table` (x: compression from the design ride height, m;
    force_n: the force above the static preload, so the car sits at design height) and `damper_table`
    (x: compression speed, m/s; force_n: damping force, 0 at 0)."""
    stiffness_n_per_m: Range(0, 1e6, "N/m", lo_open=True) | None = None
    free_length_m: Range(0, 2.0, "m", lo_open=True) | None = Field(
        default=None, description="unset: chosen so the car sits at design ride height")
    bump_stop_clearance_m: Range(0, 0.3, "m", lo_open=True) = 0.05
    bump_stop_stiffness_n_per_m: Range(0, 1e7, "N/m") = 2e5
    damping_bump_ns_per_m: Range(0, 1e5, "N s/m", lo_open=True) | None = None
    damping_rebound_ns_per_m: Range(0, 1e5, "N s/m", lo_open=True) | None = None
    spring_table: Characteristic | None = None
    damper_table: Characteristic | None = None

    @model_validator(mode="after")
    def _one_law_each(self):
        if (self.spring_table is None) == (self.stiffness_n_per_m is None):
            raise ValueError("give stiffness_n_per_m or spring_table (one of them)")
        linear = self.damping_bump_ns_per_m is not None and self.damping_rebound_ns_per_m is not None
        if (self.damper_table is None) != linear:
            raise ValueError("give damping_bump_ns_per_m and damping_rebound_ns_per_m, or damper_table")
        table = self.spring_table
        if table is not None and not table.x[0] <= 0.0 <= table.x[-1]:
            raise ValueError("spring_table must span compression 0 (the design ride height)")
        return self


class Axle(Strict):
    suspension: Literal["double_wishbone", "macpherson", "vertical_slider"]
    hardpoints: DoubleWishboneHardpoints | MacPhersonHardpoints | VerticalSliderHardpoints
    static_camber_rad: Range(-0.1, 0.1, "rad") = Field(default=0.0, description="positive: top leans out")
    static_toe_rad: Range(-0.05, 0.05, "rad") = Field(default=0.0, description="positive: toe-in")
    unsprung_mass_kg: Range(1, 200, "kg", lo_open=True) = Field(description="per corner")
    wheel_spin_inertia_kgm2: Range(0.05, 20, "kg m^2", lo_open=True) = Field(
        description="per wheel, incl. brake and shaft")
    spring: SpringDamper | None = Field(default=None, description="the spring and damper (not with rigid)")
    rigid: bool = Field(default=False, description=(
        "no suspension: the wheel's carrier is bolted to the chassis (a vertical slider whose travel a "
        "constraint holds at the design height); no spring, damper, anti-roll bar or travel stops"))
    anti_roll_bar_n_per_m: Range(0, 1e6, "N/m") = Field(
        default=0.0, description="force per metre of left-right travel difference")
    travel_m: tuple[Range(-MAX_TRAVEL_M, 0.0, "m", hi_open=True), Range(0.0, MAX_TRAVEL_M, "m", lo_open=True)] = Field(
        default=(-0.08, 0.08), description="rebound, bump limits of the fit, from the design ride height")
    travel_stop_margin_m: Range(0.0, 0.05, "m") = Field(
        default=0.008, description="the rebound and bump stops (rtsim.vehicle.kit.end_stop) engage this far "
        "inside travel_m, so a "
        "wheel hanging in the air or slammed into bump stays within the fitted kinematics")
    travel_stop_stiffness_n_per_m: Range(1e4, 1e8, "N/m") = Field(
        default=1.0e6, description="the travel stops' stiffness at the wheel (rebound strap / hydraulic stop, "
        "bump stop solid)")
    travel_stop_damping_ns_per_m: Range(0.0, 1e6, "N s/m") = Field(
        default=5.0e3, description="the travel stops' damping at the wheel")
    pivot_inertia_kgm2: Range(0, 20, "kg m^2") = Field(
        default=0.0, description="wheel, hub and knuckle about the kingpin (a car with [eps]: each front wheel "
        "steers freely "
        "about its kingpin, tied to the rack by its tie rod; steer-by-wire: their own inertia about a "
        "diameter through the wheel centre, reflected to the rack through the linkage, the wheel "
        "centre's motion being the unsprung mass's)")
    compliance_steer_rad_per_n: Range(-1e-4, 1e-4, "rad/N") = Field(
        default=0.0, description="elastokinematic steer induced by the lateral tyre force (positive: towards "
        "the force)")
    compliance_steer_rad_per_nm: Range(-1e-3, 1e-3, "rad/(N m)") = Field(
        default=0.0, description="steer induced by the aligning moment")
    anti_pitch_arm_m: Range(0.05, 20, "m", lo_open=True) | None = Field(
        default=None, description="axle reaction ('Brouilhet effect'): the longitudinal tyre force's moment "
        "about the wheel "
        "centre, Fx r, taken by an arm of this length between wheel and body (side-view swing arm)")
    anti_roll_arm_m: Range(0.05, 20, "m", lo_open=True) | None = Field(
        default=None, description="axle reaction of the lateral tyre force, Fy r over this arm (front-view swing arm)")

    @model_validator(mode="after")
    def _hardpoints_match(self):
        if not isinstance(self.hardpoints, SUSPENSIONS[self.suspension]):
            raise ValueError(f"hardpoints do not match suspension '{self.suspension}'")
        return self

    @model_validator(mode="after")
    def _spring_or_rigid(self):
        if self.rigid:
            if self.suspension != "vertical_slider":
                raise bad("rigid", True, f"a rigid mount is a locked vertical_slider, not a {self.suspension}")
            if self.spring is not None or self.anti_roll_bar_n_per_m:
                raise bad("spring", "given", "a rigid mount has no spring, damper or anti-roll bar")
        elif self.spring is None:
            raise bad("spring", None, "a suspended axle needs its [spring] (or rigid = true: no suspension)")
        return self

    @model_validator(mode="after")
    def _physical(self):
        """No degenerate link in the linkage."""
        link = short_link(self.suspension, self.hardpoints.model_dump())
        if link is not None:
            raise bad(f"hardpoints.{link[0]}", link[1], link[2])
        return self

    def spin_axis(self) -> np.ndarray:
        """The left wheel's spin axis at the design position with static toe and camber (as the model's
        build: toe-in turns the wheel's front inwards, positive camber tilts its top outwards)."""
        camber, toe = self.static_camber_rad, self.static_toe_rad
        axis = np.array([-np.sin(toe), np.cos(toe) * np.cos(camber), -np.sin(camber)])
        return axis / np.linalg.norm(axis)

    @property
    def steered(self) -> bool:
        """Linked to the rack: a double wishbone, or a vertical slider with tie rods."""
        return self.suspension == "double_wishbone" or (self.suspension == "vertical_slider"
                                                        and self.hardpoints.steered)


class Tyres(Strict):
    property_file: str = Field(description=".tir file, relative to the vehicle file")
    model: Literal["magic_formula", "linear"] = "magic_formula"


class Aero(Strict):
    drag_area_m2: Range(0, 5, "m^2") = Field(default=0.7, description="Cd * A")
    air_density_kg_m3: Range(0.5, 1.5, "kg/m^3", lo_open=True) = 1.2


class SensorNoise(Strict):
    """What one sensor reports of its physical value (rtsim.vehicle.kit.sensor_model), channel units."""
    noise_std: Range(0, math.inf, hi_open=True) = 0.0
    bias: Range(-math.inf, math.inf, "channel units", lo_open=True, hi_open=True) = 0.0   # any finite
    scale: Range(0, 10, lo_open=True) = 1.0
    quantum: Range(0, math.inf, hi_open=True) = 0.0
    delay_s: Range(0, 0.5, "s") = 0.0


class Sensors(Strict):
    imu_position_m: Vec3 = Field(description="accelerometer/gyro mounting point, design frame")
    rate_hz: Range(0, 10000, "Hz", lo_open=True) = 500.0
    channels: dict[str, SensorNoise] = Field(default_factory=dict,
                                            description="per channel noise, bias, quantisation, delay (off by default)")

    @field_validator("channels")
    @classmethod
    def _known_channels(cls, v):
        from rtsim.channels import car_sensors
        known = list(dict.fromkeys([*SENSOR_NAMES, *(c.name for c in car_sensors(("fl", "fr")))]))
        unknown = [k for k in v if k not in known]         # the car's, either driven axle
        if unknown:
            raise ValueError(f"unknown sensor channel {unknown[0]!r}; channels are {', '.join(known)}")
        return v


class Interface(Strict):
    """The vehicle's CAN interface: its DBC, whose signals carry the channels of the vehicle's channel
    dictionary (rtsim.channels.car_channels) by the same names and units."""
    dbc: str = Field(default="../can/xbw.dbc", description="DBC file, relative to the vehicle file")


#: the validated sections (chassis, axles, tyres, ..., the part configs brakes, powertrain, steering) by
#: (field, repr of the table), this process's
_PARTS: dict = {}
#: the parts whose partial table overrides their defaults key by key
_PART_KINDS = {"brakes": BrakeConfig, "powertrain": PowertrainConfig, "steering": SteeringConfig}


class VehicleConfig(Strict):
    name: str
    id: str = Field(pattern=r"^[a-z0-9_]+$", description="used in topic names: rtsim/<id>/...")
    chassis: Chassis
    front: Axle
    rear: Axle
    driven_axle: Literal["front", "rear"] = Field(
        default="rear", description="the axle the powertrain drives through its open differential")
    tyres: Tyres
    interface: Interface = Interface()
    aero: Aero = Aero()
    sensors: Sensors
    brakes: BrakeConfig = Field(default_factory=BrakeConfig, description="rtsim.vehicle.kit.brake")
    powertrain: PowertrainConfig = Field(default_factory=PowertrainConfig,
                                         description="rtsim.vehicle.kit.powertrain")
    steering: SteeringConfig = Field(default_factory=SteeringConfig, description="rtsim.vehicle.kit.steering")
    eps: EpsConfig | None = Field(default=None, description=(
        "electric power steering (rtsim.vehicle.kit.eps) instead of the steer-by-wire [steering]: the "
        "driver steers, the motor assists; the front pivots are coordinates tied to the rack"))
    effects: dict = Field(default_factory=dict, description="switchable effects, validated by "
                          "rtsim.vehicle.car.effects (canonical form after loading)")

    @field_validator("chassis", "front", "rear", "tyres", "interface", "aero", "sensors", "brakes", "powertrain",
                     "steering", "eps", mode="wrap")
    @classmethod
    def _part_tables(cls, v, handler, info):
        """A partial table of a part (brakes, powertrain, steering) overrides its defaults key by key
        (nested sections too). A section's config is immutable and a function of its table alone: one
        validated before in this process from the same table (the same repr: keys, order, types and
        values) is taken again (_PARTS; a batch's run that overrides the chassis mass validates its
        [chassis] and the checks across sections, not the rest again). Only successes are kept."""
        if not isinstance(v, Mapping):
            return handler(v)
        key = (info.field_name, repr(v))
        part = _PARTS.get(key)
        if part is None:
            kind = _PART_KINDS.get(info.field_name)
            part = handler(v if kind is None else over_defaults(kind, v))
            if len(_PARTS) >= 256:
                _PARTS.clear()
            _PARTS[key] = part
        return part

    @field_validator("effects", mode="before")
    @classmethod
    def _effects(cls, v):
        try:
            return validate_effects(v, "effects")
        except ConfigError as exc:
            raise ValueError(str(exc)) from None

    @model_validator(mode="after")
    def _axles(self):
        if not self.front.steered or self.rear.steered:
            raise ValueError("the car steers its front axle through the rack: front double_wishbone or "
                             "vertical_slider with tie rods; rear macpherson or vertical_slider without")
        wf = self.front.hardpoints.wheel_centre
        wr = self.rear.hardpoints.wheel_centre
        if wf[0] <= wr[0]:
            raise ValueError("front wheel centre must be ahead of the rear one (x forward)")
        if wf[1] <= 0 or wr[1] <= 0:
            raise ValueError("hardpoints are given for the left corners (y > 0)")
        if self.eps is not None:
            if self.front.suspension != "vertical_slider" or self.front.pivot_inertia_kgm2 <= 0.0:
                raise ValueError("[eps] steers front vertical sliders about their kingpins: front.suspension "
                                 "= 'vertical_slider' with tie rods and front.pivot_inertia_kgm2 > 0")
        elif self.front.compliance_steer_rad_per_n or self.front.compliance_steer_rad_per_nm:
            raise ValueError("compliance steer needs the front pivots as coordinates ([eps])")
        if self.rear.compliance_steer_rad_per_n or self.rear.compliance_steer_rad_per_nm:
            raise ValueError("compliance steer is modelled at the front axle only")
        return self

    @model_validator(mode="after")
    def _physical(self):
        """The sprung mass's centre between the axles and above the ground (positive static axle loads), and
        the steering ratio the front linkage and the rack give inside STEERING_RATIO_RANGE."""
        cx, _cy, cz = self.chassis.cg_m
        xf, xr = self.front.hardpoints.wheel_centre[0], self.rear.hardpoints.wheel_centre[0]
        if not (xr < cx < xf and cz > 0.0):
            raise bad("chassis.cg_m", self.chassis.cg_m, f"must lie between the axles and above the ground ({xr:g} < x "
                      f"< {xf:g} m, the wheel centres: else an axle carries a negative load; z > 0)")
        key, rp = (("eps.rack_travel_per_rad_m", self.eps.rack_travel_per_rad_m) if self.eps is not None
                   else ("steering.rack_travel_per_rad", self.steering.rack_travel_per_rad))
        hp = {k: None if v is None else np.array(v, dtype=float) for k, v in self.front.hardpoints.model_dump().items()}
        geom = (DoubleWishbone if self.front.suspension == "double_wishbone" else VerticalSlider)(
            spin_axis=self.front.spin_axis(), **hp)
        try:
            ratio = steering_ratio(geom, rp)
        except ModelError as exc:
            raise bad("front.hardpoints", self.front.hardpoints.model_dump(), f"the steering linkage cannot be "
                      f"assembled at straight ahead: {exc}") from None
        lo, hi = STEERING_RATIO_RANGE
        if not lo <= ratio <= hi:
            raise bad(key, rp, f"with the front linkage (front.hardpoints: a {1e3 * steering_arm(geom):.0f} mm "
                      f"steering arm) the overall steering ratio is {ratio:.2f}, outside the plausible {lo:g} <= "
                      f"ratio <= {hi:g} of road cars (steering-wheel angle per road-wheel angle at straight ahead)")
        return self


def load_vehicle(path: str | Path, data: dict | None = None) -> tuple[VehicleConfig, Path]:
    """The validated vehicle config and the folder its relative paths refer to (``data``: the file's
    table when already read, rtsim.vehicle.registry). The [effects] tables are checked first, so that
    their errors name the file and the full key (effects.<name>.<param>)."""
    path = Path(path)
    data = load_toml(path) if data is None else dict(data)
    if "effects" in data:
        data["effects"] = validate_effects(data["effects"], f"{path}: effects")
    cfg = validate(VehicleConfig, data, str(path))
    _tyres_apart(cfg, path)
    return cfg, path.parent


def _tyres_apart(cfg: VehicleConfig, path: Path) -> None:
    """The wheels, with the tyres of the property file, do not overlap: wheelbase > 2 x unloaded radius,
    each axle's track > the tyre's width. (A tyre file that cannot be read is reported where the model
    loads it.)"""
    from ..kit.tyre.tir import load_tir

    try:
        tyre = load_tir(path.parent / cfg.tyres.property_file)
    except ConfigError:
        return
    wf, wr = cfg.front.hardpoints.wheel_centre, cfg.rear.hardpoints.wheel_centre
    if wf[0] - wr[0] <= 2.0 * tyre.unloaded_radius:
        raise problem(path, "rear.hardpoints.wheel_centre", wr, f"the front and rear tyres overlap: wheelbase "
                      f"{wf[0] - wr[0]:g} m, need more than 2 x the tyre's unloaded radius "
                      f"({2 * tyre.unloaded_radius:g} m)")
    for axle, w in (("front", wf), ("rear", wr)):
        if 2.0 * w[1] <= tyre.width:
            raise problem(path, f"{axle}.hardpoints.wheel_centre", w, f"the {axle} tyres overlap: track "
                          f"{2 * w[1]:g} m, need more than the tyre's width ({tyre.width:g} m)")


__all__ = ["VehicleConfig", "load_vehicle", "validate", "load_toml"]
