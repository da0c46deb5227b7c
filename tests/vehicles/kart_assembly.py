"""The kart's assembly: a chassis with four wheels bolted to it (no suspension), the front wheels steered
about their kingpins by tie rods from a rack, the rear wheels driven, brakes on all four, from the kit's
parts. It reads the kart's compact tables ([chassis], [wheels], and the kit parts' own tables passed
through: [tyres], [brakes], [powertrain], [steering], [aero], [sensors], [interface]) and wires them
as the four-wheel car's assembly does, with every corner a rigid mount (``rigid = true``: the slide's
travel held by a constraint, no spring, damper or anti-roll bar). So it serves the car's tuple and
steps with the car's stages; the kart's own part is only this wiring.

Named by the vehicle file (``assembly = "kart_assembly.py"``), opened by rtsim.vehicle.registry like
any vehicle: nothing in rtsim names it.
"""
from __future__ import annotations

from pydantic import Field

from rtsim.configfile import Strict, validate
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.kind import CarKind

KART_TABLES = ("name", "id", "chassis", "tyres", "interface", "aero", "sensors", "brakes", "powertrain",
               "steering", "effects")
TRAVEL_M = (-0.02, 0.02)        # the slide's fitted range (the mount holds it at 0)


class Wheels(Strict):
    """Where the four wheels sit and what they weigh (design frame, m; kg; kg m^2)."""
    wheelbase_m: float = Field(gt=0.6, le=3.0)
    track_front_m: float = Field(gt=0.5, le=2.5)
    track_rear_m: float = Field(gt=0.5, le=2.5)
    mass_kg: float = Field(gt=1.0, le=50.0, description="per wheel")
    spin_inertia_kgm2: float = Field(gt=0.05, le=5.0, description="per wheel about its axle")
    steering_arm_m: float = Field(default=0.10, gt=0.04, le=0.3, description="kingpin to the tie rod's end")
    kingpin_offset_m: float = Field(default=0.05, ge=0.0, le=0.2, description="kingpin inboard of the wheel")


def _tyre_radius(data: dict, path) -> float:
    from rtsim.vehicle.kit.tyre.tir import load_tir

    return float(load_tir(path.parent / data["tyres"]["property_file"]).unloaded_radius)


def car_table(data: dict, path) -> dict:
    """The kart's tables as the car assembly's (rtsim.vehicle.car.config.VehicleConfig): two rigid axles,
    the front one steered through its tie rods, driven at the rear."""
    w = validate(Wheels, data.get("wheels", {}), f"{path}: wheels")
    r = _tyre_radius(data, path)
    yf, yr, arm, off = w.track_front_m / 2, w.track_rear_m / 2, w.steering_arm_m, w.kingpin_offset_m
    xr = -w.wheelbase_m

    def axle(x: float, y: float, steered: bool) -> dict:
        hp = {"wheel_centre": [x, y, r],
              # the slide's (unused) spring mounts: a rigid mount carries no spring
              "spring_lower": [x, y - 0.1, r], "spring_upper": [x, y - 0.1, r + 0.2]}
        if steered:
            kp = [x, y - off, r]
            hp |= {"kingpin": kp, "tie_outer": [x - arm, y - off, r],
                   "tie_inner": [x - arm, 0.12, r]}
        return {"suspension": "vertical_slider", "rigid": True, "hardpoints": hp, "travel_m": list(TRAVEL_M),
                "unsprung_mass_kg": w.mass_kg, "wheel_spin_inertia_kgm2": w.spin_inertia_kgm2}

    out = {k: data[k] for k in KART_TABLES if k in data}
    out["front"] = axle(0.0, yf, True)
    out["rear"] = axle(xr, yr, False)
    out["driven_axle"] = "rear"
    return out


class KartKind(CarKind):
    """The kart: the car's kind (its build, offline runner, service tuple, demo) over the kart's tables."""
    name = "kart"

    def load(self, data, path):
        unknown = sorted(set(data) - set(KART_TABLES) - {"wheels"})
        if unknown:
            from rtsim.errors import ConfigError
            raise ConfigError(f"{path}: {unknown[0]}: unknown key (a kart has {', '.join(KART_TABLES)}, wheels)")
        return load_vehicle(path, car_table(data, path))


KIND = KartKind()
