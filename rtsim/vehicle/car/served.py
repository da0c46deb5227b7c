"""The four-wheel car's stages in the service's compiled step (rtsim.vehicle.kit.served), for its tuple
``LoopCar`` (declared here: m, d, vehicle, data, road, parts, states, io). rtsim.vehicle.car.sim imports
the tuple from here, so any assembly that serves a ``LoopCar`` has the stages registered.

- drive: no driver of its own; the scenario's driver reads the car's speed, position and yaw;
- user: a user channel replaces its command where the bus has no valid command or the user took over;
- advance, sensors, observe: the car's step, its sensor stage and its observer.
"""
from __future__ import annotations

from typing import NamedTuple

from numba.extending import overload

from ..kit.served import (JIT, of_type, served_advance, served_drive, served_fault_arrays, served_observe,
                          served_sensors, served_user)
from .effect_kernels import sensor_stage
from .observer import driver_view, vehicle_state_values
from .step import vehicle_step


class LoopCar(NamedTuple):
    """The car in the service's compiled step (rtsim.vehicle.car.served): the multibody model and data,
    the compiled vehicle and its data, the road, the parts' parameters, their states, the IO arrays."""
    m: object
    d: object
    vehicle: object
    data: object
    road: object
    parts: object
    states: object
    io: object


@overload(served_drive, jit_options=JIT)
def _drive(v, state):
    if not of_type(v, LoopCar):
        return None

    def car(v, state):
        driver_view(v.d, v.vehicle, state)
        return True
    return car


@overload(served_user, jit_options=JIT)
def _user(v, usr, slot, bus_ok, takeover, work, h):
    if not of_type(v, LoopCar):
        return None

    def car(v, usr, slot, bus_ok, takeover, work, h):
        for u in range(slot.shape[0]):
            x = usr[u]
            s = slot[u]
            if s < 0 or x != x:                     # (NaN: the user does not drive it)
                continue
            if takeover or (bus_ok >> u) & 1 == 0:
                v.io.commands[s] = x
    return car


@overload(served_advance, jit_options=JIT)
def _advance(v, h):
    if not of_type(v, LoopCar):
        return None
    return lambda v, h: vehicle_step(v.m, v.d, v.vehicle, v.data, v.road, v.parts, v.states, v.io, h)


@overload(served_sensors, jit_options=JIT)
def _sensors(v, out):
    if not of_type(v, LoopCar):
        return None

    def car(v, out):
        sensor_stage(v.m, v.d, v.vehicle, v.io.signals, v.parts.effects, v.parts.sensors, v.states.sensors, out)
    return car


@overload(served_observe, jit_options=JIT)
def _observe(v, out):
    if not of_type(v, LoopCar):
        return None

    def car(v, out):
        vehicle_state_values(v.d, v.vehicle, v.data, v.io.signals, out)
    return car


@overload(served_fault_arrays, jit_options=JIT)
def _fault_arrays(v):
    if not of_type(v, LoopCar):
        return None
    # rtsim.vehicle.car.sim.FAULT_ARRAYS: commands, brake parameters, steering (or EPS) parameters and state
    return lambda v: (v.io.commands, v.parts.brake, v.parts.steering, v.states.steering)
