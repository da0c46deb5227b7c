"""Offline runs: a vehicle, a road and a scenario's driver (the scenario loaded by drivers.scenario and
handed in: the vehicle never imports its drivers), as fast as the machine allows, logged at
the scenario's output rate (column `time`, then the vehicle's sensor channels as reported, then its
state channels: the names of its channel dictionary, then the power audit's rtsim.channels.ENERGY) to
CSV or, through bridge.mcap_log, to MCAP."""
from __future__ import annotations

import csv
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from rtsim.channels import CAR, COMMANDS, ChannelDictionary
from rtsim.compile_status import CompileClock
from rtsim.errors import ConfigError, SimulationError
from rtsim.mbs.model import OK
from rtsim.model_fault import ModelFault, describe_error, force_failure, test_fault_step, test_fault_time
from rtsim.road.config import load_road

from .car.build import build_vehicle
from .car.energy import ENERGY_NAMES, energy_row
from .car.config import load_vehicle
from .car.inputs import I_BRAKE, I_STEER, I_THROTTLE, I_TORQUE_RL, I_TORQUE_RR, INPUT_NAMES, NSTATE
from .car.observer import driver_view, vehicle_state_values
from .car.sim import VehicleSim
from .car.offline_kernel import apply_commands



def columns_of(channels: ChannelDictionary) -> tuple[str, ...]:
    """CSV/MCAP columns of a run: time, the sensor channels (as reported), then the state channels that
    are not also sensor channels (the actuator states brake_pressure, throttle_angle, ... are the
    sensors' physical values) -- each name once, the vehicle's names -- then the power audit's
    (rtsim.channels.ENERGY)."""
    return ("time", *channels.sensor_names, *_state_only(channels), *ENERGY_NAMES)


def _state_only(channels: ChannelDictionary) -> list[str]:
    sensors = set(channels.sensor_names)
    return [n for n in channels.state_names if n not in sensors]


COLUMNS = columns_of(CAR)      # the rear-drive car's


@dataclass
class RunResult:
    columns: tuple[str, ...]
    data: np.ndarray          # (n, len(columns))
    wall_s: float             # s of wall time stepping, numba's compilations during the loop excluded
    steps: int
    fault: ModelFault | None = None   # the model failure that ended the run early (rows up to it)
    compile_s: float = 0.0    # s numba spent compiling kernels during the loop (0 when all were cached)
    step_s: float = 0.0       # s of wall time inside the model's steps (sim.step), compilations excluded

    def column(self, name: str) -> np.ndarray:
        return self.data[:, self.columns.index(name)]


def default_vehicle_path() -> Path:
    return Path(__file__).resolve().parents[2] / "configs" / "vehicles" / "xbw.toml"


def prepare(vehicle: str | Path | None, sc) -> tuple[VehicleSim, object]:
    """The car (argument, else the scenario's, else the default) at the start of the scenario ``sc`` (a
    loaded drivers.scenario.Scenario), and the scenario."""
    vpath = Path(vehicle) if vehicle is not None else (sc.vehicle_path or default_vehicle_path())
    cfg, base = load_vehicle(vpath)
    return sim_for(build_vehicle(cfg, base), sc), sc


def sim_for(model, sc, driver=None) -> VehicleSim:
    """The built car `model` at the scenario's start on its road, the brake at the driver's first command
    (of `driver`, reset afterwards, else of a driver of its own)."""
    road = load_road(sc.road_path)
    ini = sc.spec.initial
    own = driver is None
    driver = sc.driver() if own else driver
    first = driver.step(0.0, sc.initial_state())
    if not own:
        driver.reset()
    sim = VehicleSim(model, road, sc.dt, brake_pressure=float(first[I_BRAKE]), position=(ini.x, ini.y),
                     yaw=ini.yaw, speed=ini.speed)
    sim.road_path = sc.road_path          # what the 3D scene draws besides the mesh (OpenDRIVE road marks)
    if sc.torque_mode:
        sim.set_torque_mode(True)
    return sim


def vehicle_state(sim: VehicleSim, out: np.ndarray) -> None:
    """Speed, x, y, yaw of the centre of mass for the closed-loop drivers (rtsim.vehicle.car.inputs DriverView)."""
    driver_view(sim.data, sim.vm.vehicle, out)


def run(sim: VehicleSim, sc, progress: Callable[[float], None] | None = None,
        seed: int = 0, controller=None, driver=None) -> RunResult:
    """Run the scenario to its duration; rows at the scenario's output rate. Sensor channels are what the
    sensors report (the vehicle's sensor model: the config's [sensors.channels] and sensor effects);
    `seed` seeds its noise. A model failure ends the run: the rows up to the failure, and ``fault``
    (its step, time, reason and coordinate; rtsim.model_fault, whose test-only hook can force one).
    `controller`: a command source (rtsim.fmu.controller) driving some commands; by default the scenario's
    controller FMU (its `controller` mapping file), if it names one. `driver`: the scenario's driver
    (sc.driver()) in its reset state, else one of its own."""
    dt = sc.dt
    forced = test_fault_step(test_fault_time(), dt)
    nsteps = int(round(sc.duration / dt))
    every = max(1, int(round(1.0 / (sc.spec.output_rate * dt))))
    columns = columns_of(sim.vm.channels)
    rows = np.zeros((nsteps // every + 1, len(columns)))
    sim.start_energy_audit()            # the power audit's cumulative flows (rtsim.vehicle.car.energy)
    driver = sc.driver() if driver is None else driver
    state = np.zeros(NSTATE)
    sens = np.zeros(sim.nsensor)
    observed = np.zeros(len(sim.vm.channels.state))
    names = sim.vm.channels.state_names
    keep = np.array([names.index(n) for n in _state_only(sim.vm.channels)])
    io = sim.io
    sim.seed_sensor_noise(seed)         # the sensor model's noise, reproducible
    ctl = _Controlled(sim, sc, controller)
    t0 = time.perf_counter()
    try:
        with CompileClock() as clock:       # a first run compiles at its first step: not step time
            compiled = progress is None and ctl.source is None and getattr(driver, "car_loop", None) is not None
            if compiled:
                res = _compiled_loop(sim, driver, nsteps, every, columns, rows, state, sens, observed, keep, forced,
                                     t0)
            else:
                res = _loop(sim, sc, progress, forced, nsteps, every, columns, rows, driver, state, sens, observed,
                            keep, io, ctl, t0)
        res.wall_s, res.compile_s = max(res.wall_s - clock.seconds, 0.0), clock.seconds
        if not compiled:        # the Python loop's step timer holds the first step's compile; the cycle count does not
            res.step_s = max(res.step_s - clock.seconds, 0.0)
        return res
    finally:
        ctl.close()


def _loop(sim, sc, progress, forced, nsteps, every, columns, rows, driver, state, sens, observed, keep, io,
          ctl, t0) -> RunResult:
    dt = sc.dt
    nrow = 0
    step_s = 0.0                        # the model's steps alone (the driver and the logging are not in it)
    clock = time.perf_counter
    for n in range(nsteps + 1):
        if n % every == 0:
            _log(sim, sens, observed, keep, rows[nrow])
            nrow += 1
            if progress is not None and nrow % 50 == 0:
                progress(n / nsteps)
        if n == nsteps:
            break
        vehicle_state(sim, state)
        cmd = driver.step(sim.data.t[0] + dt, state)
        if ctl.source is not None:
            ctl.apply(n, cmd)
        apply_commands(io, cmd)
        if forced == n + 1:
            force_failure(sim)
        ts = clock()
        try:
            sim.step(1)
        except SimulationError as exc:
            wall = time.perf_counter() - t0
            return RunResult(columns, rows[:nrow], wall, n, describe_error(sim, exc, n + 1),
                             step_s=step_s + clock() - ts)
        step_s += clock() - ts
    wall = time.perf_counter() - t0
    return RunResult(columns, rows[:nrow], wall, nsteps, step_s=step_s)


_CYCLES_PER_S: list[float] = []


def _compiled_loop(sim, driver, nsteps, every, columns, rows, state, sens, observed, keep, forced,
                   t0) -> RunResult:
    """The loop of `_loop` in one compiled call, the driver's (``driver.car_loop``, drivers.car_loop: the
    same rows and fault, bit for bit), for a run without progress reports or controller; the time
    inside the steps from the cycle counter."""
    from rtsim.jit import cycles_per_second

    from .car.energy import FLOW_KEYS

    if not _CYCLES_PER_S:
        _CYCLES_PER_S.append(cycles_per_second())
    cycles = np.zeros(1, dtype=np.int64)
    status, n, nrow = driver.car_loop(sim.m, sim.data, sim.vm.vehicle, sim.vd, sim.road, sim.parts, sim.states,
                                      sim.io, sim.dt, driver.packed, driver.speed, driver.path, driver.flags, nsteps,
                                      every, rows, keep.astype(np.int64), sim.has_eps, -1 if forced is None else forced,
                                      state, driver.out, sens, observed, np.zeros(len(FLOW_KEYS)), cycles)
    wall = time.perf_counter() - t0
    step_s = float(cycles[0]) / _CYCLES_PER_S[0]
    if status != OK:
        try:
            sim.sim._raise(status, int(sim.data.stats[0]) + 1)
        except SimulationError as exc:
            return RunResult(columns, rows[:nrow], wall, n, describe_error(sim, exc, n + 1), step_s=step_s)
    return RunResult(columns, rows[:nrow], wall, nsteps, step_s=step_s)


class _Controlled:
    """A command source in the offline loop (rtsim.fmu.controller): at every `every`-th step it reads its
    input channels (the sensors as reported, else the observer's state channels), communicates, and its
    commands overwrite the driver's until its next step."""

    def __init__(self, sim: VehicleSim, sc, source):
        if source is None and getattr(sc, "mapping", None) is not None:
            from rtsim.fmu.controller import FmuController
            commands = {c.name: c.unit for c in COMMANDS}     # what the offline driver commands
            source = FmuController(sc.mapping, sim.vm.channels, commands, sc.dt)
        self.source = source
        if source is None:
            return
        ch = sim.vm.channels
        self.sim = sim
        self.every = int(round(source.step / sc.dt))
        self.sens = np.zeros(sim.nsensor)
        self.obs = np.zeros(len(ch.state))
        self.pick = [(0, ch.sensor_names.index(n)) if n in ch.sensor_names else (1, ch.state_names.index(n))
                     for n in source.inputs]
        self.reads_sensors = any(k == 0 for k, _ in self.pick)
        self.x = np.zeros(len(self.pick))
        self.slots = np.array([INPUT_NAMES.index(n) for n in source.outputs], dtype=np.int64)
        self.held = np.zeros(len(self.slots))
        source.start(float(sim.data.t[0]))

    def apply(self, n: int, cmd: np.ndarray) -> None:
        if n % self.every == 0:
            sim = self.sim
            if self.reads_sensors:
                sim.sensors(self.sens)
            vehicle_state_values(sim.data, sim.vm.vehicle, sim.vd, sim.io.signals, self.obs)
            for i, (k, j) in enumerate(self.pick):
                self.x[i] = self.sens[j] if k == 0 else self.obs[j]
            self.held[:] = self.source.communicate(float(sim.data.t[0]), self.x)
        cmd[self.slots] = self.held

    def close(self) -> None:
        if self.source is not None:
            self.source.close()


def _log(sim: VehicleSim, sens: np.ndarray, observed: np.ndarray, keep: np.ndarray, row: np.ndarray) -> None:
    """time, the sensors as reported, the observer state's channels `keep` (the service's state)."""
    sim.sensors(sens)
    row[0] = sim.data.t[0]
    ns = sens.shape[0]
    row[1:1 + ns] = sens
    vehicle_state_values(sim.data, sim.vm.vehicle, sim.vd, sim.io.signals, observed)
    n_state = len(keep)
    row[1 + ns:1 + ns + n_state] = observed[keep]
    energy_row(sim, row[1 + ns + n_state:])


def write_csv(result: RunResult, path: str | Path) -> None:
    path = Path(path)
    if path.suffix.lower() != ".csv":
        raise ConfigError(f"{path}: output format {path.suffix or '(none)'} not supported here; use .csv")
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(result.columns)
        for r in result.data:
            w.writerow([f"{v:.9g}" for v in r])
