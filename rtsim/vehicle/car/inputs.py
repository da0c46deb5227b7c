"""The car's driving inputs: the layouts a driver reads and writes (``DriverView``: the driver's view of the car;
``I_*``: its outputs, the car's input channels; declared here once, drivers.base names them for the
drivers), the ranges of its input channels (what a driver, a replay or a person may command, SI) and
what a person may drive of it (rtsim.vehicle.kit.user_inputs).

The person drives the ECU's own commands, the value written into the command slot. The pedals are one
group (either key takes the throttle and the brake, so a car nobody else drives is not held by the
watchdog's brake while the user accelerates): full throttle the plate's wide-open angle from
[powertrain.throttle], full brake 60 % of the brake actuator's maximum (a key cannot modulate: full
pressure locks the wheels). The steering is 3 rad of steering-wheel angle at full steer (about 170
degrees: a parking manoeuvre's lock), positive steering left (ISO 8855), so a right key is negative.
Released, both groups hold their rest values: the car coasts straight on."""
from __future__ import annotations

import math
from enum import IntEnum

from rtsim.channels import COMMAND_NAMES

from ..kit.user_inputs import ControlGroup, UserChannel, UserInputs

# --- the driver's view of the car: the state a closed-loop driver reads (drivers.base), ISO 8855 --------


class DriverView(IntEnum):
    """The driver's view of the car (the state array a closed-loop driver reads), ISO 8855."""
    SPEED = 0   # m/s, longitudinal speed of the reference point (forward positive)
    X = 1       # m, position x in the road frame
    Y = 2       # m, position y in the road frame
    YAW = 3     # rad, yaw angle from the road x axis, positive turning left


NSTATE = len(DriverView)   # slots in the driver's view
STATE_NAMES = ("speed", "x", "y", "yaw")

# --- the driver's outputs: one float per input channel of the car, in the order of INPUT_NAMES ---------
I_THROTTLE = 0
I_BRAKE = 1
I_STEER = 2
I_TORQUE_RL = 3
I_TORQUE_RR = 4
NINPUT = 5
INPUT_NAMES: tuple[str, ...] = (*COMMAND_NAMES, "wheel_torque_rl", "wheel_torque_rr")

#: input channel -> (lo, hi), SI: rad, kPa, rad, N m, N m
LIMITS: dict[str, tuple[float, float]] = {
    "throttle_angle_cmd": (0.0, 0.5 * math.pi),
    "brake_pressure_cmd": (0.0, 20000.0),
    "steering_wheel_angle_cmd": (-4.0 * math.pi, 4.0 * math.pi),
    "wheel_torque_rl": (-5000.0, 5000.0),
    "wheel_torque_rr": (-5000.0, 5000.0),
}
BRAKE_FRACTION = 0.6           # of the actuator's maximum pressure at full brake
STEERING_WHEEL_FULL_RAD = 3.0  # steering-wheel angle at full steer


def user_inputs(throttle_max: float = 1.4, brake_max: float = 12000.0) -> UserInputs:
    """A car's user channels (module docstring); ``throttle_max`` (rad) the wide-open plate angle,
    ``brake_max`` (kPa) the brake actuator's maximum."""
    def ch(name, unit, meaning, control, full, sign=1.0):
        return UserChannel(name, *LIMITS[name], unit, meaning, full, bus=name, control=control, sign=sign)
    return UserInputs(
        (ch("throttle_angle_cmd", "rad", "throttle plate angle", "throttle", throttle_max),
         ch("brake_pressure_cmd", "kPa", "brake line pressure", "brake", BRAKE_FRACTION * brake_max),
         ch("steering_wheel_angle_cmd", "rad", "steering-wheel angle, positive steering left", "steer",
            STEERING_WHEEL_FULL_RAD, sign=-1.0)),
        (ControlGroup("pedals", "hold", ("throttle_angle_cmd", "brake_pressure_cmd")),
         ControlGroup("steering", "hold", ("steering_wheel_angle_cmd",))),
        writes="command", in_loop="scenario", idle="safe", plots=("speed", "yaw_rate", "steering_wheel_angle"))


USER_INPUTS = user_inputs()       # with the default actuator limits (a vehicle's own: CarKind.user_inputs)
