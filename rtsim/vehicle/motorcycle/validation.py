"""The two-wheeler's validation profile (rtsim.vehicle.validation): the replay
(rtsim.validate.replay_two_wheeler) follows the recorded roll through a lean loop and the recorded
actuator outputs (throttle opening, caliper pressures); the rest is compared; the effect catalogue is
rtsim.vehicle.motorcycle.effects."""
from __future__ import annotations

from rtsim.channels import TWO_WHEELER_SENSORS

from ..validation import ValidationProfile
from .effects import EFFECTS

PROFILE = ValidationProfile(
    inputs=("roll", "throttle", "brake_pressure_front", "brake_pressure_rear"),
    compared=("wheel_speed_front", "wheel_speed_rear", "accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y",
              "gyro_z", "pitch", "steer_angle", "steering_torque", "fork_travel", "shock_travel"),
    min_range={"roll": 0.01, "throttle": 0.01, "brake_pressure_front": 10.0, "brake_pressure_rear": 10.0},
    effects=EFFECTS,
    replayer="rtsim.validate.replay_two_wheeler:TwoWheelerReplayer",
    sensor_names=tuple(c.name for c in TWO_WHEELER_SENSORS),
    manoeuvre="two-wheeler (the recorded roll followed; compared: {compared})")
