"""The service's side of the served-vehicle stages (rtsim.vehicle.kit.served): what the step does around
the vehicle's own stages, identically for every vehicle.

- ``vehicle_drive``: the vehicle's own in-loop driver (``served_drive``: a two-wheeler's rider); when the
  vehicle asks for it, the scenario's driver (drivers.driver), whose outputs go into the command slots
  of the commands the bus does not carry (a live ``driver`` control value replaces the scenario's);
- ``vehicle_user``: which of the user's channels the bus holds a valid, timely command for (the
  watchdog's view, bridge.can_e2e), then the vehicle's ``served_user``;
- ``vehicle_advance``, ``vehicle_sensors``, ``vehicle_observe``: the vehicle's own stages;
- ``vehicle_fault_arrays``: the arrays an actuator fault writes into (rtsim.faults), the vehicle's
  ``served_fault_arrays``, indexed as its sim's ``fault_actuators()`` declare.

The vehicles' implementations live with the vehicles (rtsim.vehicle.car.served,
rtsim.vehicle.motorcycle.served, or a new assembly's own module): nothing here names a vehicle.
"""
from __future__ import annotations

from bridge.can_e2e import IV_HAS_VALUE, IV_TIMED_OUT
from drivers.driver import driver_step
from rtsim.jit import inline_kernel
from rtsim.vehicle.kit.served import (served_advance, served_drive, served_fault_arrays, served_observe, served_sensors,
                                      served_user)


@inline_kernel
def vehicle_drive(v, lp, ls, t, h):
    """The in-loop drivers' commands for the step from t to t + h (see the module docstring)."""
    if served_drive(v, ls.drv_state):
        driver_step(lp.drv_packed, lp.drv_speed, lp.drv_path, lp.drv_flags, t + h, ls.drv_state, ls.drv_out)
        cmd = v.io.commands
        for c in range(ls.drv_out.shape[0]):
            if lp.drv_slot[c] >= 0:
                live = ls.drv_live[c]
                cmd[lp.drv_slot[c]] = ls.drv_out[c] if live != live else live   # (NaN: none)


@inline_kernel
def vehicle_user(v, lp, ls, h):
    """The user's commands for the step of h s (see the module docstring)."""
    iv = ls.rx.iv
    bus_ok = 0
    for u in range(lp.usr_rx.shape[0]):
        r = lp.usr_rx[u]
        if r >= 0 and iv[r, IV_HAS_VALUE] != 0 and iv[r, IV_TIMED_OUT] == 0:
            bus_ok |= 1 << u
    served_user(v, ls.usr, lp.usr_slot, bus_ok, ls.usr_mode[0] != 0, ls.usr_work, h)


@inline_kernel
def vehicle_advance(v, h):
    """One step of h s; returns the step's status (rtsim.mbs.model.OK or a failure)."""
    return served_advance(v, h)


@inline_kernel
def vehicle_sensors(v, out):
    """The sensor channels, as the vehicle's sensors report them, into out."""
    served_sensors(v, out)


@inline_kernel
def vehicle_observe(v, out):
    """The observer state channels into out."""
    served_observe(v, out)


@inline_kernel
def vehicle_fault_arrays(v):
    """The arrays actuator faults write into (a tuple of float64 arrays; see the module docstring)."""
    return served_fault_arrays(v)
