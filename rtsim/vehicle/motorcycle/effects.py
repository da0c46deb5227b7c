"""The two-wheeler's effect catalogue (its validation profile's, rtsim.vehicle.motorcycle.validation): the
physical effects a motorcycle model may lack, each applied by the validation workflow's replay
re-parametrising the model for one simulation, and the sensor effects on its channels.

Model effects (their parameters, SI):

- ``mass`` (added_mass, kg): rider or luggage heavier than the vehicle file says; the mass is added at
  the rider's centre of mass (the rider body of the file) and the model is rebuilt and settled on its
  suspension for that simulation;
- ``road_grade`` (grade, rise over run): the road rises along +x of the run's start heading; gravity is
  tilted by atan(grade) in the rebuilt model and the accelerometers sense the tilted gravity;
- ``brake_friction`` (scale): factor on both brakes' torque per unit caliper pressure (pad friction);
- ``tyre_cornering_stiffness`` (scale): factor on both tyres' cornering stiffness per unit load;
- ``tyre_camber_stiffness`` (scale): factor on both tyres' camber stiffness per unit load.

Sensor effects (bias, scale, delay) act on the compared channels through the vehicle's one sensor model
(rtsim.vehicle.kit.sensor_model), as for the car. The replay's inputs (roll, throttle, caliper
pressures) are not offered sensor effects: the replay follows them as recorded.

The names and parameters follow the car's catalogue (rtsim.vehicle.car.effects) where the effect is the
same, so a fitted value reads alike for both vehicles.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from rtsim.channels import TWO_WHEELER_SENSORS

from ..car.effects import EFFECTS as CAR_EFFECTS
from ..car.effects import EffectSpec, ParamSpec

UNITS = {c.name: c.unit for c in TWO_WHEELER_SENSORS}


def _bias_range(channel: str) -> tuple[float, float]:
    """Plausible offsets per two-wheeler channel: a few degrees of IMU tilt (2 m/s^2), MEMS gyro offsets
    (0.1 rad/s), 0.2 rad for angles, 5 N m for the steering-head torque sensor, 10 mm for a suspension
    potentiometer, 2 rad/s for a wheel-speed sensor."""
    special = {"steering_torque": 5.0, "fork_travel": 0.01, "shock_travel": 0.01,
               "wheel_speed_front": 2.0, "wheel_speed_rear": 2.0}
    if channel in special:
        b = special[channel]
    else:
        b = {"m/s^2": 2.0, "rad/s": 0.1, "rad": 0.2, "kPa": 500.0, "N*m": 5.0, "1": 0.2, "m": 0.01}[UNITS[channel]]
    return -b, b


@dataclass(frozen=True)
class TwoWheelerEffectSpec(EffectSpec):
    """An effect of the two-wheeler's catalogue: sensor biases bounded by the two-wheeler's channel units."""

    def bias_range(self, channel: str) -> tuple[float, float]:
        return _bias_range(channel)


def _p(name, unit, default, lo, hi, description, neutral=0.0) -> ParamSpec:
    return ParamSpec(name, unit, default, lo, hi, description, neutral)


def _copy(name: str) -> TwoWheelerEffectSpec:
    e = CAR_EFFECTS[name]
    return TwoWheelerEffectSpec(e.name, e.kind, e.params, e.description, e.signature)


EFFECTS: dict[str, EffectSpec] = {e.name: e for e in (
    TwoWheelerEffectSpec(
        "mass", "model",
        (_p("added_mass", "kg", 20.0, -60.0, 150.0, "mass added at the rider's centre of mass (negative: the "
            "model is heavier than the motorcycle)"),),
        "Rider or luggage heavier than the file: a point mass at the rider's centre of mass (the model is "
        "rebuilt with it and settled on its suspension).",
        "accel_x scales by m/(m + dm) for the same drive and brake forces; wheel speeds drift; fork and "
        "shock sag and pitch change; steering torque to hold a lean grows"),
    TwoWheelerEffectSpec(
        "road_grade", "model",
        (_p("grade", "1", 0.02, -0.3, 0.3, "rise over run along the start heading, positive uphill"),),
        "The road rises along the run's start heading: gravity tilted by atan(grade) for every body, and "
        "sensed so by the accelerometers.",
        "constant longitudinal force -m g sin(atan(grade)): slower acceleration uphill; accel_x offset "
        "by +g sin, pitch by -atan(grade)"),
    TwoWheelerEffectSpec(
        "brake_friction", "model",
        (_p("scale", "1", 0.8, 0.3, 2.0, "factor on both brakes' torque per unit caliper pressure", 1.0),),
        "Pad/disc friction differs from the file: both brake torques scaled.",
        "braking deceleration (accel_x, wheel speeds) and fork dive scale with the brake torque; no "
        "effect without brake pressure"),
    TwoWheelerEffectSpec(
        "tyre_cornering_stiffness", "model",
        (_p("scale", "1", 0.8, 0.3, 3.0, "factor on both tyres' cornering stiffness per unit load", 1.0),),
        "Both tyres' side force per unit slip angle scaled (peak friction unchanged).",
        "at a given lean: steer angle and steering torque change, yaw rate little; straight running "
        "unchanged"),
    TwoWheelerEffectSpec(
        "tyre_camber_stiffness", "model",
        (_p("scale", "1", 0.8, 0.3, 3.0, "factor on both tyres' camber stiffness per unit load", 1.0),),
        "Both tyres' camber thrust per unit camber scaled.",
        "at a given lean: the slip angles (steer angle, steering torque) the turn needs change; straight "
        "running unchanged"),
    _copy("sensor_delay"),
    _copy("sensor_bias"),
    _copy("sensor_scale"),
)}

#: The model effects' names, in the order the workflow screens them.
MODEL_EFFECTS = tuple(n for n, e in EFFECTS.items() if e.kind == "model")
assert all(math.isfinite(p.default) for e in EFFECTS.values() for p in e.params if e.kind == "model")


def check_effects(mapping: dict) -> None:
    """A vehicle file's [effects] for the two-wheeler: known names, every parameter given and inside its
    plausible range (sensor effects: arrays of tables with a `channel` of the two-wheeler). ValueError
    naming the effect, parameter and value otherwise."""
    for name, val in mapping.items():
        spec = EFFECTS.get(name)
        if spec is None:
            raise ValueError(f"effects.{name}: unknown effect (the two-wheeler's are {', '.join(EFFECTS)})")
        rows = val if isinstance(val, list) else [val]
        for row in rows:
            if not isinstance(row, dict):
                raise ValueError(f"effects.{name}: must be a table")
            ch = row.get("channel")
            if spec.kind == "sensor" and ch not in UNITS:
                raise ValueError(f"effects.{name}.channel = {ch!r}: not a two-wheeler sensor channel")
            extra = set(row) - set(spec.param_names) - ({"channel"} if spec.kind == "sensor" else set())
            if extra:
                raise ValueError(f"effects.{name}: unknown key(s) {', '.join(sorted(extra))}")
            for p in spec.params:
                if p.name not in row:
                    raise ValueError(f"effects.{name}.{p.name}: missing (required)")
                lo, hi = spec.bounds(p.name, ch)
                v = row[p.name]
                if not isinstance(v, (int, float)) or not lo <= float(v) <= hi:
                    raise ValueError(f"effects.{name}.{p.name} = {v!r}: outside the plausible range [{lo:g}, {hi:g}]")
