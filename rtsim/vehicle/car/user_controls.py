"""The car's controls in `rtsim view` (rtsim.vehicle.kit.user_controls): the pedals as one group (either
key takes the throttle and the brake, so a car nobody else drives is not held by the watchdog's brake
while the user accelerates), full throttle the plate's wide-open angle from [powertrain.throttle],
full brake 60 % of the brake actuator's maximum (a key cannot modulate: full pressure locks the wheels);
the steering 3 rad of steering-wheel angle at full steer (about 170 degrees: a parking manoeuvre's
lock), positive steering left (ISO 8855), so a right key is negative. Released, both groups hold their
rest values: the car coasts straight on."""
from __future__ import annotations

from ..kit.user_controls import channel, group, view_description

BRAKE_FRACTION = 0.6           # of the actuator's maximum pressure at full brake
STEERING_WHEEL_FULL_RAD = 3.0  # steering-wheel angle at full steer


def user_controls(cfg) -> dict:
    """The view description of a car (cfg: rtsim.vehicle.car.config.VehicleConfig)."""
    return view_description([
        group("pedals", "hold",
              channel("throttle_angle_cmd", "throttle", cfg.powertrain.throttle.max),
              channel("brake_pressure_cmd", "brake", BRAKE_FRACTION * cfg.brakes.actuator.max)),
        group("steering", "hold",
              channel("steering_wheel_angle_cmd", "steer", STEERING_WHEEL_FULL_RAD, sign=-1.0)),
    ], plots=["speed", "yaw_rate", "steering_wheel_angle"])
