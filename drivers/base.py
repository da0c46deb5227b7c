"""What every driver shares: the layout of its inputs (the vehicle state it may read) and of its outputs
(the command channels it writes), the sensor names a recording may use for them, and their ranges.

Outputs. A driver writes one float per *input channel* of the vehicle, in this order (`INPUT_NAMES`):

    0 throttle_angle_cmd        rad   commanded throttle plate angle
    1 brake_pressure_cmd        kPa   commanded brake line pressure
    2 steering_wheel_angle_cmd  rad   commanded steering-wheel angle, positive steering left (ISO 8855)
    3 wheel_torque_rl           N*m   rear-left wheel drive torque (torque mode only)
    4 wheel_torque_rr           N*m   rear-right wheel drive torque (torque mode only)

The first three are the ECU's actuator commands (`rtsim.channels.COMMAND_NAMES`). The last two are used
only in *torque mode*, the seed validation's way of driving the model: the measured rear wheel torques
replace the engine (the throttle is then unused).

Inputs. Closed-loop drivers read the vehicle state as a float array laid out as `DriverView` (ISO 8855
axes: x forward, y left, yaw positive turning left, from the x axis). The vehicle model fills it each
step; tests fill it from their own simple models. Position and yaw are those of the vehicle reference
point the vehicle model reports; the path follower takes the offset to the rear axle as a parameter.

Both layouts are the car's and are declared by it (rtsim.vehicle.car.inputs: the vehicle never imports
its drivers); this module names them for the drivers.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import rtsim.jit
from rtsim.channels import BY_NAME

# the layouts of the vehicle state a closed-loop driver reads (DriverView) and of its outputs (I_*): the car's,
# declared by the vehicle (rtsim.vehicle.car.inputs)
from rtsim.vehicle.car.inputs import (I_BRAKE, I_STEER, I_THROTTLE, I_TORQUE_RL, I_TORQUE_RR,  # noqa: F401
                                      INPUT_NAMES, NINPUT, NSTATE, DriverView, STATE_NAMES)

INPUT_INDEX = {name: i for i, name in enumerate(INPUT_NAMES)}
INPUT_UNITS = {name: BY_NAME[name].unit for name in INPUT_NAMES}
TORQUE_NAMES = INPUT_NAMES[3:]

#: A recording may name a command channel by the sensor that measures it (the seed's data files do).
SENSOR_ALIASES = {
    "throttle_angle": "throttle_angle_cmd",
    "brake_pressure": "brake_pressure_cmd",
    "steering_wheel_angle": "steering_wheel_angle_cmd",
}

#: Allowed value range of each input channel (inclusive), used to validate profiles and recordings.
#: Throttle: a plate angle from closed to fully open. Brake: up to 20 MPa, beyond any passenger car's
#: line pressure. Steering wheel: two turns each way. Wheel torque: +-5 kN*m per wheel.
from rtsim.vehicle.car.inputs import LIMITS  # noqa: E402  (the car's input ranges, declared by the vehicle)


def input_name(column: str) -> str | None:
    """The input channel a recording column feeds (its own name or a sensor alias), or None."""
    if column in INPUT_INDEX:
        return column
    return SENSOR_ALIASES.get(column)


def _drop_stale_kernel_cache() -> None:
    """numba's on-disk cache keys a kernel on its own file only, but the kernels here use constants
    from this module and call kernels of sibling modules (driver_step links the profile and follower
    kernels into its cached code). Drop the package's cache whenever any of its sources changed, before
    any kernel is loaded (every kernel module imports this one first)."""
    here = Path(__file__).resolve().parent
    cache = here / "__pycache__"
    try:
        sources = sorted(here.glob("*.py")) + [Path(rtsim.jit.__file__)]
        digest = hashlib.sha256(b"".join(f.read_bytes() for f in sources)).hexdigest()
        stamp = cache / "kernel-sources.sha256"
        if stamp.is_file() and stamp.read_text() == digest:
            return
        for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            f.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        stamp.write_text(digest)
    except OSError:  # read-only install: numba then compiles in memory or uses what is there
        pass


_drop_stale_kernel_cache()
