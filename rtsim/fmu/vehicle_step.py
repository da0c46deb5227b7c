"""The compiled stages the vehicle FMU steps any served vehicle with (rtsim.vehicle.kit.served: the same
stages the HIL service's step calls, so nothing here names a vehicle)."""
from __future__ import annotations

from rtsim.jit import kernel
from rtsim.mbs.model import OK
from rtsim.vehicle.kit.served import served_advance, served_observe, served_sensors


@kernel
def advance(v, h, n):
    """n steps of h s with the commands in v.io held; (status, steps done)."""
    for k in range(n):
        status = served_advance(v, h)
        if status != OK:
            return status, k
    return OK, n


@kernel
def read_channels(v, sensors, state):
    """The sensor channels as the vehicle's sensors report them and the observer's state channels."""
    served_sensors(v, sensors)
    served_observe(v, state)
