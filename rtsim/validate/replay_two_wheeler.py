"""Replaying a two-wheeler's runs into its model (rtsim.vehicle.motorcycle), with the interface the
workflow uses for the car's Replayer (inputs, simulate, reported, wheel_radius, config, simulations).

What is an input, what is compared, and why. A motorcycle is an unstable plant: the recorded steering
torque replayed open loop capsizes it within a second or two (the capsize and weave modes grow from
any small mismatch), and a prescribed steer angle is unstable in roll too. So the replay closes the loop
the way a rider does, and the quantities a rider closes it on are the inputs:

- the **roll angle** (recorded ``roll``): a lean loop on the handlebars (the rider's inner loop,
  drivers.rider) makes the model follow it, tau = p (phi_d - phi) + d (phi_d' - phi') + I - c delta'
  with I' = i (phi_d - phi); phi_d is the recorded roll smoothed and phi_d' its derivative, both by a local quadratic
  fit over `ROLL_RATE_WINDOW` s (the stiff loop would otherwise follow the roll sensor's noise and
  shake the handlebars: on straight runs with 1 mrad of noise the model's roll rate came out twice the
  data's). The loop lags its reference (about 70 ms here), so the reference is the recorded roll
  advanced by that lag (`steering_command`; on a noise-free 3 m lane change at 18 m/s: roll error
  0.026 -> 0.009 rad RMS, yaw rate 0.045 -> 0.022 rad/s, roll rate 0.082 -> 0.033 rad/s; the steering
  torque's error grows, 3.5 -> 4.1 N m);
- the **speed**, through the recorded actuator outputs: throttle opening ``throttle`` (through the
  vehicle's engine and gearbox) and the caliper pressures ``brake_pressure_front`` / ``_rear`` (as
  the actuators' outputs they act directly; no actuator lag is applied twice).

Everything else is compared (its validation profile, rtsim.vehicle.motorcycle.validation): the steering
torque the lean loop needs and the steer angle it gives, yaw, roll and pitch rates, the accelerations,
wheel speeds, fork and shock travel, pitch. The rider's demands (``rider_*``) equal the actuators' outputs without an ECU and
are neither replayed nor compared. The lean loop is not the field rider: its torque differs from the
rider's where the roll is tracked imperfectly (fast roll transients), which is structural mismatch the
workflow reports as such; in steady lean both give the torque the physics needs.

Start: the model settled upright at rest on its suspension (static pose, with the effects under test:
an added mass sags it), then rolling straight at the speed the recorded front wheel speed gives at grid
time 0 (the value at 0 of a quadratic fitted over the first `START_WINDOW` s: the noise of a single
sample stays out) through the loaded tyre's rolling radius (measured once on the model coasting).
The first sample is taken after one grid interval with the first inputs held (the sensors need the
accelerations of a step; the state at grid time 0 is that much advanced). A run must start upright
(|roll| below `START_ROLL`); the lean loop takes the recorded roll from there.

Step: the fits run at the model's step `dt` too (the workflow's coarser `fit_dt` is not used): at 2 ms the
two-wheeler's brakes (a smooth Coulomb law of the wheel's slip against its carrier) and tyres act
differently enough to be mistaken for an effect (on seven braking runs replayed at 2 ms instead of 1 ms:
accel_x RMS error 0.22 instead of 0.06 m/s^2, front wheel speed 0.9 rad/s low at the end, a fitted
brake_friction of 0.89 on data without any effect).

Effects (rtsim.vehicle.motorcycle.effects) change the model through its parameters only: an added
mass or a grade rebuilds the model (10 ms) and its static pose (cached per value; the IMU then reads
the model's tilted gravity; `_tilt` turns its pitch to the true vertical), brake and tyre
scales change the parameter arrays of that simulation; the stepping loop is one compiled kernel
(`_replay`) over the model's arrays, no Python per step. A fall (roll past 70 deg, both tyres off the
road) or a failed step ends the simulation with a SimulationError naming the run time: the workflow
reports it per run and goes on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from rtsim.errors import ConfigError, SimulationError
from rtsim.jit import kernel
from rtsim.mbs.model import EARTH_GRAVITY
from rtsim.vehicle.kit.sensor_model import apply_to_series, neutral_params, sensor_params
from rtsim.vehicle.kit.tyre.two_wheel import TW_CA, TW_CG
from rtsim.vehicle.motorcycle.build import build_motorcycle
from rtsim.vehicle.motorcycle.config import load_motorcycle
from rtsim.vehicle.motorcycle.layout import K_PHI_F
from rtsim.vehicle.motorcycle.plant import (C_ASSIST_INVALID, C_BRAKE_FRONT, C_BRAKE_FRONT_INVALID, C_BRAKE_REAR,
                                            C_BRAKE_REAR_INVALID,
                                            C_THROTTLE, C_THROTTLE_INVALID, FELL, NCOMMAND, PP_BRAKE_GAIN_F,
                                            PP_BRAKE_GAIN_R, S_PITCH, PlantIO,
                                            PlantParams, make_plant, plant_sensors,
                                            plant_step, plant_view)
from rtsim.vehicle.motorcycle.sim import TwoWheelerSim, static_pose
from rtsim.vehicle.motorcycle.step import TO_FZ
from rtsim.vehicle.registry import open_vehicle
from drivers.rider import RO_TORQUE, RV_DELTADOT, RV_PHI, RV_PHIDOT

from .benchmark import Benchmark
from .effectset import Effect, from_mapping
from .replay import InputCache
from .signals import wheel_speed as smooth_rate

START_WINDOW = 0.2       # s: the start speed is fitted over this much of the recording
START_ROLL = 0.1         # rad: a run must start with less lean than this
ROLL_RATE_WINDOW = 0.1   # s: window of the recorded roll's differentiation
SETTLE = 1.5             # s: static pose settling with the effects under test
PROBE_SPEED = 15.0       # m/s: coasting straight at this speed gives the front wheel's spin per unit speed
PROBE_TIME = 0.3         # s
# lean loop gains (the rider's inner loop, stiffer than a person's: the replay should follow the recorded
# roll closely; with the reference rate fed forward there is no lag to hide)
P_ROLL = 400.0           # N m/rad
D_ROLL = 60.0            # N m s/rad
I_ROLL = 400.0           # N m/(rad s)
I_MAX = 40.0             # N m
D_STEER = 0.0            # N m s/rad
MAX_TORQUE = 150.0       # N m

MAX_LEAD = 0.15          # s: longest lag of the lean loop the reference's advance allows for

INPUT_CHANNELS = ("roll", "throttle", "brake_pressure_front", "brake_pressure_rear")


@dataclass
class TwoWheelerInputs:
    """The recorded inputs on the comparison grid and the start state."""
    t: np.ndarray                      # grid, s
    roll: np.ndarray                   # rad, followed by the lean loop
    roll_rate: np.ndarray              # rad/s, its smoothed derivative
    throttle: np.ndarray               # 0..1, actuator output
    brake_front: np.ndarray            # kPa, caliper pressure
    brake_rear: np.ndarray             # kPa
    speed0: float                      # m/s
    mode: str
    channels: tuple = INPUT_CHANNELS
    effects: list = field(default_factory=list)        # the config's effects: the model the lead is found on
    lead: dict = field(default_factory=dict)           # model step (s) -> the lean loop's lag (grid samples)
    reference: "TwoWheelerInputs | None" = None        # a run's: the mean inputs (their lead is used)
    # the car's ReplayInputs fields the report reads: the two-wheeler has no steering matching
    brake: None = None
    torque_rl: None = None
    torque_rr: None = None
    steer: None = None
    steer_error: dict = field(default_factory=dict)
    steer_lead: dict = field(default_factory=dict)


@kernel
def _tilt(grade, row):
    """The inclinometer's view of a grade: the plant's pitch is the rear frame's from the model's z axis,
    the true vertical is tilted by the grade's angle (grade[0], rad). (The IMU's specific force needs no
    correction: it reads the model's own, tilted, gravity: rtsim.vehicle.kit.imu.)"""
    row[S_PITCH] -= grade[0]


@kernel
def _replay(m, d, veh, vd, parts, io, h, sub, roll, roll_rate, thr, bf, br, gains, grade, out):
    """Step the two-wheeler over the grid: in each grid interval k the inputs at the interval's mean
    (throttle, pressures as valid bus commands; the lean loop's torque as the rider's) for `sub` steps of
    h s; sensors into out[k + 1]. Returns (status, k): 0 when done, else the plant's status and the interval."""
    view, ro = vd.rider_view, vd.rider_out
    cmd = io.commands
    p, dd, ki, imax, cs, tmax = gains[0], gains[1], gains[2], gains[3], gains[4], gains[5]
    integ = 0.0
    n = roll.shape[0]
    cmd[C_THROTTLE] = max(0.0, thr[0])
    cmd[C_BRAKE_FRONT] = max(0.0, bf[0])
    cmd[C_BRAKE_REAR] = max(0.0, br[0])
    for j in range(sub):                 # one interval with the first inputs: the sensors need a step's accelerations
        plant_view(d, parts.idx, veh.pp, view)
        e = roll[0] - view[RV_PHI]
        ro[RO_TORQUE] = min(max(p * e + dd * (roll_rate[0] - view[RV_PHIDOT]) - cs * view[RV_DELTADOT], -tmax), tmax)
        status = plant_step(m, d, veh, vd, parts, io, h)
        if status != 0:
            return status, 0
    plant_sensors(d, parts.idx, parts.par, veh.pp, vd.inp, out[0])
    if grade[0] != 0.0:
        _tilt(grade, out[0])
    for k in range(n - 1):
        cmd[C_THROTTLE] = max(0.0, 0.5 * (thr[k] + thr[k + 1]))
        cmd[C_BRAKE_FRONT] = max(0.0, 0.5 * (bf[k] + bf[k + 1]))
        cmd[C_BRAKE_REAR] = max(0.0, 0.5 * (br[k] + br[k + 1]))
        for j in range(sub):
            a = (j + 0.5) / sub
            phi_d = roll[k] + a * (roll[k + 1] - roll[k])
            rate_d = roll_rate[k] + a * (roll_rate[k + 1] - roll_rate[k])
            plant_view(d, parts.idx, veh.pp, view)
            e = phi_d - view[RV_PHI]
            integ = min(max(integ + ki * e * h, -imax), imax)
            tau = p * e + dd * (rate_d - view[RV_PHIDOT]) + integ - cs * view[RV_DELTADOT]
            ro[RO_TORQUE] = min(max(tau, -tmax), tmax)
            status = plant_step(m, d, veh, vd, parts, io, h)
            if status != 0:
                return status, k
        plant_sensors(d, parts.idx, parts.par, veh.pp, vd.inp, out[k + 1])
        if grade[0] != 0.0:
            _tilt(grade, out[k + 1])
    return 0, n


def _start_rate(t: np.ndarray, w: np.ndarray) -> float:
    k = int(np.searchsorted(t, START_WINDOW, side="right"))
    return float(np.polyfit(t[:k], w[:k], 2)[2]) if k >= 5 else float(w[0])


class TwoWheelerReplayer(InputCache):
    """The two-wheeler's model, rebuilt per effect set where the effect needs it (module docstring)."""

    def __init__(self, vehicle: str | Path, road: str | Path | None = None, dt: float = 1e-3,
                 fit_dt: float = 5e-3):
        self.vehicle_path = Path(vehicle)
        self.profile = open_vehicle(self.vehicle_path).validation     # the vehicle's validation profile
        self.config, self.base = load_motorcycle(self.vehicle_path)
        if self.config.tyres.model == "knife_edge":
            raise ConfigError(f"{self.vehicle_path}: knife-edge wheels have no tyre forces to validate; use a "
                              "slip tyre model")
        self.road_path = Path(road) if road is not None else None
        self.dt = float(dt)
        self.fit_dt = self.dt             # fits at the model's own step (module docstring: not fit_dt)
        self.simulations = 0
        self._models: dict = {}
        self._cache: dict = {}
        mm = self._model(0.0, 0.0, self.dt)[0]
        self.model = mm
        self.sensor_names = self.profile.sensor_names
        self.wheel_radius = float(self.config.front_wheel.radius_m)
        q, loads = self._model(0.0, 0.0, self.dt)[1:]
        probe = TwoWheelerSim(mm, dt=self.dt, speed=PROBE_SPEED, q=q)
        probe.parts.tyre[:, TO_FZ] = loads
        probe.run(PROBE_TIME)
        # rad/s of the front wheel per m/s rolling freely: the loaded tyre's effective rolling radius
        self._spin_per_speed = float(probe.data.qd[mm.bike.idx[K_PHI_F]]) / probe.velocity[0]

    # ---- the model with an effect set ------------------------------------------------------------------
    def _model(self, added_mass: float, grade: float, dt: float):
        """(model, settled pose, its tyre loads) for an added mass (kg) and grade, cached."""
        key = (round(added_mass, 9), round(grade, 12), dt)
        if key not in self._models:
            cfg = self.config
            if added_mass:
                r = cfg.rider
                cfg = cfg.model_copy(update={"rider": r.model_copy(update={"mass_kg": r.mass_kg + added_mass})})
            a = math.atan(grade)
            g = EARTH_GRAVITY
            mm = build_motorcycle(cfg, self.base, gravity=(-g * math.sin(a), 0.0, -g * math.cos(a)))
            q, loads = static_pose(mm, seconds=SETTLE, dt=dt)
            if len(self._models) > 64:
                self._models.clear()
            self._models[key] = (mm, q, loads)
        return self._models[key]

    # ---- inputs -------------------------------------------------------------------------------------
    def steering_command(self, inp: TwoWheelerInputs, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The lean loop's roll reference and its rate (grid) at step dt: the recorded ones advanced by
        the loop's lag, found once on the mean inputs (the shift that best aligns the model's roll rate,
        replayed with the recorded reference, with the recorded roll's; at most `MAX_LEAD`) and used for every run.
        The workflow prepares each run's inputs through this hook (the car's steering matching)."""
        ref = inp.reference if inp.reference is not None else inp
        if dt not in ref.lead:
            from .replay import _delay
            dtg = float(ref.t[1] - ref.t[0])
            y = smooth_rate(self._run(ref, ref.effects, dt, ref.roll, ref.roll_rate)["roll"], dtg, ROLL_RATE_WINDOW)
            ref.lead[dt] = _delay(ref.roll_rate, y, int(math.ceil(MAX_LEAD / dtg)))
        d = ref.lead[dt]
        inp.lead[dt] = d
        if d == 0:
            return inp.roll, inp.roll_rate
        return (np.concatenate([inp.roll[d:], np.full(d, inp.roll[-1])]),
                np.concatenate([inp.roll_rate[d:], np.zeros(d)]))

    def _inputs(self, bench: Benchmark, run: int | None) -> TwoWheelerInputs:
        def get(c, default=None):
            if c not in bench.values:
                return default
            v = bench.values[c]
            return bench.mean(c) if run is None or run >= v.shape[0] else v[run]
        t = bench.t
        roll = get("roll")
        if roll is None:
            raise ConfigError("the two-wheeler's runs carry no roll channel: the replay follows the recorded roll "
                              "(an unstable plant cannot be replayed open loop)")
        if abs(float(roll[0])) > START_ROLL:
            raise ConfigError(f"the runs start leaning {math.degrees(float(roll[0])):.1f} deg: the two-wheeler's "
                              f"replay starts upright (|roll| < {math.degrees(START_ROLL):.0f} deg)")
        zero = np.zeros_like(t)
        thr, bf, br = get("throttle", zero), get("brake_pressure_front", zero), get("brake_pressure_rear", zero)
        w = get("wheel_speed_front")
        if w is None:
            w = get("wheel_speed_rear")
        if w is None:
            raise ConfigError("the two-wheeler's runs carry no wheel speed: the start speed is unknown")
        speed0 = max(0.0, _start_rate(t, w) / self._spin_per_speed)
        dtg = float(t[1] - t[0])
        w = max(int(round(ROLL_RATE_WINDOW / dtg)) | 1, 5)
        if roll.size > w:                  # the loop follows the roll, not its sensor noise
            roll = savgol_filter(roll, w, 2, mode="interp")
        rate = smooth_rate(roll, dtg, ROLL_RATE_WINDOW)
        have = [c for c in INPUT_CHANNELS if c in bench.values]
        mode = ("recorded roll followed by a lean loop on the handlebars; " +
                ", ".join(c for c in have if c != "roll") + " as recorded (actuator outputs)")
        return TwoWheelerInputs(t, np.asarray(roll, float), rate, np.asarray(thr, float), np.asarray(bf, float),
                                np.asarray(br, float), speed0, mode,
                                effects=from_mapping(getattr(self.config, "effects", None)),
                                reference=None if run is None else self.inputs(bench))

    # ---- simulation ---------------------------------------------------------------------------------
    def simulate(self, inp: TwoWheelerInputs, effects: list[Effect], fit: bool = False,
                 dt: float | None = None) -> dict[str, np.ndarray]:
        """The physical values of the sensor channels on the grid with the model effects of `effects`, at
        the step `dt` if given, else at the model's own (fits too: module docstring)."""
        if dt is None:
            dt = self.fit_step(float(inp.t[1] - inp.t[0])) if fit else self.dt
        return self._run(inp, effects, dt, *self.steering_command(inp, dt))

    def fit_step(self, grid: float) -> float:
        """The step of the candidate fits: the model's own (module docstring)."""
        return self.fit_dt

    def _run(self, inp: TwoWheelerInputs, effects: list[Effect], dt: float, roll: np.ndarray,
             roll_rate: np.ndarray) -> dict[str, np.ndarray]:
        """One replay at step dt with the lean loop's reference `roll` (rad) and its rate (rad/s)."""
        vals = {e.name: e.values() for e in effects if e.kind == "model"}
        mm, q, loads = self._model(vals.get("mass", {}).get("added_mass", 0.0),
                                   vals.get("road_grade", {}).get("grade", 0.0), dt)
        sim = TwoWheelerSim(mm, dt=dt, speed=inp.speed0, q=q)
        sim.parts.tyre[:, TO_FZ] = loads
        veh, vd = make_plant(mm, rider_on=False)
        if "brake_friction" in vals:
            s = vals["brake_friction"]["scale"]
            veh.pp[PP_BRAKE_GAIN_F] *= s
            veh.pp[PP_BRAKE_GAIN_R] *= s
        if "tyre_cornering_stiffness" in vals:
            sim.parts.tp[:, TW_CA] *= vals["tyre_cornering_stiffness"]["scale"]
        if "tyre_camber_stiffness" in vals:
            sim.parts.tp[:, TW_CG] *= vals["tyre_camber_stiffness"]["scale"]
        cmd = np.zeros(NCOMMAND)
        for slot in (C_THROTTLE_INVALID, C_BRAKE_FRONT_INVALID, C_BRAKE_REAR_INVALID):
            cmd[slot] = 0.0                          # the recorded actuator outputs act as valid commands
        cmd[C_ASSIST_INVALID] = 1.0                  # no assist torque
        t = inp.t
        dtg = float(t[1] - t[0])
        sub = int(round(dtg / dt))
        if sub < 1 or abs(sub * dt - dtg) > 1e-9 * dtg:
            raise ConfigError(f"grid step {dtg} s is not a multiple of the model step {dt} s")
        out = np.zeros((t.size, len(self.sensor_names)))
        gains = np.array([P_ROLL, D_ROLL, I_ROLL, I_MAX, D_STEER, MAX_TORQUE])
        a = math.atan(vals.get("road_grade", {}).get("grade", 0.0))
        grade = np.array([a])
        status, k = _replay(sim.model, sim.data, PlantParams(veh.pp, veh.ep), vd, sim.parts, PlantIO(cmd), dt, sub,
                            roll, roll_rate, inp.throttle, inp.brake_front, inp.brake_rear, gains, grade, out)
        self.simulations += 1
        if status != 0:
            what = "fell (roll past 70 deg or both tyres off the road)" if status == FELL else \
                f"step failed (status {status})"
            raise SimulationError(f"{self.config.id}: the replay {what} at t = {float(t[min(k + 1, t.size - 1)]):.2f} s "
                                  "of the grid while following the recorded roll", status, float(t[min(k, t.size - 1)]))
        return {name: out[:, i].copy() for i, name in enumerate(self.sensor_names)}

    def reported(self, raw: dict[str, np.ndarray], t: np.ndarray, effects: list[Effect]) -> dict[str, np.ndarray]:
        """What the sensors report of `raw`: the sensor model with the sensor effects of `effects`."""
        dtg = float(t[1] - t[0])
        mapping: dict[str, list] = {}
        for e in effects:
            if e.kind == "sensor" and e.channel in raw:
                mapping.setdefault(e.name, []).append(dict(e.params))
        p = sensor_params(self.sensor_names, dtg, None, mapping)
        active = [i for i in range(len(self.sensor_names)) if not np.array_equal(p[i], neutral_params(1)[0])
                  and self.sensor_names[i] in raw]
        if not active:
            return raw
        names = [self.sensor_names[i] for i in active]
        y = apply_to_series(p[active], np.column_stack([raw[n] for n in names]))
        out = dict(raw)
        out.update({n: y[:, k] for k, n in enumerate(names)})
        return out
