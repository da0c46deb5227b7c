"""The service's step as one compiled call: vehicle step, then (on sample steps) the sensor channels
packed into the CAN payloads, and (on state steps) the observer state.

One call instead of three matters: every call from Python into numba unboxes the model and state
named tuples (~75 arrays, several microseconds), which is more than the sensors and the packing cost.
"""
from __future__ import annotations

from bridge.can_pack import pack_sensor_frames
from rtsim.jit import kernel
from rtsim.mbs.model import OK
from rtsim.vehicle.dynamics import vehicle_step
from rtsim.vehicle.effect_kernels import sensor_stage
from rtsim.vehicle.state import vehicle_state_values


@kernel
def service_step(m, d, veh, vd, road, parts, states, io, h, want_sensors, pack, sens, t_s, time_start,
                 time_mask, sig_int, sig_float, words, want_state, state):
    """One vehicle step of h s with the commands in io; then true sensors into ``sens`` (and, if
    ``pack``, their frames into ``words`` stamped ``t_s``) when ``want_sensors``, and the observer
    state into ``state`` when ``want_state``. Returns the step status (OK or an error code)."""
    status = vehicle_step(m, d, veh, vd, road, parts, states, io, h)
    if status != OK:
        return status
    if want_sensors:
        sensor_stage(m, d, veh, io.signals, parts.effects, states.effects, sens)   # incl. sensor effects
        if pack:
            pack_sensor_frames(sens, t_s, time_start, time_mask, sig_int, sig_float, words)
    if want_state:
        vehicle_state_values(d, veh, vd, io.signals, state)
    return status
