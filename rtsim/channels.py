"""The channel dictionary: every signal's name, SI unit and meaning, used alike by the vehicle model,
the DBC, MCAP schemas, Zenoh payloads, CSV exports and the validation workflow.

Axes and signs follow ISO 8855 throughout: x forward, y left, z up; positive yaw rate turns left;
positive steer angle steers left; wheel order fl, fr, rl, rr.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Channel:
    name: str
    unit: str
    description: str


def _ch(name, unit, description):
    return Channel(name, unit, description)


WHEELS = ("fl", "fr", "rl", "rr")

#: Sensor channels (the seed's Table 1), sampled at 500 Hz.
SENSORS: tuple[Channel, ...] = (
    _ch("accel_x", "m/s^2", "specific force at the sensor mounting point, body x"),
    _ch("accel_y", "m/s^2", "specific force at the sensor mounting point, body y"),
    _ch("accel_z", "m/s^2", "specific force at the sensor mounting point, body z"),
    _ch("gyro_x", "rad/s", "body angular rate about x (roll rate)"),
    _ch("gyro_y", "rad/s", "body angular rate about y (pitch rate)"),
    _ch("gyro_z", "rad/s", "body angular rate about z (yaw rate, positive turning left)"),
    _ch("roll", "rad", "inclinometer roll angle, positive right side down"),
    _ch("pitch", "rad", "inclinometer pitch angle, positive nose down"),
    *(_ch(f"wheel_angle_{w}", "rad", f"cumulative rotation angle of wheel {w}, positive rolling forward")
      for w in WHEELS),
    _ch("brake_pressure", "kPa", "brake line pressure"),
    _ch("steering_wheel_angle", "rad", "steering-wheel angle, positive steering left"),
    _ch("steer_angle_fl", "rad", "road-wheel steer angle front left, positive left"),
    _ch("steer_angle_fr", "rad", "road-wheel steer angle front right, positive left"),
    _ch("engine_speed", "rad/s", "engine crankshaft speed"),
    _ch("steering_torque", "N*m", "inline torque sensor on the steering column (torsion bar)"),
    _ch("throttle_angle", "rad", "throttle plate angle"),
    _ch("wheel_torque_rl", "N*m", "drive/brake torque measured at the rear-left wheel"),
    _ch("wheel_torque_rr", "N*m", "drive/brake torque measured at the rear-right wheel"),
)

#: Actuator commands from the ECU.
COMMANDS: tuple[Channel, ...] = (
    _ch("throttle_angle_cmd", "rad", "commanded throttle angle"),
    _ch("brake_pressure_cmd", "kPa", "commanded brake line pressure"),
    _ch("steering_wheel_angle_cmd", "rad", "commanded steering-wheel angle"),
)

SENSOR_NAMES = tuple(c.name for c in SENSORS)
COMMAND_NAMES = tuple(c.name for c in COMMANDS)
BY_NAME = {c.name: c for c in SENSORS + COMMANDS}
