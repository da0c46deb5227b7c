"""The car's driving inputs: the ranges of its input channels (what a driver, a replay or a person may
command, SI) and its user channels (rtsim.vehicle.kit.user_inputs)."""
from __future__ import annotations

import math

from ..kit.user_inputs import UserChannel, UserInputs

#: input channel -> (lo, hi), SI: rad, kPa, rad, N m, N m
LIMITS: dict[str, tuple[float, float]] = {
    "throttle_angle_cmd": (0.0, 0.5 * math.pi),
    "brake_pressure_cmd": (0.0, 20000.0),
    "steering_wheel_angle_cmd": (-4.0 * math.pi, 4.0 * math.pi),
    "wheel_torque_rl": (-5000.0, 5000.0),
    "wheel_torque_rr": (-5000.0, 5000.0),
}


def user_inputs(throttle_max: float = 1.4, brake_max: float = 12000.0) -> UserInputs:
    """A car's user channels: the ECU's own commands, the user's value written into the command slot.
    Full scales: the throttle's wide-open angle, 60 % of the brake actuator's maximum, 3 rad at the
    steering wheel."""
    def ch(name, unit, meaning, full):
        return UserChannel(name, *LIMITS[name], unit, meaning, full, name)
    return UserInputs((ch("throttle_angle_cmd", "rad", "throttle plate angle", throttle_max),
                       ch("brake_pressure_cmd", "kPa", "brake line pressure", 0.6 * brake_max),
                       ch("steering_wheel_angle_cmd", "rad", "steering-wheel angle, positive steering left", 3.0)),
                      writes="command", in_loop="scenario", idle="safe")


USER_INPUTS = user_inputs()       # with the default actuator limits (a vehicle's own: CarKind.user_inputs)
