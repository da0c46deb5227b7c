"""The car's offline loop in one compiled call: per step the driver reads the vehicle (driver_view), its
kernel gives the commands for the step's end (drivers.driver.driver_step), the car takes one step
(vehicle_advance); at every `every`-th step, and before the first, a row of the log: time, the sensors
as reported (sensor_stage, noise drawn from the sensor model's own state), the observer's state channels
`keep` and the power audit's channels (rtsim.vehicle.car.energy: the same differences and sums, in the
same order, as `energy_row`). The same kernels in the same order as the Python loop of
rtsim.vehicle.offline, so the rows are the same bit for bit; what the Python loop spent between the
steps (a dispatch of each kernel, the audit's row) is gone.

The time inside the car's steps is counted with the processor's cycle counter around each
vehicle_advance (rtsim.jit.read_cycles): `cycles` out, seconds with rtsim.jit.cycles_per_second."""
from __future__ import annotations

import numpy as np

from drivers.driver import driver_step
from rtsim.jit import kernel, read_cycles

from .effect_kernels import sensor_stage
from .energy import _EPS_OUT, _FLOW_PORTS, _ROW_FLOWS, FLOW_KEYS
from .energy_kernels import A_EMF, A_STORED, A_STORED0, A_SUPPLY, A_WINDING, NSTORED
from .inputs import I_BRAKE, I_STEER, I_THROTTLE, I_TORQUE_RL, I_TORQUE_RR
from .layout import PORT_EPS
from .observer import driver_view, vehicle_state_values
from .step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE, EX_TORQUE_LEFT, EX_TORQUE_RIGHT, OK, vehicle_advance
from ..kit.eps import PORT_MOTOR_EM

NFLOW = len(FLOW_KEYS)
I_MOTOR_EM = PORT_EPS + PORT_MOTOR_EM


@kernel
def _audit_row(a, e_base, eps_out, has_eps, flows, out):
    """rtsim.vehicle.car.energy.energy_row into out, `flows` (NFLOW) its scratch."""
    n = _FLOW_PORTS.size
    for i in range(n):
        flows[i] = a[_FLOW_PORTS[i]]
    flows[n] = a[A_SUPPLY] - e_base[0]
    flows[n + 1] = -(a[A_WINDING] - e_base[1])
    flows[n + 2] = a[I_MOTOR_EM] - (a[A_EMF] - e_base[2])
    nf = _ROW_FLOWS.size
    for i in range(nf):
        out[i] = flows[_ROW_FLOWS[i]]
    stored = 0.0
    for j in range(NSTORED):
        s = a[A_STORED + j] - a[A_STORED0 + j]
        out[nf + j] = s
        stored += s
    total = 0.0
    for i in range(NFLOW):
        total += flows[i]
    out[nf + NSTORED] = stored - total
    k = nf + NSTORED + 1
    if has_eps:
        for j in range(_EPS_OUT.size):
            out[k + j] = eps_out[_EPS_OUT[j]]
    else:
        for j in range(k, out.shape[0]):
            out[j] = 0.0


@kernel
def offline_loop(m, d, veh, vd, road, parts, states, io, h, packed, speed, path, flags, nsteps, every, rows,
                 keep, has_eps, forced, state, cmd, sens, observed, flows, cycles):
    """Steps 0..nsteps of an offline run (rows as rtsim.vehicle.offline._loop logs them). Returns
    (status, steps done, rows written); cmd is the driver's output array, cycles[0] += the cycles spent
    inside vehicle_advance; step number `forced` (-1: none) fails as rtsim.model_fault's test-only hook
    makes it (the first generalized velocity NaN before it)."""
    nrow = 0
    ns = sens.shape[0]
    nk = keep.shape[0]
    for n in range(nsteps + 1):
        if n % every == 0:
            row = rows[nrow]
            sensor_stage(m, d, veh, io.signals, parts.effects, parts.sensors, states.sensors, sens)
            row[0] = d.t[0]
            for i in range(ns):
                row[1 + i] = sens[i]
            vehicle_state_values(d, veh, vd, io.signals, observed)
            for i in range(nk):
                row[1 + ns + i] = observed[keep[i]]
            _audit_row(vd.audit_e, vd.e_base, io.eps_out, has_eps, flows, row[1 + ns + nk:])
            nrow += 1
        if n == nsteps:
            break
        driver_view(d, veh, state)
        driver_step(packed, speed, path, flags, d.t[0] + h, state, cmd)
        io.commands[CMD_THROTTLE] = cmd[I_THROTTLE]
        io.commands[CMD_BRAKE] = cmd[I_BRAKE]
        io.commands[CMD_STEER] = cmd[I_STEER]
        io.extra[EX_TORQUE_LEFT] = cmd[I_TORQUE_RL]
        io.extra[EX_TORQUE_RIGHT] = cmd[I_TORQUE_RR]
        if forced == n + 1:
            d.qd[0] = np.nan
        c0 = read_cycles()
        status, _ = vehicle_advance(m, d, veh, vd, road, parts, states, io, h, 1)
        cycles[0] += read_cycles() - c0
        if status != OK:
            return status, n, nrow
    return OK, nsteps, nrow
