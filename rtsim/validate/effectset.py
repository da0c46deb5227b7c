"""Effects as the workflow handles them: a name from the vehicle's effect catalogue (its validation
profile's, rtsim.vehicle.validation: the car's rtsim.vehicle.car.effects.EFFECTS, the two-wheeler's
rtsim.vehicle.motorcycle.effects.EFFECTS) with its parameter values, and the conversions to the mapping
that `VehicleSim.set_effects` and the vehicle config's `[effects]` tables take:
{"rolling_resistance": {"coefficient": 0.012}, "sensor_bias": [{"channel": "accel_x", "bias": 0.1}]}.
Model effects go to the model; sensor effects are applied to the model's outputs
(rtsim.validate.replay.Replayer.reported: the vehicle's one sensor model)."""
from __future__ import annotations

from dataclasses import dataclass, field

#: The sensor effects: those of the one sensor model every vehicle shares (rtsim.vehicle.kit.sensor_model),
#: the same names in every vehicle's catalogue; every other effect acts on the model.
SENSOR_EFFECTS = ("sensor_delay", "sensor_bias", "sensor_scale")


def kind(name: str) -> str:
    """The effect's kind: "sensor" for an effect of the sensor model, else "model"."""
    return "sensor" if name in SENSOR_EFFECTS else "model"


@dataclass
class Effect:
    name: str
    params: dict                                         # parameter -> value (SI); sensor effects: + "channel"
    uncertainty: dict = field(default_factory=dict)      # parameter -> 95 % half-width (SI)
    #: parameter -> the 95 % half-width the model error alone gives (the linearised interval from the residual
    #: left at the fit, structural part included; uncertainty combines it with the runs' scatter)
    model_error: dict = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return kind(self.name)

    def set_interval(self, name: str, half: float, model_error: float) -> None:
        """Parameter `name`'s 95 % half-width and the part of it the model error alone gives."""
        self.uncertainty = {name: half}
        self.model_error = {name: model_error}

    def adopt_interval(self, other: "Effect") -> None:
        self.uncertainty, self.model_error = dict(other.uncertainty), dict(other.model_error)

    @property
    def channel(self) -> str | None:
        return self.params.get("channel")

    @property
    def key(self) -> tuple:
        """Identity for 'already in the model': the name, and the channel of a sensor effect."""
        return (self.name, self.channel)

    def values(self) -> dict:
        """Numeric parameters only."""
        return {k: v for k, v in self.params.items() if k != "channel"}

    def label(self) -> str:
        vals = ", ".join(f"{k} = {v:.4g}" for k, v in self.values().items())
        return f"{self.name}[{self.channel}]({vals})" if self.channel else f"{self.name}({vals})"


def to_mapping(effects: list[Effect]) -> dict:
    """The set_effects / config mapping of a list of effects (sensor effects as lists of tables)."""
    out: dict = {}
    for e in effects:
        if e.kind == "sensor":
            out.setdefault(e.name, []).append(dict(e.params))
        else:
            out[e.name] = dict(e.params)
    return out


def model_mapping(effects: list[Effect]) -> dict:
    return to_mapping([e for e in effects if e.kind != "sensor"])


def from_mapping(mapping) -> list[Effect]:
    """Effects of a config's effects mapping (dict or pydantic model)."""
    if mapping is None:
        return []
    if hasattr(mapping, "model_dump"):
        mapping = mapping.model_dump(exclude_none=True)
    out = []
    for name, val in dict(mapping).items():
        if val is None:
            continue
        if isinstance(val, (list, tuple)):
            out.extend(Effect(name, dict(v)) for v in val)
        else:
            out.append(Effect(name, dict(val)))
    return out
