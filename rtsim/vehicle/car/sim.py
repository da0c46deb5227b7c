"""A vehicle on a road: builds everything from the configuration, places the car on the road in
static equilibrium, and steps it (compiled) with the subsystems' states. The switchable effects of
rtsim.vehicle.car.effects (the config's [effects], or `effects=`) can be replaced at any time between steps
with `set_effects`, without rebuilding the model."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rtsim.errors import ConfigError
from rtsim.mbs import Simulation
from rtsim.mbs.integrator import NEED_FACTOR
from rtsim.mbs.model import OK, gravity
from rtsim.road.model import Road
from rtsim.road.query import NQUERY, Q_NX, Q_NZ, Q_Z, road_query

from ..kit.brake import BP_GAIN, BP_STUCK, BS_P_FRONT, BS_P_REAR, brake_config, brake_params, brake_state
from ..kit.powertrain import (PO_TORQUE_LEFT, PO_TORQUE_RIGHT, PP_MEASURED, powertrain_config, powertrain_params,
                              powertrain_state_rolling, powertrain_step, PtIn)
from ..kit.sensor_model import (SensorState, copy_noise_state, neutral_params as sm_neutral, seed_noise, sensor_params,
                                sensor_state)
from ..kit.eps import EP_KT, ES_FAULT, ES_GAIN, ES_STAGE, eps_state, eps_params, external_mode, stage_off
from ..kit.actuators import LAG_HI, LAG_LO
from ..kit.steering import steering_config, steering_params, steering_state, SbwPar
from ..kit.tyre.magic_formula import effective_rolling_radius
from ..kit.tyre.tir import P_UNLOADED_RADIUS, P_VERTICAL_STIFFNESS, load_tir
from .build import VehicleModel
from .effect_kernels import (FX_B_LAG, FX_DL, FX_DL_K, FX_MASS, FX_ON, fill_history, neutral_params, physical_sensors,
                             sensor_stage, EffectState)
from .effects import pack_effects, validate_effects
from .layout import CI_PHI, WHEELS
from .inputs import USER_INPUTS as CAR_USER_INPUTS
from .observer import NSTATE_OUT
from .step import (CMD_BRAKE, CMD_THROTTLE, COMMAND_SLOTS, EX_SELECTOR, INVALID_SLOTS, Parts, States, make_io, make_vehicle_data,
                   vehicle_advance)
from .served import LoopCar  # the served tuple; importing it registers the car's stages


def _align_z(n: np.ndarray) -> np.ndarray:
    """The smallest rotation taking (0, 0, 1) to the unit vector n."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    sin_a, cos_a = np.linalg.norm(axis), float(z @ n)
    if sin_a < 1e-12:
        return np.eye(3)
    k = axis / sin_a
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + sin_a * kx + (1 - cos_a) * kx @ kx




#: the arrays an actuator fault writes into, in the order the service's compiled step hands them over
#: (rtsim.vehicle.car.served, served_fault_arrays): the command slots, the brake's parameters, the steering's
#: (or EPS's) parameters and state
FAULT_ARRAYS = ("commands", "brake", "steering", "steering_state")
A_COMMANDS, A_BRAKE, A_STEERING, A_STEERING_STATE = range(4)


#: started cars by (model, road, the bytes of dt, brake pressure, position, yaw, speed): (model, road, the
#: car's attributes just after its start). A batch starts many runs of one model from the same place: made
#: once (the entry holds its model and road, so their ids in the key stay theirs).
_STARTS: dict = {}


def _copied(attrs: dict) -> dict:
    """A car's attributes with its state copied: every array of its named tuples (the tyre's parameters
    excepted: the tyre file's, read only) and of its simulation's data; configs, model and road shared."""
    out = dict(attrs)
    parts = attrs["parts"]
    out["parts"] = parts._replace(**{f: getattr(parts, f).copy() for f in parts._fields if f != "tyre"})
    for name in ("states", "vd", "io"):
        t = attrs[name]
        out[name] = type(t)(*(a.copy() for a in t))
    out["_effects"] = {k: ([dict(r) for r in v] if isinstance(v, list) else dict(v))
                       for k, v in attrs["_effects"].items()}
    sim = object.__new__(type(attrs["sim"]))
    sim.__dict__.update(attrs["sim"].__dict__)
    sim.data = type(sim.data)(*(a.copy() for a in sim.data))
    out["sim"] = sim
    out["data"] = sim.data
    return out


class VehicleSim:
    """The vehicle model, its multibody state and the subsystem states, at fixed step dt (s)."""

    def __init__(self, model: VehicleModel, road: Road, dt: float = 1e-3, brake_pressure: float = 0.0,
                 position=(0.0, 0.0), yaw: float = 0.0, speed: float = 0.0, effects=None):
        """A car at `position` (m), heading `yaw` (rad), rolling straight at `speed` (m/s) with the
        powertrain in steady motion with it (D, closed throttle: the schedule's gear, the engine where the
        converter holds it; rtsim.vehicle.kit.powertrain.powertrain_state_rolling), so a start at speed has
        no transient. effects: a mapping of rtsim.vehicle.car.effects (validated) that replaces the config's
        [effects]; None keeps the config's. The start of the same model on the same road from the same
        place with the config's effects is kept per process and copied (``_STARTS``): every array
        equal bit for bit, none shared but the tyre's parameters (shared as the tyre file's)."""
        key = (id(model), id(road), np.array([dt, brake_pressure, *position, yaw, speed], dtype=float).tobytes())
        kept = _STARTS.get(key) if effects is None else None
        if kept is not None and kept[0] is model and kept[1] is road:
            self.__dict__.update(_copied(kept[2]))
            return
        self._start(model, road, dt, brake_pressure, position, yaw, speed, effects)
        if effects is None:
            if len(_STARTS) >= 16:
                _STARTS.clear()
            _STARTS[key] = (model, road, _copied(self.__dict__))

    def _start(self, model: VehicleModel, road: Road, dt: float, brake_pressure: float, position, yaw: float,
               speed: float, effects) -> None:
        self.vm = model
        self.road = road
        self.dt = float(dt)
        self.nsensor = len(model.channels.sensors)      # sensor channels (the car's, and its EPS's)
        cfg = model.config
        self.tyre = load_tir(Path(model.base) / cfg.tyres.property_file)
        self.tp = self.tyre.params
        self.bcfg = brake_config(cfg.brakes or None, "brakes")
        bp = brake_params(self.bcfg)
        bs = brake_state(bp, self.dt, pressure=brake_pressure, stuck=brake_pressure > 0 and speed == 0)
        self.ptcfg = powertrain_config(cfg.powertrain or None, "powertrain")
        pp = powertrain_params(self.ptcfg)
        mech = model.mech
        q0, qd0 = self._placed(mech.q0.copy(), position, yaw, speed)
        names = mech.coordinate_names
        w_driven = float(np.mean([qd0[names.index(f"spin_{WHEELS[i]}")] for i in model.vehicle.driven]))
        ps = powertrain_state_rolling(pp, self.dt, w_driven, throttle=0.0, selector=1.0)
        if cfg.eps is None:
            self.stcfg = steering_config(cfg.steering or None, "steering")
            sp = steering_params(self.stcfg)
            sts = steering_state(sp, self.dt)
        else:
            self.stcfg = cfg.eps
            sp = eps_params(cfg.eps)
            sts = eps_state()
        self.vd = make_vehicle_data(mech.model.nq)
        self.parts = Parts(self.tp, bp, pp, sp, neutral_params(), sm_neutral(self.nsensor))
        self.states = States(bs, ps, sts, np.zeros(EffectState.SIZE), sensor_state(self.parts.sensors))
        self._effects: dict = {}
        self.sim = Simulation(mech, self.dt, q0=q0, qd0=qd0)
        self.data = self.sim.data
        self.m = mech.model
        self.io = make_io()
        self.io.commands[CMD_BRAKE] = brake_pressure
        self._prime_drive(w_driven)
        start = cfg.effects if effects is None else effects
        if start:
            self.set_effects(start)
        else:
            self._set_sensor_model({})

    def _placed(self, q: np.ndarray, position, yaw: float, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """Design coordinates moved onto the road: yawed by `yaw`, the design ground point under the
        centre of mass put on the road surface at `position` (x, y), the car tilted to the local road
        normal, and lowered along it so that the tyres carry their static loads; velocities of a car
        rolling straight ahead at `speed` (m/s), wheels spinning at speed / rolling radius."""
        tp = self.tp
        defl = self.vm.static_loads / tp[P_VERTICAL_STIFFNESS]
        wz = self.vm.design_wheel_centre[:, 2]
        dz = float(np.mean(tp[P_UNLOADED_RADIUS] - defl - wz))
        out = np.zeros(NQUERY)
        if road_query(self.road, float(position[0]), float(position[1]), out) < 0:
            raise ConfigError(f"start position {tuple(position)} is off the road")
        n = out[Q_NX:Q_NZ + 1]
        c, s = np.cos(yaw), np.sin(yaw)
        rot = _align_z(n) @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        cg = np.array(self.vm.config.chassis.cg_m, dtype=float)
        ref = np.array([cg[0], cg[1], 0.0])
        target = np.array([position[0], position[1], out[Q_Z]]) + dz * n
        mech = self.vm.mech
        names = mech.coordinate_names
        res = q.copy()
        vel = np.zeros_like(q)
        heading = rot @ np.array([1.0, 0.0, 0.0])
        for name in {n_[:-2] for n_ in names if n_.endswith(".x")}:
            i = names.index(name + ".x")
            if name in ("chassis.u", "chassis.v", "chassis.w"):
                res[i:i + 3] = rot @ q[i:i + 3]                 # frame unit vectors rotate only
            else:
                res[i:i + 3] = rot @ (q[i:i + 3] - ref) + target
                vel[i:i + 3] = speed * heading
        for i, w in enumerate(WHEELS):
            re = float(effective_rolling_radius(tp, self.vm.static_loads[i]))
            vel[names.index(f"spin_{w}")] = speed / re
        return res, vel

    def _prime_drive(self, w_driven: float) -> None:
        """Drive torques of the steady powertrain (closed throttle, D) put in place before the first
        step, so that effects started with the car (a driveline's wound-up shafts) start from them.
        Evaluated on a copy: the powertrain state itself is left at t = 0."""
        io = self.io
        pt_in = np.zeros(PtIn.SIZE)
        pt_in[PtIn.OMEGA_LEFT] = pt_in[PtIn.OMEGA_RIGHT] = w_driven
        pt_in[PtIn.SELECTOR] = io.extra[EX_SELECTOR]
        powertrain_step(self.parts.powertrain, self.states.powertrain.copy(), pt_in, self.dt, io.pt_out)
        left, right = self.vm.vehicle.driven
        self.vd.drive[left] = io.pt_out[PO_TORQUE_LEFT]
        self.vd.drive[right] = io.pt_out[PO_TORQUE_RIGHT]

    @property
    def drawing(self):
        """How the car is drawn (rtsim.vehicle.car.drawing: the 3D scene's and the viewer's description)."""
        from .drawing import car_drawing
        return car_drawing(self.vm.config, self.vm.base)

    @property
    def effects(self) -> dict:
        """The active effects (canonical mapping of rtsim.vehicle.car.effects.validate_effects; a copy)."""
        return {k: ([dict(r) for r in v] if isinstance(v, list) else dict(v)) for k, v in self._effects.items()}

    def set_effects(self, mapping) -> None:
        """Replace the active effects by `mapping` ({} or None: the nominal model), between steps and
        without rebuilding the model. Raises ConfigError for an unknown effect or channel, a missing
        parameter or a value outside its plausible range. Effect states start from the current state:
        the brake lag at the present brake torque, the driveline nodes at the wheels with the present
        drive torque wound into the springs, the sensor history holding the present values; the states
        of effects that stay on carry on (a changed stiffness keeps the shaft torque). A changed mass or
        driveline makes the next step refactor the tangent (the factor is reused across steps)."""
        eff = validate_effects(mapping, "effects")
        cfg = self.vm.config
        unsprung = [cfg.front.unsprung_mass_kg] * 2 + [cfg.rear.unsprung_mass_kg] * 2
        fx = pack_effects(eff, self.dt, cfg.chassis.mass_kg, unsprung, -float(gravity(self.m)[2]))
        old = self.parts.effects
        lag_on = old[FX_ON] > 0.5 and old[FX_B_LAG] > 0.0 and fx[FX_B_LAG] > 0.0
        dl_on = old[FX_ON] > 0.5 and old[FX_DL] > 0.5
        if fx[FX_MASS] != old[FX_MASS] or fx[FX_DL] != old[FX_DL] or fx[FX_DL_K] != old[FX_DL_K]:
            self.data.flags[NEED_FACTOR] = 1
        fs = self.states.effects
        bp, bs = self.parts.brake, self.states.brake
        if not lag_on:
            for i in range(4):
                fs[EffectState.LAG + i] = bp[BP_GAIN + i] * bs[BS_P_FRONT if i < 2 else BS_P_REAR]
        if fx[FX_DL] > 0.5:
            for j in range(2):
                o = EffectState.DL + 3 * j
                i = self.vm.vehicle.driven[j]
                kp = self.vm.vehicle.corner_idx[i, CI_PHI]
                t, w = (fs[o + 2], fs[o + 1]) if dl_on else (float(self.vd.drive[i]), self.data.qd[kp])
                fs[o:o + 3] = (self.data.q[kp] + t / fx[FX_DL_K], w, t)
        old[:] = fx                                      # in place: holders of self.parts stay valid
        self._set_sensor_model(eff)
        self._effects = eff

    def _set_sensor_model(self, effects: dict) -> None:
        """The sensor model's parameters from the config's [sensors.channels] and the sensor effects, in
        place; its history ring kept when its length stays, else a new one holding the present values."""
        sp = sensor_params(self.vm.channels.sensor_names, self.dt, self.vm.config.sensors.channels, effects)
        ss = sensor_state(sp)
        old = self.states.sensors
        self.parts.sensors[:] = sp
        if old.shape == ss.shape and old[SensorState.SLOTS] == ss[SensorState.SLOTS]:
            old[SensorState.ON] = ss[SensorState.ON]
            return
        copy_noise_state(old, ss)                        # the noise stream carries on
        if ss[SensorState.SLOTS] > 0:
            fill_history(self.m, self.data, self.vm.vehicle, self.io.signals, self.parts.effects, ss, np.zeros(self.nsensor))
        self.states = self.states._replace(sensors=ss)

    # ---- what the HIL service's loop needs of a vehicle (rtsim.vehicle.kit.served) ----------------------
    def served(self) -> "LoopCar":
        """The car as the service's compiled step takes it: one named tuple (rtsim.vehicle.car.served, which
        registers its stages)."""
        return LoopCar(self.m, self.data, self.vm.vehicle, self.vd, self.road, self.parts, self.states, self.io)

    command_slots = COMMAND_SLOTS     # where each bus command's value goes in io.commands
    invalid_slots = INVALID_SLOTS     # where 1.0 goes while a command has no valid value
    nstate = NSTATE_OUT               # observer state channels
    eps_commands = ("motor_current_cmd",)   # bus commands that put the EPS in external mode (the ECU's)
    rider_on = False                  # no rider inside the step (its in-loop source: the scenario's driver)
    user_inputs = CAR_USER_INPUTS     # what a person may drive (the vehicle's own: set by its kind)

    def fault_actuators(self) -> dict[str, tuple[str, dict[str, tuple[tuple, ...]]]]:
        """The actuators a fault may act on (rtsim.faults): name -> (family, {fault kind: writes}); a write is
        (array: FAULT_ARRAYS index, element, mode, value) with mode "command" (a command slot: ``value``, NaN
        for the fault's value or the command at the onset), "zero" or "value" (a parameter, restored when the
        fault ends). What the car has follows from its own parts: a steer-by-wire rack motor, or an EPS with
        its motor and power stage."""
        wheels = ("fl", "fr", "rl", "rr")
        out: dict = {"throttle": ("throttle", {"stuck_throttle": ((A_COMMANDS, CMD_THROTTLE, "command", np.nan),)})}
        for i, w in enumerate(wheels):
            out[f"brake_{w}"] = ("wheel_brake", {"brake_loss": ((A_BRAKE, BP_GAIN + i, "zero", 0.0),),
                                                 "caliper_stuck": ((A_BRAKE, BP_STUCK + i, "value", 1.0),)})
        if self.has_eps:
            out["eps_motor"] = ("steering_motor", {"steering_motor_failure": ((A_STEERING, EP_KT, "zero", 0.0),)})
            out["eps_power_stage"] = ("power_stage", {"power_stage_off": (
                (A_STEERING_STATE, ES_STAGE, "zero", 0.0), (A_STEERING_STATE, ES_FAULT, "value", 1.0))})
        else:
            # the rack motor's torque limits both zero: the motor block's output (its torque) is held at 0
            out["steering_motor"] = ("steering_motor", {"steering_motor_failure": (
                (A_STEERING, SbwPar.MOTOR + LAG_LO, "zero", 0.0), (A_STEERING, SbwPar.MOTOR + LAG_HI, "zero", 0.0))})
        return out

    def raise_status(self, status: int, step: int) -> None:
        """The exception of a failed step's status."""
        self.sim._raise(status, step)

    def seed_sensor_noise(self, seed: int) -> None:
        """Restart the sensor model's noise generator at `seed` (reproducible noise)."""
        seed_noise(self.states.sensors, seed)

    def physical_sensors(self, out: np.ndarray | None = None) -> np.ndarray:
        """The physical values the sensors sense, rtsim.channels.SENSOR_NAMES order (with what model
        effects change in the sensing), before the sensor model: for applying the sensor model to a
        sampled series instead (rtsim.vehicle.kit.sensor_model.apply_to_series)."""
        out = np.zeros(self.nsensor) if out is None else out
        physical_sensors(self.m, self.data, self.vm.vehicle, self.io.signals, self.parts.effects, out)
        return out

    @property
    def has_eps(self) -> bool:
        return self.vm.config.eps is not None

    def set_assist(self, gain: float) -> None:
        """EPS: scale the assistance law (1 nominal, 0 no assistance; the motor's drive stays on)."""
        self.states.steering[ES_GAIN] = float(gain)

    def assist_off(self) -> None:
        """EPS: the safe state, power stage off (open winding, no assistance)."""
        stage_off(self.parts.steering, self.states.steering)

    def external_eps(self, on: bool = True) -> None:
        """EPS: an external controller commands the motor current (``io.commands[CMD_MOTOR_CURRENT]``,
        with ``CMD_MOTOR_INVALID`` 1.0 while it has no valid command) instead of the built-in law; the
        power stage switches on at its first valid command, off with the fault latched when its commands
        stop (``eps_fault``)."""
        external_mode(self.parts.steering, self.states.steering, on)

    @property
    def eps_fault(self) -> bool:
        """EPS: the external controller's commands stopped and the power stage is off (latched)."""
        return self.has_eps and bool(self.states.steering[ES_FAULT] > 0.5)

    @property
    def eps_stage_on(self) -> bool:
        return self.has_eps and bool(self.states.steering[ES_STAGE] > 0.5)

    def start_energy_audit(self) -> None:
        """Start the power audit (rtsim.vehicle.car.energy) at the end of the next step."""
        self.vd.audit[0] = 1.0
        self.vd.audit_e[:] = 0.0

    def set_torque_mode(self, measured: bool) -> None:
        """Drive with the measured wheel torques (io.extra) instead of the engine model."""
        self.parts.powertrain[PP_MEASURED] = 1.0 if measured else 0.0

    def step(self, n: int = 1) -> None:
        """n steps with the commands in self.io held; raises a typed SimulationError on failure."""
        status, done = vehicle_advance(self.m, self.data, self.vm.vehicle, self.vd, self.road, self.parts,
                                       self.states, self.io, self.dt, n)
        if status != OK:
            self.sim._raise(status, int(self.data.stats[0]) + 1)

    def sensors(self, out: np.ndarray | None = None) -> np.ndarray:
        """The sensor channels as the car's sensors report them, rtsim.channels.SENSOR_NAMES order: the
        physical values (with what model effects change in the sensing: the grade's tilted gravity)
        through the sensor model (the config's [sensors.channels] and the sensor effects). Noise, if
        any, is drawn at each call, from the model's own generator (`seed_sensor_noise`; seed 0 at start)."""
        out = np.zeros(self.nsensor) if out is None else out
        sensor_stage(self.m, self.data, self.vm.vehicle, self.io.signals, self.parts.effects, self.parts.sensors,
                     self.states.sensors, out)
        return out
