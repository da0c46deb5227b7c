"""The two-wheeler's stages in the service's compiled step (rtsim.vehicle.kit.served), for its tuple
``LoopTwoWheeler`` (declared here: m, d, params, plant, rider, parts, io); rtsim.vehicle.motorcycle.hil
imports the tuple from here, so whoever serves it has the stages registered.

- drive: its own rider, inside the step (the scenario's driver never acts);
- user: throttle and caliper pressures in place of the rider's outputs; the lean demand through the
  lean loop (rtsim.vehicle.motorcycle.lean_demand) as handlebar torque; while the user has taken
  over, the bus command's invalid flag is set so the rider's input (the user's) acts;
- advance, sensors, observe: the plant's step, sensors and state.
"""
from __future__ import annotations

from typing import NamedTuple

from numba.extending import overload

from .lean_demand import W_ON, lean_torque
from .rider import RO_THROTTLE, RO_TORQUE

from ..kit.served import (JIT, of_type, served_advance, served_drive, served_fault_arrays, served_observe,
                          served_sensors, served_user)
from .plant import (PP_RIDER, plant_rider, plant_sensors, plant_state, plant_step, plant_view,
                    rider_offset_kernel)


class LoopTwoWheeler(NamedTuple):
    """The two-wheeler in the service's compiled step (rtsim.vehicle.motorcycle.served): the multibody model and
    data, its plant's parameters and state (rtsim.vehicle.motorcycle.plant), the rider, the parts, the IO."""
    m: object
    d: object
    params: object
    plant: object
    rider: object
    parts: object
    io: object


@overload(served_drive, jit_options=JIT)
def _drive(v, state):
    if not of_type(v, LoopTwoWheeler):
        return None

    def two_wheeler(v, state):
        plant_rider(v.d, v.parts.idx, v.params.pp, v.rider, v.plant.rider_view, v.plant.rider_out)
        return False
    return two_wheeler


@overload(served_user, jit_options=JIT)
def _user(v, usr, slot, bus_ok, takeover, work, h):
    if not of_type(v, LoopTwoWheeler):
        return None

    def two_wheeler(v, usr, slot, bus_ok, takeover, work, h):
        out = v.plant.rider_out
        rider = v.params.pp[PP_RIDER] > 0.5          # the scenario's rider rides it
        for u in range(3):                              # throttle, front and rear brake
            x = usr[u]
            if x == x:
                out[RO_THROTTLE + u] = x
                if takeover and slot[u] >= 0:
                    v.io.commands[slot[u]] = 1.0        # the bus command's invalid flag: the rider's input acts
            elif not rider:
                out[RO_THROTTLE + u] = 0.0
        phi = usr[3]
        if phi == phi:
            plant_view(v.d, v.parts.idx, v.params.pp, v.plant.rider_view)
            out[RO_TORQUE] = lean_torque(v.rider.par, v.plant.rider_view, phi, work, h)
            if takeover and slot[3] >= 0:
                v.io.commands[slot[3]] = 1.0
        else:
            work[W_ON] = 0.0
            if not rider:
                out[RO_TORQUE] = 0.0
    return two_wheeler


@overload(served_advance, jit_options=JIT)
def _advance(v, h):
    if not of_type(v, LoopTwoWheeler):
        return None
    return lambda v, h: plant_step(v.m, v.d, v.params, v.plant, v.parts, v.io, h)


@overload(served_sensors, jit_options=JIT)
def _sensors(v, out):
    if not of_type(v, LoopTwoWheeler):
        return None

    def two_wheeler(v, out):
        plant_sensors(v.d, v.parts.idx, v.parts.par, v.params.pp, v.plant.inp, out)
    return two_wheeler


@overload(served_observe, jit_options=JIT)
def _observe(v, out):
    if not of_type(v, LoopTwoWheeler):
        return None

    def two_wheeler(v, out):
        plant_state(v.d, v.parts.idx, v.parts.par, v.params.pp, v.parts.tyre, v.plant.inp, v.plant.es,
                    rider_offset_kernel(v.rider, v.params.pp), out)
    return two_wheeler


@overload(served_fault_arrays, jit_options=JIT)
def _fault_arrays(v):
    if not of_type(v, LoopTwoWheeler):
        return None
    return lambda v: (v.io.commands,)          # (it declares no actuator fault yet)
