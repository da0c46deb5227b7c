"""The car's step: the subsystems before the multibody step, the multibody step with the car's forces
(the stages of rtsim.vehicle.car.forces) implicit in it, and the commits after it."""
from __future__ import annotations

from collections import namedtuple
from math import sqrt

import numpy as np

from rtsim.jit import inline_kernel, kernel
from rtsim.mbs.integrator import step_with_forces
from rtsim.mbs.model import OK
from rtsim.road.query import NCONTACT

from .effect_kernels import (FX_BRAKE, FX_DL, FX_ON, FX_RELAX, driveline_commit, effects_brake, record_sensors,
                             EffectState)
from ..kit.brake import BI_SIZE, BO_LINE, BO_SIZE, brake_commit, brake_step
from ..kit.powertrain import (PO_ENGINE_SPEED, PO_SIZE, PO_THROTTLE, PO_TORQUE_LEFT, PO_TORQUE_RIGHT, powertrain_step,
                              PtIn)
from .sensors import (NSIGNAL, SG_BRAKE_PRESSURE, SG_ENGINE_SPEED, SG_MOTOR_ANGLE, SG_MOTOR_CURRENT,
                      SG_MOTOR_SPEED, SG_POWER_STAGE, SG_STEERING_TORQUE, SG_SW_ANGLE, SG_THROTTLE, SG_TORQUE_LEFT,
                      SG_TORQUE_RIGHT, SG_VEHICLE_SPEED)
from ..kit.sensor_model import SensorState
from ..kit.steering import SO_SIZE, SO_SW_ANGLE, SO_TORQUE, steering_control, steering_outputs
from ..kit.eps import (EO_CURRENT, EO_MOTOR_ANGLE, EO_MOTOR_SPEED, EO_SIZE, EO_SW_ANGLE, EO_TB_TORQUE, EP_DRIVER,
                       EP_K_TB, EP_N, EP_RP, ES_EXT, ES_STAGE, ES_T_DRIVER, DRIVER_TORQUE, eps_commit, eps_control,
                       eps_outputs, external_command, hands_step)
from .energy_kernels import audit_commit
from .forces import NTO, add_vehicle_forces, vehicle_forces, TyreOut
from .layout import CI_PHI, STEER_COLUMN, STEER_EPS, STEER_RACK, NPORT, Susp
from ..kit.tyre.magic_formula import advance_deflections, advance_deflections_relaxed

VehicleData = namedtuple("VehicleData", [
    "slip",        # (4, 2) tyre contact deflections (transient slip states), m
    "drive",       # (4,) drive torques on the wheels, N m (set per step)
    "tyre",        # (4, NTO) tyre outputs of the last force evaluation
    "contact",     # (NCONTACT,) scratch of the contact query
    "brake_torque",  # (4,) brake torque of the last evaluation, N m
    "theta", "omega",  # (4,) wheel spin angles and rates handed to the brake commit
    "brake_in", "brake_out",  # brake kernel input (BI_SIZE) and outputs (BO_SIZE)
    "steer_offset",  # (4,) rad, compliance steer of each knuckle, held over the step (from the tyre forces)
    "audit",       # (1,) 1: after each step the power audit sums the force records pf (energy.py)
    "pf",          # (NPORT, nq) the force stages' records: generalized forces per port (layout PORT_*)
                   # of the last force evaluation (rtsim.vehicle.car.forces)
    "pf_prev", "q_prev", "qc", "qc_prev",   # the audit's values at the previous step's end (energy.py)
    "audit_e",     # (A_SIZE,) the audit's cumulative energies (rtsim.vehicle.car.energy)
    "e_base",      # (3,) the EPS's electrical energies when the audit started
])
AUDIT_SIZE = 64    # >= rtsim.vehicle.car.energy.A_SIZE (checked there)


def make_vehicle_data(nq: int = 1) -> VehicleData:
    return VehicleData(slip=np.zeros((4, 2)), drive=np.zeros(4), tyre=np.zeros((4, NTO)),
                       contact=np.zeros(NCONTACT), brake_torque=np.zeros(4), theta=np.zeros(4),
                       omega=np.zeros(4), brake_in=np.zeros(BI_SIZE), brake_out=np.zeros(BO_SIZE),
                       steer_offset=np.zeros(4), audit=np.zeros(1), pf=np.zeros((NPORT, nq)),
                       pf_prev=np.zeros((NPORT, nq)), q_prev=np.zeros(nq), qc=np.zeros((2, nq)),
                       qc_prev=np.zeros((2, nq)), audit_e=np.zeros(AUDIT_SIZE), e_base=np.zeros(3))


@inline_kernel
def _car_forces(m, d, a, tangent, bq, hc):
    """The car's forces in the Newton iteration: a stage kernel, compiled into the step."""
    return add_vehicle_forces(m, d, a[0], a[1], a[2], a[3], a[4], tangent, bq, hc)


@inline_kernel
def _car_forces_call(m, d, a, tangent, bq, hc):
    """The car's forces at the converged q, where the step evaluates them there (rtsim.mbs.integrator
    finish_evaluates: the cars only when the projections make a factor of their own): a call."""
    return vehicle_forces(m, d, a[0], a[1], a[2], a[3], a[4], tangent, bq, hc)


@inline_kernel
def vehicle_mbs_step(m, d, veh, vd, road, parts, states, h):
    """One ALI3-P step of the vehicle: the multibody stages with the vehicle's forces added (all of it
    compiled into vehicle_step: see rtsim.mbs.integrator.step_with_forces)."""
    return step_with_forces(m, d, h, _car_forces, _car_forces_call, (veh, vd, road, parts, states))


# parameter arrays; effects: rtsim.vehicle.car.effect_kernels FX_* (neutral_params() for the nominal model);
# sensors: the sensor model's (rtsim.vehicle.kit.sensor_model, (channels, NSM))
Parts = namedtuple("Parts", ["tyre", "brake", "powertrain", "steering", "effects", "sensors"])
# subsystem state arrays; effects: FS_* (brake lag, driveline nodes); sensors: the sensor model's history
States = namedtuple("States", ["brake", "powertrain", "steering", "effects", "sensors"])
IO = namedtuple("IO", [
    "commands",     # (NCMD,) CMD_*: throttle rad, brake kPa, steering-wheel angle rad, EPS current A, invalid
    "extra",        # (4,) measured drive torque on the driven axle's left, right wheel (N m), selector
                    # (+1 D, 0 N, -1 R), spare
    "pt_in", "pt_out",
    "st_out",       # (SO_SIZE,) steering outputs after the step (rtsim.vehicle.kit.steering SO_*)
    "eps_out",      # (EO_SIZE,) EPS outputs after the step (rtsim.vehicle.kit.eps EO_*)
    "signals",      # (NSIGNAL,) subsystem values handed to the sensors
])
# the vehicle's command slots; the last two: an external EPS controller's current (A) and 1.0 while it
# has no valid command (none yet, or timed out); COMMAND_SLOTS: where each command channel goes
CMD_THROTTLE, CMD_BRAKE, CMD_STEER, CMD_MOTOR_CURRENT, CMD_MOTOR_INVALID = range(5)
NCMD = 5
COMMAND_SLOTS = {"throttle_angle_cmd": CMD_THROTTLE, "brake_pressure_cmd": CMD_BRAKE,
                 "steering_wheel_angle_cmd": CMD_STEER, "motor_current_cmd": CMD_MOTOR_CURRENT}
INVALID_SLOTS = {"motor_current_cmd": CMD_MOTOR_INVALID}
EX_TORQUE_LEFT, EX_TORQUE_RIGHT, EX_SELECTOR, EX_SW_TORQUE = 0, 1, 2, 3   # EX_SW_TORQUE: N m, EPS torque mode


def make_io() -> IO:
    return IO(commands=np.zeros(NCMD), extra=np.array([0.0, 0.0, 1.0, 0.0]), pt_in=np.zeros(PtIn.SIZE),
              pt_out=np.zeros(PO_SIZE), st_out=np.zeros(SO_SIZE), eps_out=np.zeros(EO_SIZE),
              signals=np.zeros(NSIGNAL))


@kernel
def vehicle_step(m, d, veh, vd, road, parts, states, io, h):
    """A full vehicle step at fixed step h:
    1. subsystems to t + h from the commands: brake pressure (actuator), steer-by-wire controller and
       motor (the column torque held over the step), powertrain (drive torques from the current wheel
       speeds);
    2. the multibody step with tyre, suspension, steering, brake, drive and aero forces implicit;
    3. between-step commits: brake stick/slide modes, tyre contact deflections; signals for sensors.
    Effects (parts.effects) act in 1 (brake torques, driveline speeds), 2 and 3 (driveline nodes,
    relaxation, sensor history)."""
    vehicle_before_mbs(m, d, veh, vd, parts, states, io, h)
    status = vehicle_mbs_step(m, d, veh, vd, road, parts, states, h)
    if status != OK:
        return status
    vehicle_after_mbs(m, d, veh, vd, parts, states, io, h)
    return OK


@inline_kernel
def vehicle_before_mbs(m, d, veh, vd, parts, states, io, h):
    """Stage 1 of vehicle_step: the subsystems to t + h (brake, steering controller or EPS, powertrain)."""
    fx = parts.effects
    fs = states.effects
    fx_on = fx[FX_ON] > 0.5
    vd.brake_in[0] = io.commands[CMD_BRAKE]
    brake_step(parts.brake, states.brake, vd.brake_in, h, vd.brake_out)
    if fx_on and fx[FX_BRAKE] > 0.5:
        effects_brake(fx, fs, parts.brake, states.brake, vd.brake_out)
    ic = veh.steer_idx[STEER_COLUMN]
    ir = veh.steer_idx[STEER_RACK]
    eps = veh.steer_kind[0] == STEER_EPS
    if eps:
        _eps_before_step(m, d, veh, parts.steering, states.steering, io, h, ic, ir)
    else:
        steering_control(parts.steering, states.steering, io.commands[CMD_STEER], d.q[ic], d.qd[ic], h)
    io.pt_in[PtIn.THROTTLE_CMD] = io.commands[CMD_THROTTLE]
    if fx_on and fx[FX_DL] > 0.5:       # the gearbox turns with the driveline nodes
        io.pt_in[PtIn.OMEGA_LEFT] = fs[EffectState.DL + 1]
        io.pt_in[PtIn.OMEGA_RIGHT] = fs[EffectState.DL + 4]
    else:
        io.pt_in[PtIn.OMEGA_LEFT] = d.qd[veh.corner_idx[veh.driven[0], CI_PHI]]
        io.pt_in[PtIn.OMEGA_RIGHT] = d.qd[veh.corner_idx[veh.driven[1], CI_PHI]]
    io.pt_in[PtIn.TORQUE_LEFT] = io.extra[EX_TORQUE_LEFT]
    io.pt_in[PtIn.TORQUE_RIGHT] = io.extra[EX_TORQUE_RIGHT]
    io.pt_in[PtIn.SELECTOR] = io.extra[EX_SELECTOR]
    powertrain_step(parts.powertrain, states.powertrain, io.pt_in, h, io.pt_out)
    vd.drive[veh.driven[0]] = io.pt_out[PO_TORQUE_LEFT]
    vd.drive[veh.driven[1]] = io.pt_out[PO_TORQUE_RIGHT]


@inline_kernel
def vehicle_after_mbs(m, d, veh, vd, parts, states, io, h):
    """Stage 3 of vehicle_step: the commits between steps (brake modes, driveline, tyre deflections, EPS)
    and the signals for the sensors."""
    fx = parts.effects
    fs = states.effects
    fx_on = fx[FX_ON] > 0.5
    ic = veh.steer_idx[STEER_COLUMN]
    ir = veh.steer_idx[STEER_RACK]
    eps = veh.steer_kind[0] == STEER_EPS
    for i in range(4):
        kp = veh.corner_idx[i, CI_PHI]
        vd.theta[i] = d.q[kp]
        vd.omega[i] = d.qd[kp]
    brake_commit(parts.brake, states.brake, vd.theta, vd.omega)
    if fx_on and fx[FX_DL] > 0.5:
        driveline_commit(fx, fs, d, veh, vd.drive, h)
    relax = fx[FX_RELAX] if fx_on else 0.0
    for i in range(4):
        t = vd.tyre[i]
        if relax != 0.0:
            advance_deflections_relaxed(parts.tyre, vd.slip, i, t[TyreOut.FZ], t[TyreOut.GAMMA], t[TyreOut.VX],
                                        t[TyreOut.VSY], t[TyreOut.OMEGA], t[TyreOut.RE], h, relax)
        else:
            advance_deflections(parts.tyre, vd.slip, i, t[TyreOut.FZ], t[TyreOut.GAMMA], t[TyreOut.VX], t[TyreOut.VSY],
                                t[TyreOut.OMEGA], t[TyreOut.RE], h)
    io.signals[SG_BRAKE_PRESSURE] = vd.brake_out[BO_LINE]
    if eps:
        stp = parts.steering
        sts = states.steering
        eps_commit(stp, sts, h, stp[EP_N] * d.qd[ir] / stp[EP_RP])
        row = veh.driver_row[0]
        t_driver = -d.lam[row] if row >= 0 else sts[ES_T_DRIVER]
        eps_outputs(stp, sts, d.q, d.qd, ic, ir, t_driver, io.eps_out)
        io.signals[SG_SW_ANGLE] = io.eps_out[EO_SW_ANGLE]
        io.signals[SG_STEERING_TORQUE] = io.eps_out[EO_TB_TORQUE]
        io.signals[SG_MOTOR_ANGLE] = io.eps_out[EO_MOTOR_ANGLE]
        io.signals[SG_MOTOR_SPEED] = io.eps_out[EO_MOTOR_SPEED]
        io.signals[SG_MOTOR_CURRENT] = io.eps_out[EO_CURRENT]
        io.signals[SG_POWER_STAGE] = sts[ES_STAGE]
        for i in range(2):       # compliance steer of the front knuckles over the next step
            sp = veh.susp[i]
            vd.steer_offset[i] = sp[Susp.CFY] * vd.tyre[i, TyreOut.FY] + sp[Susp.CMZ] * vd.tyre[i, TyreOut.MZ]
    else:
        steering_outputs(parts.steering, states.steering, d.q, ic, ir, io.st_out)
        io.signals[SG_SW_ANGLE] = io.st_out[SO_SW_ANGLE]
        io.signals[SG_STEERING_TORQUE] = io.st_out[SO_TORQUE]
    if vd.audit[0] > 0.5:
        audit_commit(m, d, veh, vd, parts.steering, states.steering)
    ci = veh.chassis_idx
    io.signals[SG_VEHICLE_SPEED] = sqrt(d.qd[ci[0]] ** 2 + d.qd[ci[1]] ** 2 + d.qd[ci[2]] ** 2)
    io.signals[SG_ENGINE_SPEED] = io.pt_out[PO_ENGINE_SPEED]
    io.signals[SG_THROTTLE] = io.pt_out[PO_THROTTLE]
    io.signals[SG_TORQUE_LEFT] = io.pt_out[PO_TORQUE_LEFT]
    io.signals[SG_TORQUE_RIGHT] = io.pt_out[PO_TORQUE_RIGHT]
    if states.sensors[SensorState.SLOTS] > 0.0:
        record_sensors(m, d, veh, io.signals, fx, parts.sensors, states.sensors)


@inline_kernel
def _eps_before_step(m, d, veh, stp, sts, io, h, ic, ir):
    """The EPS over the coming step: the drive's voltage from the torsion-bar torque, the vehicle speed
    and the motor speed at the step's start; the driver's input at its end (the angle the hands impose,
    with its rate and acceleration, or a torque)."""
    rp = stp[EP_RP]
    t_tb = stp[EP_K_TB] * (d.q[ic] - d.q[ir] / rp)
    ci = veh.chassis_idx
    speed = sqrt(d.qd[ci[0]] ** 2 + d.qd[ci[1]] ** 2 + d.qd[ci[2]] ** 2)
    if sts[ES_EXT] > 0.5:
        external_command(stp, sts, io.commands[CMD_MOTOR_CURRENT], io.commands[CMD_MOTOR_INVALID] > 0.5)
    eps_control(stp, sts, t_tb, speed, stp[EP_N] * d.qd[ir] / rp, h)
    if stp[EP_DRIVER] == DRIVER_TORQUE:
        sts[ES_T_DRIVER] = io.extra[EX_SW_TORQUE]
    else:
        k = m.con_drv[veh.driver_row[0]]
        th, w, al = hands_step(stp, sts, io.commands[CMD_STEER], h)
        d.drv_ext[k, 0] = th
        d.drv_ext[k, 1] = w
        d.drv_ext[k, 2] = al


@kernel
def vehicle_advance(m, d, veh, vd, road, parts, states, io, h, nsteps):
    """nsteps vehicle steps with the commands held (benchmarks, settling). Returns (status, steps done)."""
    for n in range(nsteps):
        status = vehicle_step(m, d, veh, vd, road, parts, states, io, h)
        if status != OK:
            return status, n
    return OK, nsteps
