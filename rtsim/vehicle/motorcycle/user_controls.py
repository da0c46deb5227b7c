"""A two-wheeler's controls in `rtsim view` (rtsim.vehicle.kit.user_controls).

- throttle: 40 % at full key (``THROTTLE_FULL``): wide open lifts the front wheel of a sport motorcycle
  in the low gears, and a key cannot modulate it; released, the throttle is handed back (the rider in
  the loop holds its speed again; with no rider the service closes it);
- brakes: both calipers on the brake key, for ``BRAKE_DECEL_G`` (0.5 g) of deceleration at full key, the
  front brake taking ``BRAKE_FRONT_SHARE`` of it (the load transfer puts most of the grip there): each
  caliper's pressure from its torque per pressure and its wheel's radius, at most the caliper limit.
  A key cannot modulate, and a step to the 1 g the calipers can give locks the front wheel and the
  motorcycle falls; handed back when released;
- steer: the lean demand (``roll_angle_demand``, the lean loop in the step turns it into handlebar
  torque: nobody balances a motorcycle through a key's steering torque), 30 degrees at full key, right
  key leaning right; held when released (upright: the user steers from the first lean key on).
"""
from __future__ import annotations

import math

from ..kit.user_controls import channel, group, view_description

THROTTLE_FULL = 0.4                 # of wide open, at full throttle key
BRAKE_DECEL_G = 0.5                 # deceleration (in g) at full brake key, upright on a flat road
BRAKE_FRONT_SHARE = 0.8             # of the braking force, on the front wheel
G = 9.81                            # m/s^2, to turn BRAKE_DECEL_G into a force
LEAN_FULL_RAD = math.radians(30.0)  # lean demand at full steer key
DEFAULT_MAX_PRESSURE_KPA = 12000.0  # a vehicle without [brakes]: the user channel's scale only


def user_controls(cfg) -> dict:
    """The view description of a two-wheeler (cfg: rtsim.vehicle.motorcycle.config.MotorcycleConfig)."""
    b = cfg.brakes
    if b is None:                       # no brakes fitted: the channels exist, the pressures act on nothing
        front = rear = DEFAULT_MAX_PRESSURE_KPA
    else:
        force = BRAKE_DECEL_G * G * total_mass_kg(cfg)
        front = min(b.max_pressure_kpa, BRAKE_FRONT_SHARE * force * cfg.front_wheel.radius_m / b.front_nm_per_kpa)
        rear = min(b.max_pressure_kpa, (1 - BRAKE_FRONT_SHARE) * force * cfg.rear_wheel.radius_m / b.rear_nm_per_kpa)
    return view_description([
        group("throttle", "hand_back", channel("throttle_cmd", "throttle", THROTTLE_FULL)),
        group("brakes", "hand_back", channel("brake_pressure_front_cmd", "brake", front),
              channel("brake_pressure_rear_cmd", "brake", rear)),
        group("lean", "hold", channel("roll_angle_demand", "steer", LEAN_FULL_RAD)),
    ], plots=["speed", "roll_angle", "steer_angle"])


def total_mass_kg(cfg) -> float:
    """The two-wheeler's mass with its rider (kg): every body of the config."""
    bodies = (cfg.rear_frame, cfg.rider, cfg.swingarm, cfg.upper_fork, cfg.lower_fork, cfg.front_wheel,
              cfg.rear_wheel)
    return sum(b.mass_kg for b in bodies if b is not None)
