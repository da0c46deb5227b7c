"""The car's side of a compiled offline loop (drivers.car_loop runs it with the driver's kernel): a
driver's inputs into the car's commands, and one row of the log -- time, the sensors as reported
(sensor_stage, noise drawn from the sensor model's own state), the observer's state channels `keep`
and the power audit's channels (rtsim.vehicle.car.energy: the same differences and sums, in the same
order, as `energy_row`) -- with the kernels the Python loop of rtsim.vehicle.offline calls, so the rows
are the same bit for bit."""
from __future__ import annotations

from rtsim.jit import kernel

from .effect_kernels import sensor_stage
from .energy import _EPS_OUT, _FLOW_PORTS, _ROW_FLOWS, FLOW_KEYS
from .energy_kernels import A_EMF, A_STORED, A_STORED0, A_SUPPLY, A_WINDING, NSTORED
from .inputs import I_BRAKE, I_STEER, I_THROTTLE, I_TORQUE_RL, I_TORQUE_RR
from .layout import PORT_EPS
from .observer import vehicle_state_values
from .step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE, EX_TORQUE_LEFT, EX_TORQUE_RIGHT
from ..kit.eps import PORT_MOTOR_EM

NFLOW = len(FLOW_KEYS)
I_MOTOR_EM = PORT_EPS + PORT_MOTOR_EM


@kernel
def apply_commands(io, cmd):
    """A driver's inputs (rtsim.vehicle.car.inputs layout) into the car's commands and drive torques."""
    io.commands[CMD_THROTTLE] = cmd[I_THROTTLE]
    io.commands[CMD_BRAKE] = cmd[I_BRAKE]
    io.commands[CMD_STEER] = cmd[I_STEER]
    io.extra[EX_TORQUE_LEFT] = cmd[I_TORQUE_RL]
    io.extra[EX_TORQUE_RIGHT] = cmd[I_TORQUE_RR]


@kernel
def log_row(m, d, veh, vd, parts, states, io, keep, has_eps, sens, observed, flows, row):
    """One row of an offline run's log (rtsim.vehicle.offline._log): time, the sensors as reported (the
    sensor model's noise drawn from its own state), the observer's state channels `keep`, the power
    audit's channels; sens, observed and flows are scratch."""
    ns = sens.shape[0]
    nk = keep.shape[0]
    sensor_stage(m, d, veh, io.signals, parts.effects, parts.sensors, states.sensors, sens)
    row[0] = d.t[0]
    for i in range(ns):
        row[1 + i] = sens[i]
    vehicle_state_values(d, veh, vd, io.signals, observed)
    for i in range(nk):
        row[1 + ns + i] = observed[keep[i]]
    _audit_row(vd.audit_e, vd.e_base, io.eps_out, has_eps, flows, row[1 + ns + nk:])


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
