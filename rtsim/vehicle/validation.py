"""What the validation workflow (rtsim.validate) needs to know of a kind of vehicle: its validation
profile. Each VehicleKind provides one (``VehicleKind.validation``); the workflow takes it from
``open_vehicle(path).validation`` and passes it on, so a new kind of vehicle brings its own profile and
needs no change in the workflow.

The profile is data: the channels the replay follows (never compared), the channels compared by
default, the least range that makes an input count as varying (the alignment's test, SI units, peak to
peak), the vehicle's effect catalogue (name -> EffectSpec), its sensor channels (the runs' columns the
workflow reads), the replayer that re-simulates the vehicle and the report's line on the manoeuvre. The
replayer lives with the workflow, a layer above the vehicle, so the profile names it (``module:Class``)
and the workflow imports it; the vehicle never imports the workflow.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable


@dataclass(frozen=True)
class Relation:
    """A model-free relation between measured channels (rtsim.validate.redundancy): `channel` reads a
    multiple of `reference(channels)` plus a constant plus multiples of `offsets(channels)`, whatever the
    vehicle's dynamics do. `needs`: the channels the reference and offsets read; `says`: what the
    reference is, in words for the report; `checks`: the sensor effects of the catalogue it checks
    ("sensor_delay": the lag; "sensor_scale": the gain, only where the relation's coefficient does not
    depend on the vehicle's structure)."""
    channel: str
    needs: tuple[str, ...]
    reference: Callable[[dict], object]
    offsets: Callable[[dict], list]
    says: str
    checks: tuple[str, ...] = ("sensor_delay",)


@dataclass(frozen=True)
class ValidationProfile:
    inputs: tuple[str, ...]                   # the channels the replay follows (never compared)
    compared: tuple[str, ...] | None          # default compared channels (None: the benchmark's rule,
                                              # longitudinal channels and the lateral ones when it steers)
    min_range: dict = field(default_factory=dict)   # input -> least range (peak to peak, SI) that counts
                                              # as varying (alignment)
    effects: dict = field(default_factory=dict)     # the effect catalogue: name -> EffectSpec
    replayer: str = ""                        # "module:Class" of the replayer, built as
                                              # Class(vehicle, road, dt, fit_dt)
    sensor_names: tuple[str, ...] = ()        # the vehicle's sensor channels (its channel dictionary)
    #: the report's description of the manoeuvre ("{compared}": the compared channels); "" when the
    #: benchmark's own (longitudinal, or lateral when the runs steer) describes it
    manoeuvre: str = ""
    #: model-free relations that check a sensor's gain and lag (rtsim.validate.redundancy)
    relations: tuple[Relation, ...] = ()
    #: pairs of channels tied kinematically, so that a gain of the vehicle's own response (not in the
    #: catalogue) shows on both alike: a scale of one is named only when it predicts left-out runs better
    #: than a common gain of the pair (rtsim.validate.identify.kinematic_gain_check)
    gain_pairs: tuple[tuple[str, str], ...] = ()
    #: pairs of channels whose scales are identified only relative to each other (a car's two wheel angles
    #: on an axle, whose rolling radius the nuisance adjustments re-fit): a scale of one is not a candidate
    #: once the other carries one (rtsim.validate.identify.ratio_partner)
    ratio_pairs: tuple[tuple[str, str], ...] = ()
