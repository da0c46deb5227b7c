"""Replaying the benchmark's mean inputs into the vehicle model (the seed's third phase): the model is
built once per workflow run, and every re-simulation starts a fresh VehicleSim on it (5 ms) with the
effect set under test (`set_effects`), so no state can leak from one simulation into the next. A
replay's grid loop is one compiled call (rtsim.validate.replay_kernel.replay_grid), and a replay is made
once per inputs, model effects, step and frame for the benchmark in hand (`Replayer._run`).

Inputs, as the seed drove its model: the measured rear-wheel torques (torque mode) and the brake line
pressure; the steering-wheel angle when the manoeuvre steers; the throttle angle when the runs carry
no torques. The measured brake pressure and throttle angle are already the actuators' outputs, so the
model's brake-pressure and throttle actuator lags are bypassed (time constant 0, no rate limit):
replaying them through the actuator would delay them twice. The measured steering-wheel angle is the
steer-by-wire actuator's output too, but its position loop (PID, motor, torsion bar loaded by the rack)
cannot be bypassed by a parameter: fed the measured angle as its command, the model's column lags it by
about 15 ms and overshoots it by 3 % (0.017 rad RMS on a +-1 rad lane change: 0.05 m/s^2 on accel_y,
three times its standard error). So the command is matched instead (`steering_command`): iterative
learning control on the model itself, u(t) <- u(t) + e(t + d) with e = measured - model angle and the
phase lead d the loop's delay (the shift that best aligns the first pass's angle with the measured one;
20 ms here), each pass one simulation with the config's effects, until the RMS error falls below
`STEER_TOL` standard errors of the measured angle's mean or stops falling (at most `STEER_PASSES`
simulations; 3 in practice: 0.017 -> 0.001 -> 0.0002 rad on that lane change). A single run takes
the mean's correction (command minus angle) added to its own measured angle, without a simulation of its
own: that leaves only the loop's response to the run's small deviation from the mean. The matched command is computed once per
replay input and model step and reused by every simulation with it (the effects under test change the
rack load, which the loop's integral absorbs). A steering wheel that moves less than `STEER_ACTIVE` is
replayed as the command unchanged.

Resampling to the integrator step: the model steps at `dt` (default 1 ms); candidate fits use the
coarser `fit_dt` (default 5 ms, or the largest step under it that divides the grid step: `fit_step`),
and the reported before/after simulations and each run's own estimate use `dt`. On the benchmark's
manoeuvres the nominal replay at 5 ms differs from the one at 1 ms by 0.5-4 % of the model's RMS
mismatch with the runs (accel_x of a stop from 20 m/s: 0.023 against 0.57 m/s^2; 2 ms: 0.006), an offset
that the nominal and the candidate replays share; a replay at 5 ms costs 0.46-0.66 of one at 2 ms on
three benchmark cases (a 2 ms step takes 1.2 Newton iterations). The inputs are held over each interval
of the comparison grid (default 10 ms) at the interval's mean value (the average of the grid values at
both ends), which is second-order accurate and adds no delay; the sensors are read at the grid times.

Initial state: at rest when the mean front wheel speed at the start is below 0.2 rad/s, else rolling
straight at the speed the front wheels give with the tyre's effective rolling radius (the start speed:
slope at 0 of a quadratic fitted to the front wheel angles over the first 0.2 s: about 0.01 rad/s of
noise on a single run of the tests' data, where the first sample of the derived speed has 0.1-0.2 and
could start a braked car rolling); the brake starts at the
measured line pressure (stuck when at rest). A car found at rest first settles for `SETTLE` s with the
first inputs held (it stood before the recording started; an added mass or a grade would otherwise
show a start-up transient the runs do not have).

Accelerometer frame (`accel_frame`, declared for a set of runs: a property of the logger, never fitted).
`body` (default): the model's IMU reports the specific force in body axes, as rtsim's sensors do; on a
rolled body accel_y reads a_y cos(roll) + g sin(roll) in a steady turn. `level`: the acceleration in the
yaw-aligned horizontal frame that inertial navigation systems also output (x forward and y left in the
ground plane under the body's heading, z up; roll and pitch removed, gravity not sensed): the body
specific force f rotated by the inclinometer angles (z-y-x Euler, rtsim.channels: roll positive right
side down, pitch positive nose down), a = Ry(pitch) Rx(roll) f, and accel_z = a_z - g (0 at rest), see
`level_frame`. In a steady turn the level accel_y is v r.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtsim.errors import ConfigError
from rtsim.mbs.model import EARTH_GRAVITY, OK
from rtsim.road.config import load_road
from rtsim.vehicle.kit.actuators import LAG_RATE, LAG_TAU
from rtsim.vehicle.kit.brake import BP_ACT
from rtsim.vehicle.car.config import load_vehicle
from rtsim.vehicle.car.step import CMD_BRAKE, CMD_STEER, CMD_THROTTLE, EX_TORQUE_LEFT, EX_TORQUE_RIGHT
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.kit.powertrain import PP_THR
from rtsim.vehicle.kit.sensor_model import apply_to_series, neutral_params, sensor_params
from rtsim.vehicle.car.sensors import NSENSOR
from rtsim.vehicle.car.sim import VehicleSim
from rtsim.vehicle.kit.tyre.magic_formula import effective_rolling_radius
from rtsim.vehicle.registry import open_vehicle

from .benchmark import Benchmark
from .data import ACCEL_FRAMES
from .effectset import Effect, from_mapping, model_mapping
from .replay_kernel import replay_grid
from .signals import DERIVED, derive_wheel_speeds

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_ROAD = ROOT / "configs" / "roads" / "flat.toml"
SETTLE = 1.0          # s
STANDSTILL_RATE = 0.2  # rad/s: front wheels slower than this at the start: the car starts at rest
START_WINDOW = 0.2    # s: the start speed is fitted over this much of the recording
STEER_ACTIVE = 0.05   # rad: a steering wheel moving less than this is replayed as the command itself
STEER_TOL = 0.1       # matched when the angle's RMS error is below this many standard errors of its mean
STEER_PASSES = 4      # simulations at most to match the steering command
STEER_FLOOR = 1e-4    # rad: matching never aims below this RMS error
STEER_MAX_LEAD = 0.1  # s: longest loop delay the matching's phase lead allows for
GRAVITY = EARTH_GRAVITY  # m/s^2, the model's gravity (down)


def level_frame(accel_x, accel_y, accel_z, roll, pitch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body-axis specific force (m/s^2) at the IMU and the body's inclinometer roll and pitch (rad, ISO
    8855: roll positive right side down, pitch positive nose down; the chassis is R = Rz(yaw) Ry(pitch)
    Rx(roll)) -> the acceleration in the yaw-aligned level frame: Ry(pitch) Rx(roll) f, gravity removed
    from the vertical (x forward, y left, z up; m/s^2)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    zr = sr * accel_y + cr * accel_z             # Rx(roll) f, its z; its y follows
    return cp * accel_x + sp * zr, cr * accel_y - sr * accel_z, -sp * accel_x + cp * zr - GRAVITY


def _start_rate(bench: Benchmark, run: int | None) -> float:
    """Mean front wheel speed (rad/s) at grid time 0: the slope at 0 of a quadratic fitted to the front
    wheel angles over the first `START_WINDOW` s (the derived speed's first sample carries the angle
    noise amplified about 80 times on a 10 ms grid), else the first sample of the derived wheel speeds."""
    def row(c):
        v = bench.values[c]
        return bench.mean(c) if run is None or run >= v.shape[0] else v[run]
    t = bench.t
    k = int(np.searchsorted(t, START_WINDOW, side="right"))
    angles = [c for c in ("wheel_angle_fl", "wheel_angle_fr") if c in bench.values]
    if angles and k >= 5:
        return float(np.mean([np.polyfit(t[:k], row(c)[:k], 2)[1] for c in angles]))
    w = [row(c)[0] for c in ("wheel_speed_fl", "wheel_speed_fr") if c in bench.values]
    return float(np.mean(w)) if w else 0.0


_EMPTY = np.zeros(0)


def _grid(x: np.ndarray | None) -> np.ndarray:
    """An input for the compiled grid loop: float64, contiguous and writable (a read-only array, as Ray's
    object store hands them out, would make the kernel compile a variant of its own), or empty when not
    driven."""
    return _EMPTY if x is None else np.require(x, np.float64, ["C", "W"])


def _delay(target: np.ndarray, y: np.ndarray, most: int) -> int:
    """Grid samples by which y lags target (0..most): the shift that aligns them best (least RMS)."""
    n = target.size
    most = max(0, min(most, n // 4))
    rms = [float(np.mean((y[s:] - target[:n - s]) ** 2)) for s in range(most + 1)]
    return int(np.argmin(rms))


@dataclass
class ReplayInputs:
    """Mean inputs on the comparison grid and the start state."""
    t: np.ndarray                       # grid, s
    brake: np.ndarray | None            # kPa, line pressure
    torque_rl: np.ndarray | None        # N m
    torque_rr: np.ndarray | None        # N m
    throttle: np.ndarray | None         # rad
    steer: np.ndarray | None            # rad, steering-wheel angle (measured)
    speed0: float                       # m/s
    mode: str                           # text: which inputs drive the model
    steer_effects: list = field(default_factory=list)   # effects of the model the steering is matched on
    steer_tol: float = STEER_FLOOR                      # rad RMS: the matching's target
    steer_cmd: dict = field(default_factory=dict)       # model step (s) -> matched steering command (grid)
    steer_error: dict = field(default_factory=dict)     # model step (s) -> RMS error left (rad)
    steer_lead: dict = field(default_factory=dict)      # model step (s) -> loop delay (grid samples)
    reference: "ReplayInputs | None" = None              # a run's: the mean inputs (first guess of matching)


class InputCache:
    """A replayer's replay inputs per benchmark and run, made once by the replayer's ``_inputs(bench,
    run)`` (a car's carry the matched steering commands, a two-wheeler's the advanced roll reference)."""

    _cache: dict

    def inputs(self, bench: Benchmark, run: int | None = None):
        """The benchmark's mean inputs and start state (or those of run number `run`); the same object
        for the same benchmark and run."""
        if getattr(self, "_cache", {}).get("bench") is not bench:
            self._cache = {"bench": bench}
        key = ("inputs", run)
        if key not in self._cache:
            self._cache[key] = self._inputs(bench, run)
        return self._cache[key]

    def prepared(self, bench: Benchmark) -> bool:
        """Whether every run's inputs of `bench` are in hand."""
        return getattr(self, "_cache", {}).get("bench") is bench and all(
            ("inputs", i) in self._cache for i in range(bench.n))

    def remember(self, bench: Benchmark, run: int | None, inp) -> None:
        """Keep inputs prepared elsewhere (e.g. matched in a worker process) for `inputs`."""
        if getattr(self, "_cache", {}).get("bench") is not bench:
            self._cache = {"bench": bench}
        self._cache[("inputs", run)] = inp


class Replayer(InputCache):
    """The vehicle model built once; `simulate` replays the inputs with a set of model effects."""

    def __init__(self, vehicle: str | Path, road: str | Path | None = None, dt: float = 1e-3,
                 fit_dt: float = 5e-3, accel_frame: str = "body"):
        self.vehicle_path = Path(vehicle)
        self.profile = open_vehicle(self.vehicle_path).validation     # the vehicle's validation profile
        self.config, base = load_vehicle(self.vehicle_path)
        self.model = build_vehicle(self.config, base)
        self.road_path = Path(road) if road is not None else DEFAULT_ROAD
        self.road = load_road(self.road_path)
        self.dt = float(dt)
        self.fit_dt = float(fit_dt)
        probe = VehicleSim(self.model, self.road, self.dt)
        self.wheel_radius = float(effective_rolling_radius(probe.tp, self.model.static_loads[0]))
        self.simulations = 0
        self._cache: dict = {}
        self.accel_frame = accel_frame

    @property
    def accel_frame(self) -> str:
        """The frame the model's accel_x/y/z are reported in: "body" or "level" (module docstring)."""
        return self._accel_frame

    @accel_frame.setter
    def accel_frame(self, frame: str) -> None:
        if frame not in ACCEL_FRAMES:
            raise ConfigError(f"accelerometer frame {frame!r}: use one of {', '.join(ACCEL_FRAMES)}")
        self._accel_frame = frame

    def _inputs(self, bench: Benchmark, run: int | None) -> ReplayInputs:
        m = {c: (bench.mean(c) if run is None else bench.values[c][run]) for c in bench.inputs}
        tq = "wheel_torque_rl" in m and "wheel_torque_rr" in m
        if not tq and "throttle_angle" not in m and "brake_pressure" not in m:
            raise ConfigError("the runs carry neither wheel torques, throttle angle nor brake pressure: the "
                              "longitudinal inputs cannot be replayed")
        parts = []
        if tq:
            parts.append("measured rear-wheel torques (torque mode)")
        elif "throttle_angle" in m:
            parts.append("throttle angle (engine model; no wheel torques recorded)")
        if "brake_pressure" in m:
            parts.append("brake line pressure")
        steer = m.get("steering_wheel_angle")
        tol = STEER_FLOOR
        if steer is not None:
            b = bench.bands["steering_wheel_angle"]
            if b.has_band:
                tol = max(STEER_FLOOR, STEER_TOL * float(np.sqrt(np.mean(b.se ** 2))))
            moving = float(np.max(np.abs(steer - steer[0]))) >= STEER_ACTIVE
            parts.append("steering-wheel angle" + (" (command matched to it through the steer-by-wire loop)"
                                                   if moving else ""))
        omega0 = _start_rate(bench, run)
        speed0 = omega0 * self.wheel_radius if abs(omega0) > STANDSTILL_RATE else 0.0
        return ReplayInputs(bench.t, m.get("brake_pressure"), m.get("wheel_torque_rl") if tq else None,
                            m.get("wheel_torque_rr") if tq else None,
                            None if tq else m.get("throttle_angle"), steer, speed0,
                            ", ".join(parts), from_mapping(getattr(self.config, "effects", None)), tol,
                            reference=None if run is None else self.inputs(bench))

    def steering_command(self, inp: ReplayInputs, dt: float) -> np.ndarray | None:
        """The steering-wheel command (grid) under which the model at step dt reproduces the measured
        angle (module docstring); computed once per inputs and step."""
        if inp.steer is None:
            return None
        if dt in inp.steer_cmd:
            return inp.steer_cmd[dt]
        target = inp.steer
        u = target.copy()
        if float(np.max(np.abs(target - target[0]))) < STEER_ACTIVE:
            inp.steer_cmd[dt], inp.steer_error[dt] = u, float("nan")
            return u
        ref = inp.reference
        lead = None
        if ref is not None and ref.steer is not None and ref.steer.shape == target.shape:
            # a run: the mean's correction carried over unchecked (no simulation); what it leaves is the
            # loop's response to the run's small deviation from the mean (well under a milliradian here)
            u = target + (self.steering_command(ref, dt) - ref.steer)
            inp.steer_cmd[dt], inp.steer_error[dt] = u, ref.steer_error.get(dt, float("nan"))
            return u
        best, best_err = u, math.inf
        for _ in range(STEER_PASSES):
            raw = self._run(inp, inp.steer_effects, dt, u)
            y = self.reported(raw, inp.t, inp.steer_effects)["steering_wheel_angle"]
            e = target - y
            err = float(np.sqrt(np.mean(e * e)))
            stalled = err > best_err / 1.5
            if err < best_err:
                best, best_err = u, err
            if err <= inp.steer_tol or stalled:
                break
            if lead is None:         # the loop's delay, from the plain replay (command = measured angle)
                lead = _delay(target, y, int(math.ceil(STEER_MAX_LEAD / float(inp.t[1] - inp.t[0]))))
                inp.steer_lead[dt] = lead
            u = u + np.concatenate([e[lead:], np.full(lead, e[-1])])
        inp.steer_cmd[dt], inp.steer_error[dt] = best, best_err
        return best

    def reported(self, raw: dict[str, np.ndarray], t: np.ndarray, effects: list[Effect]) -> dict[str, np.ndarray]:
        """What the sensors report of the physical values `raw` (channel -> samples on the uniform grid t,
        as `simulate` gives them): the vehicle's one sensor model (rtsim.vehicle.kit.sensor_model) with
        the config's [sensors.channels] and the sensor effects of `effects` (model effects ignored),
        applied once, on the grid (delays interpolated between grid samples, noise from seed 0). Sensor
        effects need no re-simulation: they change what the sensors report, not the car's motion. A
        wheel angle's scale and delay carry over to the wheel speed derived from it (a constant angle
        bias does not show in a speed). A copy of `raw` when some channel is not neutral, else `raw`."""
        dtg = float(t[1] - t[0])
        mapping: dict[str, list] = {}
        for e in effects:
            if e.kind == "sensor" and e.channel in raw:
                mapping.setdefault(e.name, []).append(dict(e.params))
        sensor_names = self.model.channels.sensor_names
        p = sensor_params(sensor_names, dtg, self.config.sensors.channels, mapping)
        active = [i for i in range(len(sensor_names)) if not np.array_equal(p[i], neutral_params(1)[0])
                  and sensor_names[i] in raw]
        if not active:
            return raw
        names = [sensor_names[i] for i in active]
        y = apply_to_series(p[active], np.column_stack([raw[n] for n in names]))
        out = dict(raw)
        out.update({n: y[:, k] for k, n in enumerate(names)})
        angles = {a: out[a] for s, a in DERIVED.items() if a in names and s not in names}
        if angles:
            out.update(derive_wheel_speeds(angles, dtg))
        return out

    def new_sim(self, inp: ReplayInputs, effects: list[Effect], dt: float) -> VehicleSim:
        p0 = float(inp.brake[0]) if inp.brake is not None else 0.0
        sim = VehicleSim(self.model, self.road, dt, brake_pressure=p0, speed=inp.speed0,
                         effects=model_mapping(effects))
        sim.parts.brake[BP_ACT + LAG_TAU] = 0.0             # measured line pressure: actuator bypassed
        sim.parts.brake[BP_ACT + LAG_RATE] = math.inf
        sim.parts.powertrain[PP_THR + LAG_TAU] = 0.0        # measured throttle angle: actuator bypassed
        sim.parts.powertrain[PP_THR + LAG_RATE] = math.inf
        if inp.torque_rl is not None:
            sim.set_torque_mode(True)
        return sim

    def simulate(self, inp: ReplayInputs, effects: list[Effect], fit: bool = False,
                 dt: float | None = None) -> dict[str, np.ndarray]:
        """The physical values of the sensor channels (and wheel speeds) of the model on the grid, with
        the model effects of `effects` switched on; what the sensors report of them is `reported`.
        At the step `dt` if given, else at fit_step (`fit`) or the model's step."""
        if dt is None:
            dt = self.fit_step(float(inp.t[1] - inp.t[0])) if fit else self.dt
        return self._run(inp, effects, dt, self.steering_command(inp, dt))

    def fit_step(self, grid: float) -> float:
        """The step of the candidate fits on a grid of `grid` s: the largest step not above fit_dt that
        divides the grid interval (10 ms and 5 ms: 5 ms; 4 ms: 4 ms; 8 ms: 4 ms), and not below dt."""
        return max(self.dt, grid / math.ceil(grid / self.fit_dt - 1e-9))

    def _run(self, inp: ReplayInputs, effects: list[Effect], dt: float, steer: np.ndarray | None) -> dict:
        """One replay at step dt with `steer` as the steering-wheel command; a replay already made with
        the same inputs, model effects, step and frame is not made again (`_memo_key`)."""
        key = self._memo_key(inp, effects, dt, steer)
        memo = self.replays()
        if key not in memo:
            memo[key] = self._replay(inp, effects, dt, steer)
        return dict(memo[key])

    def replays(self) -> dict:
        """The replays made for the benchmark in hand: digest (`_memo_key`) -> outputs. A worker process
        hands the ones it made back to the workflow (tasks.map_tasks)."""
        return self._cache.setdefault("replays", {})

    def _memo_key(self, inp: ReplayInputs, effects: list[Effect], dt: float, steer: np.ndarray | None) -> str:
        """What a replay depends on besides the model: the inputs on the grid, the start speed, the model
        effects with their exact values (sensor effects act on the readings only), the step and the
        accelerometer frame; as a digest. Replays are deterministic, so one made again would be the same
        bit for bit (a sensor effect's iteration re-screens the model effects at the same trial values;
        the last steering-matching pass is the replay the matched command then asks for)."""
        h = hashlib.sha1(repr((float(dt), float(inp.speed0), self._accel_frame,
                               model_mapping(effects))).encode())
        for x in (inp.t, inp.brake, inp.torque_rl, inp.torque_rr, inp.throttle, steer):
            h.update(b"-" if x is None else np.ascontiguousarray(x, dtype=np.float64).tobytes() + b"|")
        return h.hexdigest()

    def _replay(self, inp: ReplayInputs, effects: list[Effect], dt: float, steer: np.ndarray | None) -> dict:
        """One replay, made (see _run)."""
        sim = self.new_sim(inp, effects, dt)
        t = inp.t
        n = t.size
        dtg = float(t[1] - t[0])
        sub = int(round(dtg / dt))
        if abs(sub * dt - dtg) > 1e-9 * dtg or sub < 1:
            raise ConfigError(f"grid step {dtg} s is not a multiple of the model step {dt} s")
        out = np.zeros((n, NSENSOR))
        cmd, extra = sim.io.commands, sim.io.extra
        if inp.brake is not None:                  # the first inputs, held through the settling
            cmd[CMD_BRAKE] = max(0.0, float(inp.brake[0]))
        if inp.torque_rl is not None:
            extra[EX_TORQUE_LEFT] = float(inp.torque_rl[0])
            extra[EX_TORQUE_RIGHT] = float(inp.torque_rr[0])
        if inp.throttle is not None:
            cmd[CMD_THROTTLE] = max(0.0, float(inp.throttle[0]))
        if steer is not None:
            cmd[CMD_STEER] = float(steer[0])
        if inp.speed0 == 0.0:
            sim.step(int(round(SETTLE / dt)))
        sim.physical_sensors(out[0])
        status, _ = replay_grid(sim.m, sim.data, sim.vm.vehicle, sim.vd, sim.road, sim.parts, sim.states, sim.io,
                                sim.dt, sub, *(_grid(x) for x in (inp.brake, inp.torque_rl, inp.torque_rr,
                                                                 inp.throttle, steer)), out)
        if status != OK:
            sim.sim._raise(status, int(sim.data.stats[0]) + 1)
        self.simulations += 1
        res = {name: out[:, i].copy() for i, name in enumerate(self.model.channels.sensor_names)}
        if self._accel_frame == "level":
            res["accel_x"], res["accel_y"], res["accel_z"] = level_frame(
                res["accel_x"], res["accel_y"], res["accel_z"], res["roll"], res["pitch"])
        res.update(derive_wheel_speeds(res, dtg))
        return res
