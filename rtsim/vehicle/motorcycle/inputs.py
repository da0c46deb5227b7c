"""The two-wheeler's user channels (rtsim.vehicle.kit.user_inputs). A person cannot balance a motorcycle
through a keyboard's steering torque, so the user asks for a lean angle and a lean loop in the step (the
rider's roll-loop gains) turns it into the handlebar torque, as a rider balancing by counter-steering
would; the ECU's assist torque adds to it. Throttle and brakes replace the rider's outputs."""
from __future__ import annotations

import math

from ..kit.user_inputs import UserChannel, UserInputs


def user_inputs(max_pressure_kpa: float = 12000.0) -> UserInputs:
    """Full scales: 40 % throttle (wide open lifts the front wheel of a sport motorcycle in the low gears: a
    person with a key cannot modulate it), 60 % / 30 % of the caliper limit front / rear, 30 deg of lean."""
    return UserInputs((
        UserChannel("throttle_cmd", 0.0, 1.0, "1", "throttle, 0 closed .. 1 wide open", 0.4, "throttle_cmd"),
        UserChannel("brake_pressure_front_cmd", 0.0, 20000.0, "kPa", "front caliper pressure",
                    0.6 * max_pressure_kpa, "brake_pressure_front_cmd"),
        UserChannel("brake_pressure_rear_cmd", 0.0, 20000.0, "kPa", "rear caliper pressure",
                    0.3 * max_pressure_kpa, "brake_pressure_rear_cmd"),
        UserChannel("roll_angle_demand", -math.radians(60.0), math.radians(60.0), "rad",
                    "lean angle asked of the lean loop, positive leaning right", math.radians(30.0),
                    "assist_torque_cmd", adds_to_bus=True)),
        writes="in_loop", in_loop="rider", idle="none")


USER_INPUTS = user_inputs()       # with the default caliper limit (a vehicle's own: TwoWheelerKind.user_inputs)
