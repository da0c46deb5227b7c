"""A car's offline run in one compiled call with a driver (drivers.driver): per step the driver reads the
vehicle (driver_view), its kernel gives the inputs for the step's end (driver_step), the car takes
one step (vehicle_advance); at every `every`-th step, and before the first, a row of the log
(rtsim.vehicle.car.offline_kernel.log_row). The same kernels in the same order as the Python loop of
rtsim.vehicle.offline, so the rows are the same bit for bit; what the Python loop spent between the
steps (a dispatch of each kernel per step) is gone. The vehicle's offline runner gets it from the
driver it is handed (``Driver.car_loop``): the vehicle does not import its drivers.

The time inside the car's steps is counted with the processor's cycle counter around each
vehicle_advance (rtsim.jit.read_cycles): `cycles` out, seconds with rtsim.jit.cycles_per_second."""
from __future__ import annotations

import numpy as np

from rtsim.jit import kernel, read_cycles
from rtsim.mbs.model import OK
from rtsim.vehicle.car.observer import driver_view
from rtsim.vehicle.car.offline_kernel import apply_commands, log_row
from rtsim.vehicle.car.step import vehicle_advance

from .driver import driver_step


@kernel
def car_offline_loop(m, d, veh, vd, road, parts, states, io, h, packed, speed, path, flags, nsteps, every, rows,
                 keep, has_eps, forced, state, cmd, sens, observed, flows, cycles):
    """Steps 0..nsteps of an offline run (rows as rtsim.vehicle.offline._loop logs them). Returns
    (status, steps done, rows written); cmd is the driver's output array, cycles[0] += the cycles spent
    inside vehicle_advance; step number `forced` (-1: none) fails as rtsim.model_fault's test-only hook
    makes it (the first generalized velocity NaN before it)."""
    nrow = 0
    for n in range(nsteps + 1):
        if n % every == 0:
            log_row(m, d, veh, vd, parts, states, io, keep, has_eps, sens, observed, flows, rows[nrow])
            nrow += 1
        if n == nsteps:
            break
        driver_view(d, veh, state)
        driver_step(packed, speed, path, flags, d.t[0] + h, state, cmd)
        apply_commands(io, cmd)
        if forced == n + 1:
            d.qd[0] = np.nan
        c0 = read_cycles()
        status, _ = vehicle_advance(m, d, veh, vd, road, parts, states, io, h, 1)
        cycles[0] += read_cycles() - c0
        if status != OK:
            return status, n, nrow
    return OK, nsteps, nrow
