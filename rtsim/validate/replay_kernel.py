"""A replay's grid loop in one compiled call (rtsim.validate.replay.Replayer._run): per interval of the
comparison grid the inputs held at the interval's mean value (the average of the grid values at both
ends; pressure and throttle not below 0), `sub` model steps (vehicle_advance), then the physical sensor
values at the grid time (physical_sensors). The same kernels with the same numbers in the same order as
the Python loop it replaces, so the replay is the same bit for bit; what that loop spent between the
steps (two kernel dispatches per grid interval, about a fifth of a replay at the fitting step) is gone.
An input the replay does not drive is an empty array."""
from __future__ import annotations

from rtsim.jit import kernel
from rtsim.mbs.model import OK
from rtsim.vehicle.car.effect_kernels import physical_sensors
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE, EX_TORQUE_LEFT, EX_TORQUE_RIGHT, vehicle_advance


@kernel
def _mid(x, k):
    return 0.5 * (x[k] + x[k + 1])


@kernel
def replay_grid(m, d, veh, vd, road, parts, states, io, h, sub, brake, torque_rl, torque_rr, throttle, steer, out):
    """Grid intervals 0..n-2 (n = out.shape[0]; inputs on the same grid, n samples each, or empty): the
    commands set, `sub` steps of h s, the physical sensor values into out[k + 1]. Returns (status, k):
    OK and n - 1, or the failing status and the interval it failed in."""
    n = out.shape[0]
    cmd, extra = io.commands, io.extra
    for k in range(n - 1):
        if brake.size > 0:
            v = _mid(brake, k)
            cmd[CMD_BRAKE] = v if v > 0.0 else 0.0          # Python's max(0.0, v)
        if torque_rl.size > 0:
            extra[EX_TORQUE_LEFT] = _mid(torque_rl, k)
            extra[EX_TORQUE_RIGHT] = _mid(torque_rr, k)
        if throttle.size > 0:
            v = _mid(throttle, k)
            cmd[CMD_THROTTLE] = v if v > 0.0 else 0.0
        if steer.size > 0:
            cmd[CMD_STEER] = _mid(steer, k)
        status, _ = vehicle_advance(m, d, veh, vd, road, parts, states, io, h, sub)
        if status != OK:
            return status, k
        physical_sensors(m, d, veh, io.signals, parts.effects, out[k + 1])
    return OK, n - 1
