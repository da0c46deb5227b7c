"""Which vehicle the workflow validates: the vehicle file's ``kind`` chooses the replay's input channels,
the compared channels, the effect catalogue and the replayer (the car's, or the two-wheeler's).

The workflow activates the profile of its vehicle once per run (`activate`) before it loads the data;
the benchmark, the alignment, the effect catalogue, the report and the config writer then read the
active profile (`active`); it stays active after the run until another run activates its own. Worker
processes forked by the workflow inherit it; a two-wheeler replayer shipped to another process
activates its profile when it is unpickled.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from rtsim.errors import ConfigError


@dataclass(frozen=True)
class Profile:
    kind: str                                  # "car" or "two_wheeler"
    inputs: tuple[str, ...]                    # the channels the replay follows (never compared)
    compared: tuple[str, ...] | None           # default compared channels (None: the car's own rule)
    min_range: dict = field(default_factory=dict)   # input -> least range (peak to peak, SI) that counts as
                                               # varying (alignment)


CAR = Profile("car", ("brake_pressure", "wheel_torque_rl", "wheel_torque_rr", "throttle_angle",
                      "steering_wheel_angle"), None,
              {"brake_pressure": 10.0, "wheel_torque_rl": 2.0, "wheel_torque_rr": 2.0, "throttle_angle": 0.005,
               "steering_wheel_angle": 0.005})

#: The two-wheeler (rtsim.validate.replay_two_wheeler): the replay follows the recorded roll through a
#: lean loop and the recorded actuator outputs (throttle opening, caliper pressures); the rest is compared.
TWO_WHEELER = Profile(
    "two_wheeler", ("roll", "throttle", "brake_pressure_front", "brake_pressure_rear"),
    ("wheel_speed_front", "wheel_speed_rear", "accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z",
     "pitch", "steer_angle", "steering_torque", "fork_travel", "shock_travel"),
    {"roll": 0.01, "throttle": 0.01, "brake_pressure_front": 10.0, "brake_pressure_rear": 10.0})

PROFILES = {p.kind: p for p in (CAR, TWO_WHEELER)}
_ACTIVE = [CAR]


def vehicle_kind(vehicle: str | Path) -> str:
    """The vehicle file's ``kind`` (a car when it has none)."""
    path = Path(vehicle)
    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the vehicle file ({exc})") from None
    kind = data.get("kind", "car")
    if kind not in PROFILES:
        raise ConfigError(f"{path}: kind = {kind!r}: the validation workflow handles {', '.join(PROFILES)}")
    return kind


def activate(kind: str) -> Profile:
    _ACTIVE[0] = PROFILES[kind]
    return _ACTIVE[0]


def active() -> Profile:
    return _ACTIVE[0]
