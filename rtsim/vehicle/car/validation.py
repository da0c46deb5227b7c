"""The car's validation profile (rtsim.vehicle.validation): the replay follows the measured rear-wheel
torques, brake line pressure, throttle angle and steering-wheel angle (rtsim.validate.replay); the
compared channels follow the benchmark's rule (longitudinal, and lateral when the runs steer); the
effect catalogue is rtsim.vehicle.car.effects."""
from __future__ import annotations

from dataclasses import replace

from ..validation import ValidationProfile
from .effects import EFFECTS

PROFILE = ValidationProfile(
    inputs=("brake_pressure", "wheel_torque_rl", "wheel_torque_rr", "throttle_angle", "steering_wheel_angle"),
    compared=None,
    min_range={"brake_pressure": 10.0, "wheel_torque_rl": 2.0, "wheel_torque_rr": 2.0, "throttle_angle": 0.005,
               "steering_wheel_angle": 0.005},
    effects=EFFECTS,
    replayer="rtsim.validate.replay:Replayer")


def profile(config) -> ValidationProfile:
    """The profile of a car config: its own sensor channels (the EPS's when it has one)."""
    from .build import vehicle_channels

    return replace(PROFILE, sensor_names=tuple(vehicle_channels(config).sensor_names))
