"""What a person may drive of a two-wheeler (rtsim.vehicle.kit.user_inputs). Throttle and brakes replace
the rider's outputs; the steer key asks for a lean angle, to which the ECU's assist torque adds.

- throttle: 40 % at full key (``THROTTLE_FULL``): wide open lifts the front wheel of a sport motorcycle
  in the low gears, and a key cannot modulate it; released, the throttle is handed back (the rider in
  the loop holds its speed again; with no rider the service closes it);
- brakes: both calipers on the brake key, for ``BRAKE_DECEL_G`` (0.5 g) of deceleration at full key, the
  front brake taking ``BRAKE_FRONT_SHARE`` of it (the load transfer puts most of the grip there): each
  caliper's pressure from its torque per pressure and its wheel's radius, at most the caliper limit.
  A key cannot modulate, and a step to the 1 g the calipers can give locks the front wheel and the
  motorcycle falls; handed back when released;
- steer: the lean demand (``roll_angle_demand``): nobody balances a motorcycle through a key's steering
  torque, so a lean loop in the step (the rider's roll-loop gains) turns it into the handlebar torque, as
  a rider balancing by counter-steering would; 30 degrees at full key, right key leaning right; held when
  released (upright: the user steers from the first lean key on).
"""
from __future__ import annotations

import math

from rtsim.mbs.model import EARTH_GRAVITY

from ..kit.user_inputs import ControlGroup, UserChannel, UserInputs

THROTTLE_FULL = 0.4                 # of wide open, at full throttle key
BRAKE_DECEL_G = 0.5                 # deceleration (in g) at full brake key, upright on a flat road
BRAKE_FRONT_SHARE = 0.8             # of the braking force, on the front wheel
LEAN_FULL_RAD = math.radians(30.0)  # lean demand at full steer key
LEAN_MAX_RAD = math.radians(60.0)   # the lean demand's range
PRESSURE_MAX_KPA = 20000.0          # the caliper pressures' range
DEFAULT_MAX_PRESSURE_KPA = 12000.0  # a vehicle without [brakes]: the user channel's scale only


def user_inputs(cfg=None) -> UserInputs:
    """A two-wheeler's user channels (module docstring); cfg: its rtsim.vehicle.motorcycle.config
    MotorcycleConfig (None, or no [brakes]: the channels exist, the pressures act on nothing)."""
    b = cfg.brakes if cfg is not None else None
    if b is None:
        front = rear = DEFAULT_MAX_PRESSURE_KPA
    else:
        force = BRAKE_DECEL_G * EARTH_GRAVITY * total_mass_kg(cfg)
        front = min(b.max_pressure_kpa, BRAKE_FRONT_SHARE * force * cfg.front_wheel.radius_m / b.front_nm_per_kpa)
        rear = min(b.max_pressure_kpa, (1 - BRAKE_FRONT_SHARE) * force * cfg.rear_wheel.radius_m / b.rear_nm_per_kpa)
    return UserInputs((
        UserChannel("throttle_cmd", 0.0, 1.0, "1", "throttle, 0 closed .. 1 wide open", THROTTLE_FULL,
                    bus="throttle_cmd", control="throttle"),
        UserChannel("brake_pressure_front_cmd", 0.0, PRESSURE_MAX_KPA, "kPa", "front caliper pressure", front,
                    bus="brake_pressure_front_cmd", control="brake"),
        UserChannel("brake_pressure_rear_cmd", 0.0, PRESSURE_MAX_KPA, "kPa", "rear caliper pressure", rear,
                    bus="brake_pressure_rear_cmd", control="brake"),
        UserChannel("roll_angle_demand", -LEAN_MAX_RAD, LEAN_MAX_RAD, "rad",
                    "lean angle asked of the lean loop, positive leaning right", LEAN_FULL_RAD,
                    bus="assist_torque_cmd", control="steer", adds_to_bus=True)),
        (ControlGroup("throttle", "hand_back", ("throttle_cmd",)),
         ControlGroup("brakes", "hand_back", ("brake_pressure_front_cmd", "brake_pressure_rear_cmd")),
         ControlGroup("lean", "hold", ("roll_angle_demand",))),
        writes="in_loop", in_loop="rider", idle="none", plots=("speed", "roll_angle", "steer_angle"))


def total_mass_kg(cfg) -> float:
    """The two-wheeler's mass with its rider (kg): every body of the config."""
    bodies = (cfg.rear_frame, cfg.rider, cfg.swingarm, cfg.upper_fork, cfg.lower_fork, cfg.front_wheel,
              cfg.rear_wheel)
    return sum(b.mass_kg for b in bodies if b is not None)


#: the channels as a two-wheeler without brakes declares them (names, ranges, buses: what the service's
#: loop needs of a sim built outside its kind); a vehicle's own: TwoWheelerKind.user_inputs
USER_INPUTS = user_inputs()
