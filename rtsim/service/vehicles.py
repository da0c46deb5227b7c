"""The vehicles the service's compiled step can serve, and its calls into them.

The step (rtsim.service.kernel) takes the vehicle as one named tuple ``v`` (what ``sim.served()``
returns: each vehicle's own fields, named for what they hold) and calls, per step:

- ``vehicle_drive``: the in-loop driver (when the loop's PI_DRIVER is set): for the car, the scenario's
  driver (drivers.driver) writing the commands its DBC does not carry; for a two-wheeler, the rider;
- ``vehicle_user``: the user's commands (rtsim.service.user_input), after the watchdog: a car's into its
  command array, a two-wheeler's in place of the rider's outputs (the lean demand through the lean loop,
  drivers.lean_demand);
- ``vehicle_advance``: one step of the vehicle (its inputs from ``v.io.commands``, which the watchdog filled);
- ``vehicle_sensors`` and ``vehicle_observe``: the sensor channels and the observer state;
- ``vehicle_fault_arrays``: the arrays an actuator fault writes into (rtsim.faults), indexed as the vehicle's
  ``fault_actuators`` declare (a tuple of float64 arrays).

Each vehicle registers its own implementation of each call for the type of its tuple (numba
``overload``: an implementation answers only for its vehicle's type), so each vehicle gets its own
compiled step with no branch or indirection in it:

- the car (rtsim.vehicle.car.sim.LoopCar): m, d, vehicle, data, road, parts, states, io;
- a two-wheeler (rtsim.vehicle.motorcycle.hil.LoopTwoWheeler): m, d, params, plant, rider, parts, io.

A vehicle of another type has no implementation: numba refuses it when the step is compiled.
"""
from __future__ import annotations

from numba.extending import overload

from bridge.can_e2e import IV_HAS_VALUE, IV_TIMED_OUT
from drivers.driver import driver_step
from drivers.lean_demand import W_ON, lean_torque
from drivers.rider import RO_THROTTLE, RO_TORQUE
from rtsim.vehicle.car.effect_kernels import sensor_stage
from rtsim.vehicle.car.observer import driver_view, vehicle_state_values
from rtsim.vehicle.car.sim import LoopCar
from rtsim.vehicle.car.step import vehicle_step
from rtsim.vehicle.motorcycle.hil import LoopTwoWheeler
from rtsim.vehicle.motorcycle.plant import (plant_rider, plant_sensors, plant_state, plant_step, plant_view,
                                            rider_offset_kernel, PP_RIDER)

JIT = {"_nrt": False}


def _of(v, cls) -> bool:
    """Whether the numba type ``v`` is the named tuple ``cls`` (a vehicle's served tuple)."""
    return getattr(v, "instance_class", None) is cls


def vehicle_drive(v, lp, ls, t, h):
    """The in-loop driver's commands for the step from t to t + h (see the module docstring)."""


def vehicle_user(v, lp, ls, h):
    """The user's commands for the step of h s (see the module docstring)."""


def vehicle_advance(v, h):
    """One step of h s; returns the step's status (rtsim.mbs.model.OK or a failure)."""


def vehicle_sensors(v, out):
    """The sensor channels, as the vehicle's sensors report them, into out."""


def vehicle_observe(v, out):
    """The observer state channels into out."""


def vehicle_fault_arrays(v):
    """The arrays actuator faults write into (``fault_actuators`` of the vehicle sim indexes them)."""


# ---- the car ---------------------------------------------------------------------------------------
@overload(vehicle_drive, jit_options=JIT)
def _car_drive(v, lp, ls, t, h):
    if not _of(v, LoopCar):
        return None

    def car(v, lp, ls, t, h):
        driver_view(v.d, v.vehicle, ls.drv_state)
        driver_step(lp.drv_packed, lp.drv_speed, lp.drv_path, lp.drv_flags, t + h, ls.drv_state, ls.drv_out)
        cmd = v.io.commands
        for c in range(ls.drv_out.shape[0]):
            if lp.drv_slot[c] >= 0:
                live = ls.drv_live[c]
                cmd[lp.drv_slot[c]] = ls.drv_out[c] if live != live else live   # (NaN: none)
    return car


@overload(vehicle_user, jit_options=JIT)
def _car_user(v, lp, ls, h):
    if not _of(v, LoopCar):
        return None

    def car(v, lp, ls, h):
        iv = ls.rx.iv
        takeover = ls.usr_mode[0] != 0
        for u in range(lp.usr_slot.shape[0]):
            x = ls.usr[u]
            s = lp.usr_slot[u]
            if s < 0 or x != x:                     # (NaN: the user does not drive it)
                continue
            r = lp.usr_rx[u]
            if r < 0 or takeover or iv[r, IV_HAS_VALUE] == 0 or iv[r, IV_TIMED_OUT] != 0:
                v.io.commands[s] = x
    return car


@overload(vehicle_advance, jit_options=JIT)
def _car_advance(v, h):
    if not _of(v, LoopCar):
        return None
    return lambda v, h: vehicle_step(v.m, v.d, v.vehicle, v.data, v.road, v.parts, v.states, v.io, h)


@overload(vehicle_sensors, jit_options=JIT)
def _car_sensors(v, out):
    if not _of(v, LoopCar):
        return None

    def car(v, out):
        sensor_stage(v.m, v.d, v.vehicle, v.io.signals, v.parts.effects, v.parts.sensors, v.states.sensors, out)
    return car


@overload(vehicle_observe, jit_options=JIT)
def _car_observe(v, out):
    if not _of(v, LoopCar):
        return None

    def car(v, out):
        vehicle_state_values(v.d, v.vehicle, v.data, v.io.signals, out)
    return car


@overload(vehicle_fault_arrays, jit_options=JIT)
def _car_fault_arrays(v):
    if not _of(v, LoopCar):
        return None
    # rtsim.vehicle.car.sim.FAULT_ARRAYS: commands, brake parameters, steering (or EPS) parameters and state
    return lambda v: (v.io.commands, v.parts.brake, v.parts.steering, v.states.steering)


# ---- the two-wheeler --------------------------------------------------------------------------------
@overload(vehicle_drive, jit_options=JIT)
def _two_wheeler_drive(v, lp, ls, t, h):
    if not _of(v, LoopTwoWheeler):
        return None

    def two_wheeler(v, lp, ls, t, h):
        plant_rider(v.d, v.parts.idx, v.params.pp, v.rider, v.plant.rider_view, v.plant.rider_out)
    return two_wheeler


@overload(vehicle_user, jit_options=JIT)
def _two_wheeler_user(v, lp, ls, h):
    if not _of(v, LoopTwoWheeler):
        return None

    def two_wheeler(v, lp, ls, h):
        out = v.plant.rider_out
        takeover = ls.usr_mode[0] != 0
        rider = v.params.pp[PP_RIDER] > 0.5          # the scenario's rider rides it
        for u in range(3):                              # throttle, front and rear brake
            x = ls.usr[u]
            if x == x:
                out[RO_THROTTLE + u] = x
                if takeover and lp.usr_slot[u] >= 0:
                    v.io.commands[lp.usr_slot[u]] = 1.0  # the bus command's invalid flag: the rider's input acts
            elif not rider:
                out[RO_THROTTLE + u] = 0.0
        phi = ls.usr[3]
        if phi == phi:
            plant_view(v.d, v.parts.idx, v.params.pp, v.plant.rider_view)
            out[RO_TORQUE] = lean_torque(v.rider.par, v.plant.rider_view, phi, ls.usr_work, h)
            if takeover and lp.usr_slot[3] >= 0:
                v.io.commands[lp.usr_slot[3]] = 1.0
        else:
            ls.usr_work[W_ON] = 0.0
            if not rider:
                out[RO_TORQUE] = 0.0
    return two_wheeler


@overload(vehicle_advance, jit_options=JIT)
def _two_wheeler_advance(v, h):
    if not _of(v, LoopTwoWheeler):
        return None
    return lambda v, h: plant_step(v.m, v.d, v.params, v.plant, v.parts, v.io, h)


@overload(vehicle_sensors, jit_options=JIT)
def _two_wheeler_sensors(v, out):
    if not _of(v, LoopTwoWheeler):
        return None

    def two_wheeler(v, out):
        plant_sensors(v.d, v.parts.idx, v.parts.par, v.params.pp, v.plant.inp, out)
    return two_wheeler


@overload(vehicle_observe, jit_options=JIT)
def _two_wheeler_observe(v, out):
    if not _of(v, LoopTwoWheeler):
        return None

    def two_wheeler(v, out):
        plant_state(v.d, v.parts.idx, v.parts.par, v.params.pp, v.parts.tyre, v.plant.inp, v.plant.es,
                    rider_offset_kernel(v.rider, v.params.pp), out)
    return two_wheeler


@overload(vehicle_fault_arrays, jit_options=JIT)
def _two_wheeler_fault_arrays(v):
    if not _of(v, LoopTwoWheeler):
        return None
    return lambda v: (v.io.commands,)          # (it declares no actuator fault yet)
