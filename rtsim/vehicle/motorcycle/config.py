"""The two-wheeler's vehicle file (configs/vehicles/motorcycle.toml, whipple_benchmark.toml), validated
on load.

Frame of every position: the design frame, ISO 8855 (x forward, y left, z up), origin on the ground at
the rear tyre's contact point, the motorcycle upright with both tyres touching the ground at their
unloaded radius and the suspensions at their design travel (the static analysis finds the sag). The
motorcycle is symmetric about y = 0, so positions are (x, z) pairs. Inertia tensors are about each
body's centre of mass in design-frame axes: Ixx, Iyy, Izz and the product ixz_kgm2 = integral of x z dm
(the tensor's xz entry is -ixz, as in the car's file).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from rtsim.configfile import Range, Strict, bad, load_toml, validate
from rtsim.errors import ConfigError

from ..kit.design_frame import Moments, Product, Vec2
from ..kit.inertia import inertia_problem
from ..kit.linkage_checks import MIN_LINK_M
from ..kit.spring_damper import Characteristic
from ..kit.tyre.two_wheel import TwoWheelTyreSpec, sport_front, sport_rear



class Body(Strict):
    """A rigid body's mass properties (massless bodies: mass_kg = 0). The inertia tensor is a rigid body's:
    principal moments non-negative and within the triangle inequalities (a body of the vehicle file with
    mass: positive, checked by MotorcycleConfig)."""
    mass_kg: Range(0, 2000, "kg")
    cg_m: Vec2 = Field(default=(0.0, 0.0), description="centre of mass (x, z), design frame")
    inertia_kgm2: Moments = Field(default=(0.0, 0.0, 0.0), description="Ixx, Iyy, Izz about the CG")
    ixz_kgm2: Product = 0.0

    @model_validator(mode="after")
    def _physical(self):
        problem = inertia_problem(self.inertia_kgm2, self.ixz_kgm2, strict=False)
        if problem is not None:
            raise bad(problem[0], getattr(self, problem[0]), problem[1])
        return self


class Wheel(Strict):
    """A wheel is a body of the model (its in-plane axes are coordinates): mass and both moments positive,
    and spin <= 2 x diametral (the triangle inequality of an axisymmetric body: equal for a thin disc)."""
    mass_kg: Range(0, 100, "kg", lo_open=True) = Field(description="wheel, tyre, disc(s) and sprocket")
    radius_m: Range(0.1, 1.0, "m", lo_open=True) = Field(description="unloaded outer radius of the tyre")
    spin_inertia_kgm2: Range(0, 10, "kg m^2", lo_open=True) = Field(description="about the axle")
    diametral_inertia_kgm2: Range(0, 10, "kg m^2", lo_open=True) = Field(description="about a diameter")

    @model_validator(mode="after")
    def _physical(self):
        if self.spin_inertia_kgm2 > 2.0 * self.diametral_inertia_kgm2 * (1.0 + 1e-9):
            raise bad("spin_inertia_kgm2", self.spin_inertia_kgm2, "more than twice diametral_inertia_kgm2 "
                      f"({self.diametral_inertia_kgm2:g}): violates the triangle inequality of the principal "
                      "moments (spin <= 2 x diametral, equal for a thin disc)")
        return self


class Geometry(Strict):
    wheelbase_m: Range(0.3, 3.0, "m", lo_open=True)
    caster_deg: Range(0, 45, "deg") = Field(description="steering axis from the vertical (rake)")
    trail_m: Range(-0.2, 0.3, "m") | None = Field(default=None, description="ground trail; or fork_offset_m")
    fork_offset_m: Range(-0.2, 0.3, "m") | None = Field(
        default=None, description="front wheel centre ahead of the steering axis")
    fork_length_m: Range(0.05, 1.5, "m", lo_open=True) = Field(
        description="along the steering axis from the head point (top of the fork) down to the foot of the front wheel "
        "centre, at the design travel")
    swingarm_pivot_m: Vec2 = Field(description="swingarm pivot (x, z)")

    @model_validator(mode="after")
    def _one_of(self):
        if (self.trail_m is None) == (self.fork_offset_m is None):
            raise ValueError("give exactly one of trail_m and fork_offset_m")
        return self


class Damper(Strict):
    compression_ns_per_m: Range(0, 1e5, "N s/m") = 0.0
    rebound_ns_per_m: Range(0, 1e5, "N s/m") = 0.0
    table: Characteristic | None = Field(default=None, description="instead of the two rates")


class Spring(Strict):
    """Spring force against the element's compression from its fully extended length (m): a linear rate
    with preload, or a table; stops: top-out below 0 and bottom-out beyond the stroke (linear stops)."""
    stiffness_n_per_m: Range(0, 1e7, "N/m") = 0.0
    preload_n: Range(0, 1e5, "N") = 0.0
    table: Characteristic | None = None
    stroke_m: Range(0, 0.5, "m", lo_open=True)
    top_out_n_per_m: Range(0, 1e8, "N/m") = 2e6
    bottom_out_n_per_m: Range(0, 1e8, "N/m") = 2e6


def _within_stroke(part):
    """The design position lies inside the spring's stroke: 0 <= design_travel_m < spring.stroke_m."""
    if part.design_travel_m >= part.spring.stroke_m:
        raise bad("design_travel_m", part.design_travel_m, f"at or beyond spring.stroke_m ("
                  f"{part.spring.stroke_m:g} m): the design position must lie inside the stroke "
                  "(0 <= design_travel_m < stroke_m)")
    return part


class Fork(Strict):
    spring: Spring
    damper: Damper = Damper()
    design_travel_m: Range(0, 0.5, "m") = Field(default=0.0, description="compression at the design position")

    _stroke = model_validator(mode="after")(_within_stroke)


class Shock(Strict):
    frame_mount_m: Vec2 = Field(description="shock's upper eye on the rear frame (x, z)")
    swingarm_mount_m: Vec2 = Field(description="shock's lower eye on the swingarm (x, z), design position")
    spring: Spring
    damper: Damper = Damper()
    design_travel_m: Range(0, 0.5, "m") = Field(default=0.0, description="compression at the design position")

    _stroke = model_validator(mode="after")(_within_stroke)

    @model_validator(mode="after")
    def _shock_length(self):
        length = math.dist(self.frame_mount_m, self.swingarm_mount_m)
        if length < MIN_LINK_M:
            raise bad("swingarm_mount_m", self.swingarm_mount_m, f"{1e3 * length:.1f} mm from frame_mount_m: the shock "
                      f"has no length (its eyes at least {1e3 * MIN_LINK_M:g} mm apart)")
        return self


class Suspension(Strict):
    locked: bool = Field(default=False, description="fork and swingarm fixed at the design position")
    fork: Fork | None = None
    shock: Shock | None = None

    @model_validator(mode="after")
    def _free_needs_springs(self):
        if not self.locked and (self.fork is None or self.shock is None):
            raise ValueError("a free suspension needs [suspension.fork] and [suspension.shock]")
        return self


class Steering(Strict):
    damper_nms_per_rad: Range(0, 200, "N m s/rad") = Field(default=0.0, description="steering damper")
    lock_rad: Range(0, 1.5, "rad", lo_open=True) = Field(default=0.6, description="steering stops at +-lock")
    stop_nm_per_rad: Range(0, 1e6, "N m/rad") = 2000.0


class Tyres(Strict):
    """The tyre model and, for the slip models, each tyre's parameters (rtsim.vehicle.kit.tyre.two_wheel;
    keys not given take the sport front and rear values; the unloaded radius is the wheel's radius_m)."""
    model: Literal["knife_edge", "magic_formula", "linear"] = Field(description=(
        "knife_edge: rolling without slip (the Whipple bicycle); magic_formula or linear: "
        "rtsim.vehicle.kit.tyre.two_wheel"))
    front: TwoWheelTyreSpec = Field(default_factory=sport_front)
    rear: TwoWheelTyreSpec = Field(default_factory=sport_rear)

    @model_validator(mode="before")
    @classmethod
    def _defaults(cls, data):
        if isinstance(data, dict):
            data = dict(data)
            law = data.get("model")
            for end, base in (("front", sport_front), ("rear", sport_rear)):
                given = data.get(end, {})
                if isinstance(given, dict):
                    merged = {**base().model_dump(), **given}
                    if law in ("magic_formula", "linear") and "model" not in given:
                        merged["model"] = law
                    data[end] = merged
        return data


class Chain(Strict):
    front_sprocket_m: Vec2 = Field(description="gearbox output sprocket centre (x, z), on the rear frame")
    front_sprocket_radius_m: Range(0.01, 0.2, "m", lo_open=True)
    rear_sprocket_radius_m: Range(0.02, 0.3, "m", lo_open=True)


CrankTorque = Range(0.0, 2000.0, "N m")


class Powertrain(Strict):
    """Engine, clutch and gearbox (rtsim.vehicle.motorcycle.engine); the final ratio is the chain's
    sprocket radii (rear / front). Engine speeds in rpm here, rad/s in the kernel."""
    engine_speed_rpm: list[Range(0.0, 25000.0, "rpm", lo_open=True)] = Field(
        min_length=2, max_length=16, description="axis of the torque tables")
    full_load_torque_nm: list[CrankTorque] = Field(min_length=2, max_length=16, description="at full throttle, crank")
    closed_throttle_torque_nm: list[CrankTorque] = Field(min_length=2, max_length=16, description=(
        "friction and pumping torque with the throttle shut (engine braking), a positive magnitude"))
    idle_rpm: Range(300, 5000, "rpm")
    launch_rpm: Range(300, 15000, "rpm") = Field(description="clutch slip speed at full throttle")
    rev_limit_rpm: Range(1000, 25000, "rpm")
    limiter_band_rpm: Range(0, 2000, "rpm", lo_open=True) = Field(
        default=200.0, description="fuel ramp below the limit")
    clutch_capacity_nm: Range(0, 2000, "N m", lo_open=True)
    primary_ratio: Range(1.0, 4.0)
    gear_ratios: list[Range(0.3, 5.0)] = Field(min_length=1, max_length=8, description="first to top")
    efficiency: Range(0.5, 1.0, lo_open=True) = Field(default=0.92, description="gearbox and chain")
    gear: Range(0, 8, integer=True) = Field(default=0, description="0: automatic, else the fixed gear")
    upshift_rpm: Range(1000, 25000, "rpm")
    downshift_rpm: Range(300, 25000, "rpm")
    shift_time_s: Range(0, 1, "s") = Field(default=0.05, description="drive interrupted per shift")
    shift_hold_s: Range(0, 10, "s") = Field(default=0.5, description="minimum time between automatic shifts")

    @model_validator(mode="after")
    def _consistent(self):
        w = self.engine_speed_rpm
        for key in ("full_load_torque_nm", "closed_throttle_torque_nm"):
            v = getattr(self, key)
            if len(v) != len(w):
                raise bad(key, v, f"needs as many values as engine_speed_rpm ({len(w)})")
        if any(b <= a for a, b in zip(w, w[1:])):
            raise bad("engine_speed_rpm", w, "must be strictly increasing")
        if not w[0] <= self.idle_rpm < self.launch_rpm < self.rev_limit_rpm <= w[-1]:
            raise bad("launch_rpm", self.launch_rpm, "need engine_speed_rpm[0] <= idle_rpm < launch_rpm < "
                      f"rev_limit_rpm <= engine_speed_rpm[-1] (got {w[0]:g}, {self.idle_rpm:g}, {self.launch_rpm:g}, "
                      f"{self.rev_limit_rpm:g}, {w[-1]:g})")
        r = self.gear_ratios
        if any(b >= a for a, b in zip(r, r[1:])):
            raise bad("gear_ratios", r, "must decrease from first to top gear")
        if self.gear > len(r):
            raise bad("gear", self.gear, f"the gearbox has gears 1..{len(r)} (0: automatic)")
        if not self.idle_rpm < self.downshift_rpm < self.upshift_rpm < self.rev_limit_rpm - self.limiter_band_rpm:
            raise bad("upshift_rpm", self.upshift_rpm, "need idle_rpm < downshift_rpm < upshift_rpm < "
                      "rev_limit_rpm - limiter_band_rpm")
        for k in range(len(r) - 1):
            after = self.upshift_rpm * r[k + 1] / r[k]
            if after <= self.downshift_rpm:
                raise bad("downshift_rpm", self.downshift_rpm, f"an upshift from gear {k + 1} at upshift_rpm "
                          f"lands at {after:.0f} rpm, at or below the downshift speed: the box would hunt")
        return self


class Brakes(Strict):
    front_nm_per_kpa: Range(0, 10, "N m/kPa", lo_open=True) = Field(description="front brake torque per line pressure")
    rear_nm_per_kpa: Range(0, 10, "N m/kPa", lo_open=True)
    max_pressure_kpa: Range(0, 30000, "kPa", lo_open=True) = 12000.0
    slip_speed_rad_s: Range(0, 10, "rad/s", lo_open=True) = Field(
        default=0.5, description="smooth Coulomb regularisation")


class Aero(Strict):
    drag_area_m2: Range(0, 2, "m^2") = Field(default=0.0, description="Cd A")
    lift_area_m2: Range(-2, 2, "m^2") = Field(default=0.0, description="Cl A, positive lifting")
    centre_of_pressure_m: Vec2 = (0.7, 0.7)
    air_density_kg_m3: Range(0.5, 1.5, "kg/m^3", lo_open=True) = 1.2


class Sensors(Strict):
    imu_position_m: Vec2 = Field(default=(0.6, 0.6), description="IMU on the rear frame (x, z)")


class Interface(Strict):
    dbc: str = Field(default="../can/motorcycle.dbc", description="DBC file, relative to the vehicle file")


class MotorcycleConfig(Strict):
    name: str
    id: str = Field(pattern=r"^[a-z0-9_]+$")
    kind: Literal["two_wheeler"] = "two_wheeler"
    geometry: Geometry
    rear_frame: Body = Field(description="frame, engine, tank; the rider's mass is in [rider]")
    rider: Body | None = Field(default=None, description="rider rigidly attached to the rear frame")
    swingarm: Body = Body(mass_kg=0.0)
    upper_fork: Body = Field(description="upper fork, triple clamps and handlebars: turns with the steer")
    lower_fork: Body = Body(mass_kg=0.0)
    front_wheel: Wheel
    rear_wheel: Wheel
    tyres: Tyres
    suspension: Suspension
    steering: Steering = Steering()
    chain: Chain | None = None
    brakes: Brakes | None = None
    powertrain: Powertrain | None = Field(default=None, description="engine and gearbox; needs [chain]")
    aero: Aero = Aero()
    sensors: Sensors = Sensors()
    interface: Interface = Interface()
    effects: dict | None = Field(default=None, description="effects identified by rtsim validate "
                                 "(rtsim.vehicle.motorcycle.effects); applied by its replay")

    @model_validator(mode="after")
    def _consistent(self):
        if self.effects is not None:
            from .effects import check_effects
            check_effects(self.effects)
        px, pz = self.geometry.swingarm_pivot_m
        if math.hypot(px, pz - self.rear_wheel.radius_m) < 0.05:
            raise ValueError("swingarm_pivot_m is too close to the rear axle")
        if self.powertrain is not None and self.chain is None:
            raise ValueError("[powertrain] needs [chain] (its sprockets give the final ratio)")
        return self

    @model_validator(mode="after")
    def _physical(self):
        """The machine as physics: bodies the model needs have mass, every massive body a rigid body's
        inertia, a massless one none; the wheels apart, the swingarm pivot between them, the whole machine's
        centre of mass between the tyre contacts; a positive trail where tyres steer the fork."""
        for key in ("rear_frame", "upper_fork"):
            body = getattr(self, key)
            if body.mass_kg <= 0.0:
                raise bad(f"{key}.mass_kg", body.mass_kg, "must be positive: the model needs this body's mass "
                          "and inertia (its axes are coordinates of the model)")
        for key in ("rear_frame", "rider", "swingarm", "upper_fork", "lower_fork"):
            body = getattr(self, key)
            if body is None:
                continue
            if body.mass_kg > 0.0:
                problem = inertia_problem(body.inertia_kgm2, body.ixz_kgm2, strict=True)
                if problem is not None:
                    raise bad(f"{key}.{problem[0]}", getattr(body, problem[0]),
                              f"a body of mass {body.mass_kg:g} kg: {problem[1]}")
            elif any(body.inertia_kgm2) or body.ixz_kgm2:
                raise bad(f"{key}.mass_kg", body.mass_kg, f"a massless body has no inertia, yet inertia_kgm2 = "
                          f"{body.inertia_kgm2}, ixz_kgm2 = {body.ixz_kgm2:g} (give its mass, or no inertia)")
        g = self.geometry
        rf, rr = self.front_wheel.radius_m, self.rear_wheel.radius_m
        if g.wheelbase_m <= rf + rr:
            raise bad("geometry.wheelbase_m", g.wheelbase_m, "the wheels overlap: need wheelbase_m > "
                      f"front_wheel.radius_m + rear_wheel.radius_m ({rf + rr:g} m)")
        px, pz = g.swingarm_pivot_m
        if not (0.0 < px < g.wheelbase_m and pz > 0.0):
            raise bad("geometry.swingarm_pivot_m", g.swingarm_pivot_m, "must lie between the axles and above the "
                      f"ground (0 < x < wheelbase_m = {g.wheelbase_m:g} m, z > 0)")
        masses = [(b.mass_kg, b.cg_m[0]) for b in (self.rear_frame, self.rider, self.swingarm, self.upper_fork,
                                                    self.lower_fork) if b is not None]
        masses += [(self.rear_wheel.mass_kg, 0.0), (self.front_wheel.mass_kg, g.wheelbase_m)]
        x_cg = sum(m * x for m, x in masses) / sum(m for m, _ in masses)
        if not 0.0 < x_cg < g.wheelbase_m:
            raise bad("rear_frame.cg_m", self.rear_frame.cg_m, f"puts the whole machine's centre of mass at x = "
                      f"{x_cg:.3f} m, not between the tyre contacts (0 < x < wheelbase_m = {g.wheelbase_m:g} m): "
                      "a wheel would carry a negative load")
        if self.tyres.model != "knife_edge" and not self.trail > 0.0:
            key = "geometry.trail_m" if g.trail_m is not None else "geometry.fork_offset_m"
            raise bad(key, getattr(g, key.split(".")[1]), f"gives a ground trail of {self.trail:.4f} m: with "
                      "tyre forces the trail must be positive (the front tyre's side force then turns the "
                      "steering back; knife_edge wheels, a theoretical bicycle, may have any trail)")
        if g.fork_offset_m is not None and not -0.2 <= self.trail <= 0.3:
            raise bad("geometry.fork_offset_m", g.fork_offset_m, f"gives a ground trail of {self.trail:.4f} m "
                      "(allowed -0.2 <= trail <= 0.3 m, as trail_m)")
        return self

    @property
    def final_ratio(self) -> float:
        """Rear-wheel turns per gearbox output turn: the chain's sprocket radii, rear / front."""
        return self.chain.rear_sprocket_radius_m / self.chain.front_sprocket_radius_m

    @property
    def caster_rad(self) -> float:
        return math.radians(self.geometry.caster_deg)

    @property
    def fork_offset(self) -> float:
        """Front wheel centre's distance ahead of the steering axis, m."""
        g = self.geometry
        if g.fork_offset_m is not None:
            return g.fork_offset_m
        eps = self.caster_rad
        return self.front_wheel.radius_m * math.sin(eps) - g.trail_m * math.cos(eps)

    @property
    def trail(self) -> float:
        eps = self.caster_rad
        return (self.front_wheel.radius_m * math.sin(eps) - self.fork_offset) / math.cos(eps)


def refuse_effects(cfg: MotorcycleConfig, path: str | Path, runner: str) -> None:
    """A two-wheeler's [effects] are applied by `rtsim validate`'s replay only: `runner` (the service, the
    offline ride) would run the nominal model under a file that says otherwise, so it stops instead."""
    if cfg.effects:
        raise ConfigError(f"{path}: [effects] ({', '.join(cfg.effects)}): a two-wheeler's identified effects are "
                          f"applied by `rtsim validate`'s replay only, not yet by {runner}; run the file they were "
                          "identified on, or remove the [effects] tables to run the nominal model")


def load_motorcycle(path: str | Path, data: dict | None = None) -> tuple[MotorcycleConfig, Path]:
    """The validated two-wheeler file and the folder its relative paths refer to (``data``: the file's
    table when already read, rtsim.vehicle.registry)."""
    path = Path(path)
    return validate(MotorcycleConfig, load_toml(path) if data is None else data, str(path)), path.parent
