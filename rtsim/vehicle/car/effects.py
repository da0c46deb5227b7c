"""The catalogue of switchable physical effects: named, parameterised extensions the nominal vehicle
model lacks, switched on from the vehicle config (``[effects.<name>]``) or at run time
(``VehicleSim.set_effects``) without rebuilding the model. The validation workflow (issue 5) fits their
parameters by re-simulation and writes the winner back into a config.

Mapping form (config tables, ``set_effects``, ``VehicleSim(effects=...)``), SI units::

    {"rolling_resistance": {"coefficient": 0.012},
     "sensor_bias": [{"channel": "accel_x", "bias": 0.1}, {"channel": "gyro_z", "bias": -0.002}]}

and in TOML::

    [effects.rolling_resistance]
    coefficient = 0.012
    [[effects.sensor_bias]]          # sensor effects: an array of tables, one per channel
    channel = "accel_x"
    bias = 0.1

A single table is accepted for a sensor effect too (one channel). Every parameter is required; its
plausible range (ParamSpec.lo..hi, for sensor_bias the channel's own range, ``EffectSpec.bounds``) is
enforced on load and by ``set_effects``. Sensor effects act on the channels of
rtsim.channels.SENSOR_NAMES in the sensor stage (``VehicleSim.sensors``): y = scale x(t - delay) + bias.
They are parameters of the one sensor model (rtsim.vehicle.kit.sensor_model.sensor_params), packed there
with the config's ``[sensors.channels]`` into one array: their biases and delays add to the config's,
their scales multiply the config's.
Wheel speeds are not sensor channels (the workflow derives them from ``wheel_angle_*``): a scale or
delay of a wheel angle carries over to its speed, and a bias of a speed has no meaning for an angle
counter, so there are no ``wheel_speed_*`` sensor effects. The formulations are in
rtsim.vehicle.car.effect_kernels.

Mass at run time. The multibody model's mass matrix is constant and compiled into ``Model.m_env``,
which every VehicleSim of one VehicleModel shares, and the integrator reuses its Cholesky factor across
steps. So ``mass`` does not touch the model arrays: the point mass dm enters the vehicle forces as
-dm r'' - dm g e_z at the centre of mass (r'' being the Newton iterate's trapezoidal acceleration),
with its exact tangent dm added to W = M + h/2 C + h^2/4 K whenever the tangent is rebuilt. The Newton
residual, the tangent and the metric of the velocity and acceleration projections all then carry
M + dm, i.e. the step integrates the heavier car exactly, and ``set_effects`` flags a refactorization
when dm (or the driveline) changes. The penalty factors keep the nominal mass scale (they only
condition the constraints). The added mass is not in the car's static placement: it sags onto its
springs during the first second (the same whether set at construction or by set_effects).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Optional

import numpy as np

from pydantic import Field, create_model, model_validator
from pydantic_core import PydanticCustomError

from rtsim.channels import BY_NAME, COMMANDS, EPS_COMMANDS, SENSOR_NAMES
from rtsim.configfile import Range, Strict, bad, validate
from rtsim.errors import ConfigError

from .effect_kernels import (
    BRAKE_STICTION_PRESSURE, DRIVELINE_DAMPING_RATIO, DRIVELINE_INERTIA, FX_B_BREAK, FX_B_LAG, FX_B_SCALE,
    FX_BEARING, FX_BRAKE, FX_CDA, FX_COS, FX_DL, FX_DL_C, FX_DL_J, FX_DL_K, FX_G_1MCOS, FX_G_SIN, FX_GRADE,
    FX_M_CHASSIS, FX_M_CORNER, FX_MASS, FX_ON, FX_RELAX, FX_RR, FX_SIN, FX_SLIP, neutral_params,
)


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: SI unit, a typical value (start of a fit), the physically plausible range and
    the value at which the effect does nothing (None: none, e.g. an infinitely stiff driveline)."""
    name: str
    unit: str
    default: float
    lo: float
    hi: float
    description: str
    neutral: float | None = None


@dataclass(frozen=True)
class EffectSpec:
    name: str
    kind: Literal["model", "sensor"]
    params: tuple[ParamSpec, ...]      # numeric parameters (sensor effects also take a `channel`)
    description: str
    signature: str                     # where it shows in the channels, and how

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)

    def param(self, name: str) -> ParamSpec:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(f"effect {self.name!r} has no parameter {name!r}")

    def bounds(self, param: str, channel: str | None = None) -> tuple[float, float]:
        """Plausible range of a parameter; sensor_bias.bias depends on the channel (its unit)."""
        if self.name == "sensor_bias" and param == "bias":
            if channel is None:
                raise ValueError("sensor_bias.bias: the plausible range depends on the channel; give it")
            return self.bias_range(channel)
        p = self.param(param)
        return p.lo, p.hi

    def bias_range(self, channel: str) -> tuple[float, float]:
        """Plausible sensor offsets of a channel of this catalogue's vehicle (the car's: `_bias_range`)."""
        return _bias_range(channel)


def _bias_range(channel: str) -> tuple[float, float]:
    """Plausible offsets per channel: a few degrees of mounting tilt for the accelerometers (2 m/s^2),
    MEMS gyro offsets (0.1 rad/s), 0.2 rad for angle encoders and inclinometers, one revolution for a
    wheel angle counter, 500 kPa, 50 N*m (5 N*m on the steering column), 50 rad/s of engine speed; for
    the EPS's sensors 10 A of current offset, 2 m/s of speed and a whole step of the stage flag."""
    special = {"steering_torque": 5.0, "engine_speed": 50.0}
    if channel in special:
        b = special[channel]
    elif channel.startswith("wheel_angle_"):
        b = 2.0 * math.pi
    else:
        b = {"m/s^2": 2.0, "rad/s": 0.1, "rad": 0.2, "kPa": 500.0, "N*m": 50.0, "A": 10.0, "m/s": 2.0,
         "1": 1.0}[BY_NAME[channel].unit]
    return -b, b


def _p(name, unit, default, lo, hi, description, neutral=0.0) -> ParamSpec:
    return ParamSpec(name, unit, default, lo, hi, description, neutral)


EFFECTS: dict[str, EffectSpec] = {e.name: e for e in (
    EffectSpec("rolling_resistance", "model",
               (_p("coefficient", "1", 0.01, 0.0, 0.05, "added rolling-resistance coefficient: a force c Fz at "
                   "each contact patch opposing rolling"),),
               "Rolling resistance on top of the tyre's and the road's: c Fz per wheel opposing the wheel "
               "centre's forward speed, C1-smooth through standstill (|vx| < 0.1 m/s).",
               "coast-down decelerates more by ~c g, independent of speed; no effect at standstill; "
               "steady speed needs more drive torque (c m g r)"),
    EffectSpec("aero_drag", "model",
               (_p("drag_area", "m^2", 0.3, 0.0, 2.0, "added drag area Cd A (air density of the config)"),),
               "Aerodynamic drag on top of the model's: 0.5 rho dCdA |v| v at the centre of mass.",
               "decelerates in coast-down ~ v^2 (0.5 rho CdA v^2 / m); negligible below ~5 m/s; "
               "no effect at standstill"),
    EffectSpec("road_grade", "model",
               (_p("grade", "1", 0.02, -0.3, 0.3, "rise over run, positive uphill in the direction of "
                   "travel (the car's heading)"),),
               "The road rises at this grade along the car's heading: gravity is tilted by atan(grade) "
               "for all masses, and the accelerometers and inclinometers sense the tilted gravity.",
               "constant offset of the longitudinal force -m g sin(atan(grade)): slower acceleration "
               "uphill, creep when released; accel_x offset +g sin at rest, pitch -atan(grade)"),
    EffectSpec("brake_friction", "model",
               (_p("scale", "1", 0.8, 0.3, 2.0, "factor on the pad friction, i.e. on every brake torque "
                   "(sliding and breakaway)", 1.0),),
               "Pad/disc friction differs from the nominal mu: all brake torques scaled.",
               "braking deceleration scaled in proportion to the brake torque; no effect without "
               "brake pressure"),
    EffectSpec("brake_stiction", "model",
               (_p("breakaway_torque", "N*m", 50.0, 0.0, 500.0, "added static (breakaway) friction torque "
                   f"per wheel, full from {BRAKE_STICTION_PRESSURE:g} kPa wheel-cylinder pressure, "
                   "linear below"),),
               "A held wheel needs this much more torque to break away than the nominal mu_s/mu; it "
               "vanishes with the pressure (pads lift off), so a released brake drags nothing.",
               "the car starts later when the brake is released from standstill (and is held "
               "against more torque); no effect while rolling"),
    EffectSpec("brake_lag", "model",
               (_p("time_constant", "s", 0.05, 0.0, 0.5, "first-order lag from line pressure to "
                   "brake torque (hydraulic line and caliper compliance)"),),
               "The brake torque follows the measured line pressure through a first-order lag.",
               "deceleration lags brake_pressure at each brake application and release by tau; "
               "steady braking unchanged"),
    EffectSpec("driveline_compliance", "model",
               (ParamSpec("stiffness", "N*m/rad", 5000.0, 300.0, 1e5, "torsional stiffness per driven "
                          f"wheel between the drive torque source and the wheel (node inertia "
                          f"{DRIVELINE_INERTIA:g} kg*m^2, damping ratio {DRIVELINE_DAMPING_RATIO:g})",
                          None),),
               "The drive torque (engine model or measured wheel torque) reaches each driven wheel "
               "through a torsional spring with a little damping, from a node of inertia "
               f"{DRIVELINE_INERTIA:g} kg*m^2; the powertrain sees the node speed.",
               "torsional oscillation at ~sqrt(k/J) after drive-torque steps (wheel speeds, accel_x); "
               "smooth torque inputs show almost nothing"),
    EffectSpec("tyre_slip_stiffness", "model",
               (_p("scale", "1", 0.8, 0.3, 3.0, "factor on the longitudinal slip stiffness and the "
                   "cornering stiffness (peak friction unchanged)", 1.0),),
               "The slips fed to the tyre force law are scaled (kappa s, atan(s tan alpha)).",
               "wheel slip at a given drive/brake force scales by 1/s (driven wheel speed vs free "
               "wheels); lateral: yaw-rate and accel_y gains at small slip angles"),
    EffectSpec("tyre_relaxation", "model",
               (_p("length", "m", 0.2, 0.0, 1.5, "added relaxation length (longitudinal and lateral)"),),
               "Tyre forces build up over a longer rolling distance (transient-slip model), and the "
               "tyre is a softer spring at standstill.",
               "force transients lag by ~L/v: slower yaw-rate rise in steering, delayed drive/brake "
               "force at low speed; steady state unchanged"),
    EffectSpec("bearing_drag", "model",
               (_p("torque", "N*m", 2.0, 0.0, 30.0, "drag torque per wheel between wheel and knuckle "
                   "(bearings, seals, residual pad drag)"),),
               "A constant drag torque on each wheel's spin, C1-smooth through standstill "
               "(|omega| < 0.2 rad/s).",
               "coast-down decelerates more by ~4 T / (r m), independent of speed; no effect at "
               "standstill"),
    EffectSpec("mass", "model",
               (_p("added_mass", "kg", 50.0, -200.0, 600.0, "point mass at the sprung centre of mass "
                   "(negative: the model is heavier than the car)"),),
               "Extra mass at the centre of mass with its weight and its translational inertia (a point "
               "mass: no rotational inertia); the car settles onto its springs after it is added.",
               "every longitudinal acceleration scales by m/(m + dm) for the same forces; grade and "
               "rolling loads grow; static sag (accel_z, pitch transients at the start)"),
    EffectSpec("sensor_delay", "sensor",
               (_p("delay", "s", 0.02, 0.0, 0.5, "transport delay of the channel"),),
               "The channel shows its value `delay` seconds late (linear between integrator steps).",
               "the channel is shifted in time against the others: residual ~ -delay x'(t), largest "
               "where the channel changes fast; zero in steady phases"),
    EffectSpec("sensor_bias", "sensor",
               (ParamSpec("bias", "unit of the channel", 0.0, -math.inf, math.inf, "constant offset; the "
                          "plausible range depends on the channel (EffectSpec.bounds)", 0.0),),
               "The channel reads a constant offset.",
               "constant residual on one channel in every phase, also at standstill"),
    EffectSpec("sensor_scale", "sensor",
               (_p("scale", "1", 1.05, 0.5, 2.0, "gain error of the channel (wheel angles: rolling "
                   "radius / tooth count)", 1.0),),
               "The channel reads its value times a factor.",
               "residual proportional to the channel's value: zero where it is zero, largest at its "
               "peaks"),
)}

SENSOR_EFFECTS = tuple(n for n, e in EFFECTS.items() if e.kind == "sensor")
MODEL_EFFECTS = tuple(n for n, e in EFFECTS.items() if e.kind == "model")


# ---------------------------------------------------------------------------------------- validation
def _param_field(spec: EffectSpec, p: ParamSpec):
    lo, hi = (-1e9, 1e9) if (spec.name == "sensor_bias" and p.name == "bias") else (p.lo, p.hi)
    unit = "" if p.unit == "1" or p.unit.startswith("unit") else p.unit
    return (Range(lo, hi, unit), Field(description=p.description))


def _effect_model(spec: EffectSpec) -> type[Strict]:
    """The pydantic model of one effect's table, from the catalogue: every parameter required, within
    its plausible range (sensor_bias.bias within the channel's, which depends on the channel)."""
    fields = {p.name: _param_field(spec, p) for p in spec.params}
    if spec.kind == "sensor":
        fields = {"channel": (str, Field(description="sensor channel")), **fields}
    model = create_model(f"Effect_{spec.name}", __base__=Strict, **fields)
    if spec.kind == "sensor":
        def _check(self, spec=spec):
            if self.channel not in BY_NAME or BY_NAME[self.channel] not in SENSOR_CHANNELS:
                raise bad("channel", self.channel, f"not a sensor channel; channels are {', '.join(SENSOR_NAMES)}")
            if spec.name == "sensor_bias":
                lo, hi = spec.bounds("bias", self.channel)
                if not lo <= self.bias <= hi:
                    raise bad("bias", self.bias, f"out of range (allowed {lo:g} <= bias <= {hi:g} "
                                                 f"{BY_NAME[self.channel].unit})")
            return self
        model = create_model(f"Effect_{spec.name}", __base__=model,
                             __validators__={"_channel": model_validator(mode="after")(_check)})
    return model


def _effects_model() -> type[Strict]:
    """The pydantic model of an [effects] table: a model effect is one table, a sensor effect an array
    of tables (one table alone is one channel), each channel at most once."""
    fields = {}
    for name, spec in EFFECTS.items():
        m = _effect_model(spec)
        fields[name] = (Optional[m] if spec.kind == "model" else Optional[list[m]], None)

    def _shapes(cls, data):
        if isinstance(data, dict):
            for name, val in data.items():
                spec = EFFECTS.get(name)
                if spec is None:
                    raise PydanticCustomError("unknown_key", "unknown effect", {
                        "key": name, "value": val, "allowed": ", ".join(EFFECTS)})
                if spec.kind == "model" and isinstance(val, (list, tuple)):
                    raise bad(name, "[...]", f"a model effect is one table ([effects.{name}]), not an array")
            return {k: ([v] if EFFECTS[k].kind == "sensor" and isinstance(v, dict) else v) for k, v in data.items()}
        return data

    def _channels_once(self):
        for name in SENSOR_EFFECTS:
            seen = set()
            for k, row in enumerate(getattr(self, name) or ()):
                if row.channel in seen:
                    raise bad(f"{name}[{k}].channel", row.channel, f"channel given twice for {name}")
                seen.add(row.channel)
        return self

    return create_model("Effects", __base__=Strict, **fields, __validators__={
        "_shapes": model_validator(mode="before")(classmethod(_shapes)),
        "_channels_once": model_validator(mode="after")(_channels_once)})


SENSOR_CHANNELS = tuple(c for c in BY_NAME.values() if c not in COMMANDS + EPS_COMMANDS)
_EFFECTS_MODEL = _effects_model()


def validate_effects(mapping, where: str = "effects") -> dict:
    """The canonical effects mapping of `mapping` (None or {} for none): model effects as
    {name: {param: float}}, sensor effects as {name: [{"channel": str, param: float}, ...]}.
    ConfigError (rtsim.configfile: one line naming `where`, the key, the value and the allowed range)
    otherwise."""
    if mapping is None:
        return {}
    if hasattr(mapping, "items") and not isinstance(mapping, dict):
        mapping = dict(mapping.items())
    source, _, prefix = where.rpartition(": ")
    eff = validate(_EFFECTS_MODEL, mapping, source, prefix=prefix)
    return {k: v for k, v in eff.model_dump(exclude_none=True).items() if v != []}


def effects_toml(effects) -> str:
    """TOML text of an effects mapping ([effects.<name>] tables, [[effects.<sensor effect>]] arrays)."""
    eff = validate_effects(effects)
    lines: list[str] = []
    for name, val in eff.items():
        if EFFECTS[name].kind == "model":
            lines.append(f"[effects.{name}]")
            lines += [f"{k} = {v!r}" for k, v in val.items()]
        else:
            for row in val:
                lines.append(f"[[effects.{name}]]")
                lines += [f'channel = "{row["channel"]}"'] + [f"{k} = {v!r}" for k, v in row.items()
                                                             if k != "channel"]
        lines.append("")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------- packing
def pack_effects(effects: dict, dt: float, chassis_mass: float, unsprung_masses, g: float) -> np.ndarray:
    """The kernels' parameter array (rtsim.vehicle.car.effect_kernels FX_*) of a validated effects mapping,
    for integrator step dt (s), sprung mass (kg), the four unsprung masses (kg) and the model's gravity g
    (m/s^2, downward: rtsim.mbs.model.gravity's -z component), which the road grade tilts."""
    fx = neutral_params()
    model_on = False

    def val(name, param):
        return effects[name][param] if name in effects else None

    if (c := val("rolling_resistance", "coefficient")) is not None:
        fx[FX_RR] = c
        model_on = True
    if (a := val("aero_drag", "drag_area")) is not None:
        fx[FX_CDA] = a
        model_on = True
    dm = val("mass", "added_mass") or 0.0
    if "mass" in effects:
        if chassis_mass + dm <= 0.0:
            raise ConfigError(f"effects.mass.added_mass = {dm:g}: leaves no sprung mass ({chassis_mass:g} kg)")
        fx[FX_MASS] = dm
        model_on = True
    if (grade := val("road_grade", "grade")) is not None:
        th = math.atan(grade)
        fx[FX_GRADE] = 1.0
        fx[FX_SIN], fx[FX_COS] = math.sin(th), math.cos(th)
        fx[FX_G_SIN], fx[FX_G_1MCOS] = g * math.sin(th), g * (1.0 - math.cos(th))
        model_on = True
    fx[FX_M_CHASSIS] = chassis_mass + dm
    fx[FX_M_CORNER:FX_M_CORNER + 4] = unsprung_masses
    if any(n in effects for n in ("brake_friction", "brake_stiction", "brake_lag")):
        fx[FX_BRAKE] = 1.0
        model_on = True
        fx[FX_B_SCALE] = val("brake_friction", "scale") or 1.0
        fx[FX_B_BREAK] = val("brake_stiction", "breakaway_torque") or 0.0
        tau = val("brake_lag", "time_constant") or 0.0
        fx[FX_B_LAG] = 1.0 - math.exp(-dt / tau) if tau > 0.0 else 0.0
    if (k := val("driveline_compliance", "stiffness")) is not None:
        fx[FX_DL] = 1.0
        fx[FX_DL_K] = k
        fx[FX_DL_J] = DRIVELINE_INERTIA
        fx[FX_DL_C] = 2.0 * DRIVELINE_DAMPING_RATIO * math.sqrt(k * DRIVELINE_INERTIA)
        model_on = True
    if (s := val("tyre_slip_stiffness", "scale")) is not None:
        fx[FX_SLIP] = s
        model_on = True
    if (length := val("tyre_relaxation", "length")) is not None:
        fx[FX_RELAX] = length
        model_on = True
    if (t := val("bearing_drag", "torque")) is not None:
        fx[FX_BEARING] = t
        model_on = True
    fx[FX_ON] = 1.0 if model_on else 0.0
    return fx


__all__ = ["ParamSpec", "EffectSpec", "EFFECTS", "SENSOR_EFFECTS", "MODEL_EFFECTS", "validate_effects",
           "pack_effects", "effects_toml"]
