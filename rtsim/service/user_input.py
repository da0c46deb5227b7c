"""The user's command source: a person driving the served vehicle from `rtsim view` (keyboard, gamepad,
steering wheel), through the service's Zenoh ``drive`` control op.

The user drives a fixed set of channels per vehicle kind (SI units, ISO 8855 signs):

- a car: ``throttle_angle_cmd`` (rad), ``brake_pressure_cmd`` (kPa), ``steering_wheel_angle_cmd`` (rad,
  positive steering left): the same channels as its ECU's commands;
- a two-wheeler: ``throttle_cmd`` (1), ``brake_pressure_front_cmd`` and ``brake_pressure_rear_cmd`` (kPa)
  and ``roll_angle_demand`` (rad, positive leaning right). A person cannot balance a motorcycle through
  a keyboard's steering torque, so the user asks for a lean angle and a lean loop in the step
  (drivers.lean_demand, the rider's roll-loop gains) turns it into the handlebar torque, as a rider
  balancing by counter-steering would.

Priority, applied inside the compiled step after the watchdog (rtsim.service.vehicles.vehicle_user): a
user channel replaces the in-loop driver's (the scenario's driver, the rider) always, and the bus ECU's
command only where the bus has no valid command (never received or timed out) or while the user has
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

#: the shipped kinds' user channels, (lo, hi, unit, meaning) in slot order: every name the drive op may
#: carry (rtsim.service.control_args). A served vehicle's own: its sim's ``user_inputs``.
USER_CHANNELS: dict[str, dict[str, tuple[float, float, str, str]]] = {
    "car": CAR_USER.table(), "two_wheeler": TWO_WHEELER_USER.table()}


def user_channels(kind: str) -> dict[str, tuple[float, float, str, str]]:
    """(Kept for callers that know only the kind; the loop reads the served vehicle's ``user_inputs``.)"""
    return USER_CHANNELS[kind]


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
