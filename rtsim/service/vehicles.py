"""The vehicles the service's compiled step can serve, and its four calls into them.

The step (rtsim.service.kernel) takes a vehicle as eight arguments ``m, d, veh, vd, road, parts, states,
io`` (what ``sim.loop_args()`` returns) and calls, per step:

- ``vehicle_drive``: the in-loop driver (when the loop's PI_DRIVER is set): for the car, the scenario's
  driver (drivers.driver) writing the commands its DBC does not carry; for a two-wheeler, the rider;
- ``vehicle_user``: the user's commands (rtsim.service.user_input), after the watchdog: a car's into its
  command array, a two-wheeler's in place of the rider's outputs (the lean demand through the lean loop,
  drivers.lean_demand);
- ``vehicle_advance``: one step of the vehicle (its inputs from ``io.commands``, which the watchdog filled);
- ``vehicle_sensors`` and ``vehicle_observe``: the sensor channels and the observer state.

Which vehicle it is follows from the type of ``veh`` at compile time (numba ``overload``), so each
vehicle gets its own compiled step with no branch or indirection in it:

- the car (rtsim.vehicle.car): ``veh`` a ``Vehicle``, the other arguments its data, road, parts,
  states and IO;
- a two-wheeler (rtsim.vehicle.motorcycle.plant): ``veh`` a ``PlantParams``, ``vd`` a ``PlantState``,
  ``road`` its rider (drivers.rider), ``parts`` its ``TwoWheelerParts``, ``io`` a ``PlantIO``
  (``states`` is unused).
"""
from __future__ import annotations

from numba.extending import overload

from bridge.can_e2e import IV_HAS_VALUE, IV_TIMED_OUT
from drivers.driver import driver_step
from drivers.lean_demand import W_ON, lean_torque
from drivers.rider import RO_THROTTLE, RO_TORQUE
from rtsim.vehicle.car.effect_kernels import sensor_stage
from rtsim.vehicle.car.layout import Vehicle
from rtsim.vehicle.car.observer import driver_view, vehicle_state_values
from rtsim.vehicle.car.step import vehicle_step
from rtsim.vehicle.motorcycle.plant import (PlantParams, plant_rider, plant_sensors, plant_state, plant_step,
                                            plant_view, rider_offset_kernel, PP_RIDER)

JIT = {"_nrt": False}


def _kind(veh) -> str:
    cls = getattr(veh, "instance_class", None)
    if cls is Vehicle:
        return "car"
    if cls is PlantParams:
        return "two_wheeler"
    raise TypeError(f"the service cannot step a vehicle of type {veh}")


def vehicle_drive(m, d, veh, vd, road, parts, states, io, lp, ls, t, h):
    """The in-loop driver's commands for the step from t to t + h (see the module docstring)."""


def vehicle_user(m, d, veh, vd, road, parts, states, io, lp, ls, h):
    """The user's commands for the step of h s (see the module docstring)."""


def vehicle_advance(m, d, veh, vd, road, parts, states, io, h):
    """One step of h s; returns the step's status (rtsim.mbs.model.OK or a failure)."""


def vehicle_sensors(m, d, veh, vd, road, parts, states, io, out):
    """The sensor channels, as the vehicle's sensors report them, into out."""


def vehicle_observe(m, d, veh, vd, road, parts, states, io, out):
    """The observer state channels into out."""


@overload(vehicle_drive, jit_options=JIT)
def _drive(m, d, veh, vd, road, parts, states, io, lp, ls, t, h):
    if _kind(veh) == "car":
        def car(m, d, veh, vd, road, parts, states, io, lp, ls, t, h):
            driver_view(d, veh, ls.drv_state)
            driver_step(lp.drv_packed, lp.drv_speed, lp.drv_path, lp.drv_flags, t + h, ls.drv_state, ls.drv_out)
            for c in range(ls.drv_out.shape[0]):
                if lp.drv_slot[c] >= 0:
                    live = ls.drv_live[c]
                    io.commands[lp.drv_slot[c]] = ls.drv_out[c] if live != live else live   # (NaN: none)
        return car

    def two_wheeler(m, d, veh, vd, road, parts, states, io, lp, ls, t, h):
        plant_rider(d, parts.idx, veh.pp, road, vd.rider_view, vd.rider_out)
    return two_wheeler


@overload(vehicle_user, jit_options=JIT)
def _user(m, d, veh, vd, road, parts, states, io, lp, ls, h):
    if _kind(veh) == "car":
        def car(m, d, veh, vd, road, parts, states, io, lp, ls, h):
            iv = ls.rx.iv
            takeover = ls.usr_mode[0] != 0
            for u in range(lp.usr_slot.shape[0]):
                v = ls.usr[u]
                s = lp.usr_slot[u]
                if s < 0 or v != v:                     # (NaN: the user does not drive it)
                    continue
                r = lp.usr_rx[u]
                if r < 0 or takeover or iv[r, IV_HAS_VALUE] == 0 or iv[r, IV_TIMED_OUT] != 0:
                    io.commands[s] = v
        return car

    def two_wheeler(m, d, veh, vd, road, parts, states, io, lp, ls, h):
        out = vd.rider_out
        takeover = ls.usr_mode[0] != 0
        rider = veh.pp[PP_RIDER] > 0.5               # the scenario's rider rides it
        for u in range(3):                              # throttle, front and rear brake
            v = ls.usr[u]
            if v == v:
                out[RO_THROTTLE + u] = v
                if takeover and lp.usr_slot[u] >= 0:
                    io.commands[lp.usr_slot[u]] = 1.0   # the bus command's invalid flag: the rider's input acts
            elif not rider:
                out[RO_THROTTLE + u] = 0.0
        phi = ls.usr[3]
        if phi == phi:
            plant_view(d, parts.idx, veh.pp, vd.rider_view)
            out[RO_TORQUE] = lean_torque(road.par, vd.rider_view, phi, ls.usr_work, h)
            if takeover and lp.usr_slot[3] >= 0:
                io.commands[lp.usr_slot[3]] = 1.0
        else:
            ls.usr_work[W_ON] = 0.0
            if not rider:
                out[RO_TORQUE] = 0.0
    return two_wheeler


@overload(vehicle_advance, jit_options=JIT)
def _advance(m, d, veh, vd, road, parts, states, io, h):
    if _kind(veh) == "car":
        return lambda m, d, veh, vd, road, parts, states, io, h: vehicle_step(m, d, veh, vd, road, parts, states,
                                                                             io, h)
    return lambda m, d, veh, vd, road, parts, states, io, h: plant_step(m, d, veh, vd, parts, io, h)


@overload(vehicle_sensors, jit_options=JIT)
def _sensors(m, d, veh, vd, road, parts, states, io, out):
    if _kind(veh) == "car":
        def car(m, d, veh, vd, road, parts, states, io, out):
            sensor_stage(m, d, veh, io.signals, parts.effects, parts.sensors, states.sensors, out)
        return car

    def two_wheeler(m, d, veh, vd, road, parts, states, io, out):
        plant_sensors(d, parts.idx, parts.par, veh.pp, vd.inp, out)
    return two_wheeler


@overload(vehicle_observe, jit_options=JIT)
def _observe(m, d, veh, vd, road, parts, states, io, out):
    if _kind(veh) == "car":
        def car(m, d, veh, vd, road, parts, states, io, out):
            vehicle_state_values(d, veh, vd, io.signals, out)
        return car

    def two_wheeler(m, d, veh, vd, road, parts, states, io, out):
        plant_state(d, parts.idx, parts.par, veh.pp, parts.tyre, vd.inp, vd.es, rider_offset_kernel(road, veh.pp),
                    out)
    return two_wheeler
