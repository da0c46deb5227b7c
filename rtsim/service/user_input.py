"""The user's command source: a person driving the served vehicle from `rtsim view` (keyboard, gamepad,
steering wheel), through the service's Zenoh ``drive`` control op.

The user drives the channels the served vehicle declares (its ``user_inputs``,
rtsim.vehicle.kit.user_inputs: a car's own ECU commands; a two-wheeler's throttle, caliper pressures and
a lean demand that a lean loop in the step, rtsim.vehicle.motorcycle.lean_demand, turns into handlebar torque), SI units,
ISO 8855 signs.

Priority, applied inside the compiled step after the watchdog (rtsim.service.vehicles.vehicle_user, then
the vehicle's ``served_user``): a user channel replaces the in-loop driver's (the scenario's driver, the
rider) always, and the bus ECU's command only where the bus has no valid command (never received or timed out) or while the user has
taken over (``takeover``: then a two-wheeler's assist torque is ignored too). A user channel is held
until the next request; ``null`` hands it back; every channel lapses ``USER_HOLD`` s of wall time after
the last request (a page that went away stops driving).
"""
from __future__ import annotations

import math

from rtsim.vehicle.car.inputs import USER_INPUTS as CAR_USER
from rtsim.vehicle.motorcycle.inputs import USER_INPUTS as TWO_WHEELER_USER

NUSR = 4                 # user channels per vehicle (the car uses the first three)
NWORK = 3                # lean loop state: on, rate-limited reference (rad), integral (N m)
USER_HOLD = 1.0          # s of wall time a user command is held without a new request

#: the shipped vehicles' user channel names: every name the drive op may carry (rtsim.service.control_args;
#: the handler checks the served vehicle's own, its sim's ``user_inputs``)
USER_CHANNEL_NAMES: tuple[str, ...] = tuple(dict.fromkeys(CAR_USER.names + TWO_WHEELER_USER.names))


def check_value(inputs, name: str, value) -> float:
    """A user command's value as a float within its range (``inputs``: the vehicle's UserInputs);
    ValueError naming channel, value and range."""
    chans = inputs.table()
    if name not in chans:
        raise ValueError(f"{name!r} is not a user channel of this vehicle (those are: {', '.join(chans)})")
    lo, hi, unit, _ = chans[name]
    if isinstance(value, bool):
        raise ValueError(f"{name} = {value!r} is not a number")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} = {value!r} is not a number") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ValueError(f"{name} = {v}: outside {lo:g} .. {hi:g} {unit}")
    return v
