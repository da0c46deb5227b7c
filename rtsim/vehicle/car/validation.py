"""The car's validation profile (rtsim.vehicle.validation): the replay follows the measured rear-wheel
torques, brake line pressure, throttle angle and steering-wheel angle (rtsim.validate.replay); the
compared channels follow the benchmark's rule (longitudinal, and lateral when the runs steer); the
effect catalogue is rtsim.vehicle.car.effects."""
from __future__ import annotations

from dataclasses import replace

from ..validation import Relation, ValidationProfile
from .effects import EFFECTS

REAR = ("wheel_speed_rl", "wheel_speed_rr")


def _yaw_from_wheels(c: dict):
    """The rear axle's wheel speed difference (rad/s): the yaw rate times the rear track over the rolling
    radius (ISO 8855: the right wheel is the outer one in a left, positive, turn)."""
    return c["wheel_speed_rr"] - c["wheel_speed_rl"]


def _axle_speed(c: dict) -> list:
    """An axle's rolling-radius difference reads as a yaw rate proportional to speed."""
    return [c["wheel_speed_rr"] + c["wheel_speed_rl"]]


#: the yaw rate gyro's lag checked against the rear wheel speeds. Its gain is not: a wheel's rolling radius
#: changes with its load, which moves with the lateral acceleration, so the wheels' yaw gain differs from car
#: to car by a few per cent (1.04 to 1.08 between independent simulators and this model with no gyro effect);
#: nor is the lateral accelerometer against speed times yaw rate: the sideslip rate's share of the reading
#: moves its apparent lag by more than the delays to be found
RELATIONS = (
    Relation("gyro_z", REAR, _yaw_from_wheels, _axle_speed, "the yaw rate from the rear wheel speeds",
             checks=("sensor_delay",)),
)

PROFILE = ValidationProfile(
    inputs=("brake_pressure", "wheel_torque_rl", "wheel_torque_rr", "throttle_angle", "steering_wheel_angle"),
    compared=None,
    min_range={"brake_pressure": 10.0, "wheel_torque_rl": 2.0, "wheel_torque_rr": 2.0, "throttle_angle": 0.005,
               "steering_wheel_angle": 0.005},
    effects=EFFECTS,
    replayer="rtsim.validate.replay:Replayer",
    relations=RELATIONS,
    # a_y = v r + dv_y/dt (v r in steady cornering): a car that yaws more than the model reads higher on both
    gain_pairs=(("gyro_z", "accel_y"),),
    # an axle's two wheel angles: the axle's rolling radius (a nuisance adjustment) scales both alike
    ratio_pairs=(("wheel_angle_fl", "wheel_angle_fr"), ("wheel_angle_rl", "wheel_angle_rr")))


def profile(config) -> ValidationProfile:
    """The profile of a car config: its own sensor channels (the EPS's when it has one)."""
    from .build import vehicle_channels

    return replace(PROFILE, sensor_names=tuple(vehicle_channels(config).sensor_names))
