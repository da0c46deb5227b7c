"""Rides of drawn command sequences (rtsim.robustness.commands) through the vehicle step the HIL service
uses, offline, with the outcome of each.

The step is the service's (rtsim.service.vehicles ``vehicle_advance``): for a car, its
``vehicle_step`` (rtsim.vehicle.car.step, n steps per call); for a two-wheeler, the rider's call
(``plant_rider``, when the ride has the scenario's rider) then ``plant_step`` (rtsim.vehicle.motorcycle.plant),
as the service's ``one_step`` calls them. The vehicle is placed as ``rtsim serve`` places it: a car on
the road at (2, 0) heading +x (rtsim.vehicle.car.sim.VehicleSim), a two-wheeler settled on its
suspension with the rider on (rtsim.vehicle.motorcycle.hil.TwoWheelerHil, the served scenario's rider
riding its figure-eight), rolling straight at the ride's speed. Each command period (the DBC's
``GenMsgCycleTime``) the drawn values are written into the vehicle's command slots as the watchdog
writes valid bus commands (a two-wheeler's ``*_INVALID`` slots 0: the bus's throttle and brakes replace
the rider's demands and its assist torque adds to the rider's), then the steps of that period run.

Outcomes (``RideResult.outcome``):

- ``ok``: the ride ran to its end;
- ``fell``: a two-wheeler fell (roll past rtsim.vehicle.motorcycle.sim.FALL_ROLL, or both tyres off the
  road after the start): the defined end of a ride, as in the service (status FELL), not a model failure;
- ``failed``: a model failure: the step returned a failure status (Newton, projection, factorization,
  non-finite force or state; ``failure`` holds the message with step, time and coordinate), or a
  coordinate or velocity became non-finite, or the energy bound below was broken.

Energy bound. The mechanical energy E = T + V (T = qd' M qd / 2 with the multibody mass matrix, which
holds every body's and every wheel's inertia; V = -Q_g' q, gravity's potential) can grow only by the work
of the drive and of the actuators; tyres, brakes, dampers and friction only take energy out, and the
springs (suspension, tyres, bump stops) give back at most what they held. So at every command period
(a car's held commands: every ``CHECK_S``)

    E(t) - E(0) <= W_drive(t) + E_store,

with W_drive(t) = P_max t for an engine (its peak power at the crank, which no gearbox or converter
multiplies; the two-wheeler's ideal drive of a vehicle without an engine: the sum of
``MAX_WHEEL_TORQUE`` |omega_rear| dt, what its drive can do at the wheel speed it had), plus for a
two-wheeler the steering torques' work, the sum of (|rider's torque| + |assist torque|) |steer rate| dt
(each command period's torques with the mean of the steer rate's magnitude at its start and end), and E_store the
energy the vehicle can release besides: the engine's flywheel spun down from its rev limit (J w^2 / 2,
a car's), the springs and actuators relaxing (the vehicle's weight through 0.25 m: more than all its
suspension and tyre travel) and 1 % of the start's kinetic energy for the integrator's tolerances.
A car's steering actuator (the steer-by-wire or EPS motor) is not summed on its own: its work over a
ride, of the order of a kilowatt for a few seconds, lies well inside the flywheel's share of E_store
(about 35 kJ for the shipped cars). ``energy_ratio`` is max over the ride of
(E(t) - E(0)) / (W_drive(t) + E_store): at most 1 holds the bound.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtsim.errors import SimulationError
from rtsim.jit import kernel
from rtsim.mbs.model import OK
from rtsim.vehicle.motorcycle.plant import plant_rider, plant_step

from .commands import CommandSpace, Ride, command_space, expand

ROOT = Path(__file__).resolve().parents[2]
ROADS_DIR = ROOT / "configs" / "roads"
VEHICLES_DIR = ROOT / "configs" / "vehicles"
START_XY = (2.0, 0.0)              # m: where a car starts (on every shipped road, the campus lane's too)
SPRING_DROP_M = 0.25               # m: the weight's drop that bounds the springs' and actuators' release
TOLERANCE_SHARE = 0.01             # of the start's kinetic energy: the integrator's tolerances
CHECK_S = 0.01                     # s: the longest a car runs between the checks (state, energy)
NO_ENGINE_TOP_SPEED = 10.0         # m/s: a vehicle without an engine (the Whipple bicycle, ridden by its
                                   # rider's legs): the benchmark's speed range (Meijaard et al. 2007, 0-10 m/s)


def shipped_vehicles() -> list[Path]:
    return sorted(VEHICLES_DIR.glob("*.toml"))


def shipped_roads() -> list[Path]:
    return sorted(ROADS_DIR.glob("*.toml"))


@dataclass
class RideResult:
    """What a ride ended in (module docstring); ``t`` the simulated time reached, s."""
    outcome: str
    t: float
    steps: int
    energy_ratio: float
    finite: bool
    failure: str = ""
    error_type: str = ""
    wall_s: float = 0.0

    @property
    def failed(self) -> bool:
        return self.outcome == "failed"


@kernel
def two_wheeler_advance(m, d, veh, vd, rider, parts, io, h, n, rider_on):
    """n steps of the served two-wheeler as the service's one_step makes them: the rider's call (if
    ``rider_on``), then plant_step. Returns (status, steps done)."""
    for k in range(n):
        if rider_on:
            plant_rider(d, parts.idx, veh.pp, rider, vd.rider_view, vd.rider_out)
        status = plant_step(m, d, veh, vd, parts, io, h)
        if status != 0:
            return status, k
    return 0, n


class FuzzTarget:
    """One vehicle file, built once, ready to ride drawn sequences on the shipped roads it can run on."""

    def __init__(self, vehicle: str | Path, dt: float = 1e-3):
        from rtsim.vehicle.registry import open_vehicle

        self.path = Path(vehicle)
        self.dt = float(dt)
        self.kind = open_vehicle(self.path).name      # (its per-kind set-up: still branches, see below)
        self.skipped_roads: dict[str, str] = {}
        if self.kind == "two_wheeler":
            self._init_two_wheeler()
        else:
            self._init_car()
        self.steps_per_frame = max(1, int(round(self.space.frame_s / self.dt)))

    @property
    def name(self) -> str:
        return self.path.stem

    # ---- set-up ------------------------------------------------------------------------------------
    def _init_car(self) -> None:
        from rtsim.vehicle.car.build import build_vehicle
        from rtsim.vehicle.car.config import load_vehicle
        from rtsim.vehicle.car.step import COMMAND_SLOTS
        from rtsim.vehicle.kit.powertrain import describe, powertrain_config

        cfg, base = load_vehicle(self.path)
        self.model = build_vehicle(cfg, base)
        self.eps = cfg.eps is not None
        dbc = (Path(base) / cfg.interface.dbc).resolve()
        # the EPS car's driver (the scenario's, in the loop) writes the commands its DBC does not carry
        drivers = tuple(n for n in COMMAND_SLOTS if n != "motor_current_cmd") if self.eps else ()
        self.space: CommandSpace = command_space(dbc, drivers)
        self.slots = np.array([COMMAND_SLOTS[c.name] for c in self.space.commands], dtype=np.int64)
        pt = powertrain_config(cfg.powertrain or None, "powertrain")
        e, g = pt.engine, pt.gearbox
        self.top_speed = e.rev_limit / (g.ratios[-1] * g.final_drive) * g.wheel_radius
        self.p_max = describe(pt)["peak_power_kW"] * 1e3
        self.e_flywheel = 0.5 * e.inertia * e.rev_limit ** 2
        self.roads = tuple(p.stem for p in shipped_roads())
        self._road_cache: dict = {}

    def _init_two_wheeler(self) -> None:
        from drivers.rider import P_TYRE_LEAN
        from drivers.scenario import load_scenario
        from rtsim.road.config import FlatRoadConfig, read_road_config
        from rtsim.service.config import TWO_WHEELER_SCENARIO
        from rtsim.vehicle.motorcycle.build import build_motorcycle
        from rtsim.vehicle.motorcycle.config import load_motorcycle
        from rtsim.vehicle.motorcycle.plant import COMMAND_SLOTS, INVALID_SLOTS, MAX_WHEEL_TORQUE
        from rtsim.vehicle.motorcycle.ride import tyre_lean_ratio
        from rtsim.vehicle.motorcycle.sim import static_pose

        cfg, base = load_motorcycle(self.path)
        self.mm = build_motorcycle(cfg, base)
        self.q_static = static_pose(self.mm)[0]
        self.dbc = (Path(base) / cfg.interface.dbc).resolve()
        self.space = command_space(self.dbc)
        self.slots = np.array([COMMAND_SLOTS[c.name] for c in self.space.commands], dtype=np.int64)
        self.invalid = np.array([INVALID_SLOTS[c.name] for c in self.space.commands], dtype=np.int64)
        self.eps = False
        self.scenario = load_scenario(TWO_WHEELER_SCENARIO, check_files=True)
        self.tyre_lean = tyre_lean_ratio(self.mm)
        self.p_tyre_lean = P_TYRE_LEAN
        pt = cfg.powertrain
        if pt is not None:
            rpm = 2.0 * math.pi / 60.0
            self.top_speed = (pt.rev_limit_rpm * rpm / (pt.primary_ratio * pt.gear_ratios[-1] * cfg.final_ratio)
                              * cfg.rear_wheel.radius_m)
            self.p_max = max(t * w * rpm for t, w in zip(pt.full_load_torque_nm, pt.engine_speed_rpm))
            self.wheel_torque = 0.0
        else:
            self.top_speed = NO_ENGINE_TOP_SPEED
            self.p_max = 0.0
            # the ideal drive acts through the chain; a vehicle without one (the Whipple bicycle) has no drive
            self.wheel_torque = MAX_WHEEL_TORQUE if cfg.chain is not None else 0.0
        self.e_flywheel = 0.0       # the engine's rotating inertia is not modelled (engine.py)
        roads = []
        for p in shipped_roads():
            rc = read_road_config(p)
            if isinstance(rc, FlatRoadConfig) and rc.height == 0.0:
                roads.append(p.stem)
            else:   # the service refuses these too (rtsim.vehicle.motorcycle.kind.TwoWheelerKind.service_sim)
                self.skipped_roads[p.stem] = "a two-wheeler's tyres run on the plane z = 0 only"
        self.roads = tuple(roads)

    # ---- one ride ----------------------------------------------------------------------------------
    def _road(self, name: str):
        from rtsim.road.config import load_road

        if name not in self._road_cache:
            self._road_cache[name] = load_road(ROADS_DIR / f"{name}.toml")
        return self._road_cache[name]

    def new_sim(self, ride: Ride):
        """The vehicle at the ride's start (module docstring)."""
        if self.kind == "two_wheeler":
            from rtsim.road.config import read_road_config
            from rtsim.vehicle.motorcycle.hil import TwoWheelerHil

            mu = read_road_config(ROADS_DIR / f"{ride.road}.toml").mu
            r = None
            if ride.rider:
                r = self.scenario.rider()
                r.par[self.p_tyre_lean] = self.tyre_lean
            sim = TwoWheelerHil(self.mm, self.dbc, self.q_static, self.dt, speed=ride.speed, rider=r, mu=mu)
            sim.io.commands[self.invalid] = 0.0          # every bus command valid from the start
            return sim
        from rtsim.vehicle.car.sim import VehicleSim
        from rtsim.vehicle.car.step import CMD_MOTOR_INVALID

        sim = VehicleSim(self.model, self._road(ride.road), self.dt, brake_pressure=0.0, position=START_XY,
                         speed=ride.speed)
        if self.eps and ride.eps_external:
            sim.external_eps(True)
            sim.io.commands[CMD_MOTOR_INVALID] = 0.0
        return sim

    def _mechanics(self, sim):
        s = sim.tw.sim if self.kind == "two_wheeler" else sim.sim
        return s.mech.mass_dense, s.model.q_grav

    def ride(self, ride: Ride) -> RideResult:
        """Run the ride (module docstring) and return its outcome."""
        if ride.road not in self.roads:
            raise ValueError(f"{self.name}: road {ride.road!r} is not one it runs on ({', '.join(self.roads)})")
        t0 = time.perf_counter()
        sim = self.new_sim(ride)
        table = expand(ride.segments, self.space.rest())
        if ride.eps_external is False and self.eps:      # the built-in law: the bus's current is not read
            keep = [i for i, c in enumerate(self.space.commands) if c.source != "bus"]
        else:
            keep = list(range(len(self.space.commands)))
        slots = self.slots[keep]
        table = table[:, keep]
        mass, q_grav = self._mechanics(sim)
        d = sim.data
        m_g = -float(np.sum(q_grav))                      # the weight, N (gravity's generalized forces)

        def energy() -> float:
            qd = d.qd
            return 0.5 * float(qd @ (mass @ qd)) - float(q_grav @ d.q)

        e0 = energy()
        t_kin0 = 0.5 * float(d.qd @ (mass @ d.qd))
        store = self.e_flywheel + m_g * SPRING_DROP_M + TOLERANCE_SHARE * t_kin0
        w_drive = 0.0
        ratio = 0.0
        n = self.steps_per_frame
        steps = 0
        outcome, failure, etype = "ok", "", ""
        two = self.kind == "two_wheeler"
        if two:
            from rtsim.vehicle.motorcycle.layout import K_DELTA, K_PHI_R, K_THETA
            from rtsim.vehicle.motorcycle.plant import IN_ASSIST, IN_RIDER_TORQUE
            from rtsim.vehicle.motorcycle.plant import FELL
            v = sim.served()
            m, veh, vd, rider, parts, io = v.m, v.params, v.plant, v.rider, v.parts, v.io
            k_rear, k_arm, k_steer = parts.idx[K_PHI_R], parts.idx[K_THETA], parts.idx[K_DELTA]
        # a car's held commands run in one call for up to CHECK_S (the checks at its end); a two-wheeler's
        # each command period (its drive and steering work are summed per period)
        runs = [(row, 1) for row in table] if two else _runs(table, max(1, int(round(CHECK_S / self.space.frame_s))))
        for row, frames in runs:
            sim.io.commands[slots] = row
            if two:
                w_before = abs(d.qd[k_rear] - (d.qd[k_arm] if k_arm >= 0 else 0.0))
                s_before = abs(d.qd[k_steer])
                status, done = two_wheeler_advance(m, d, veh, vd, rider, parts, io, self.dt, n, ride.rider)
                steps += int(done)
                if status == FELL:
                    outcome = "fell"
                    break
                if status != OK:
                    try:
                        sim.raise_status(int(status), steps + 1)
                    except SimulationError as exc:
                        outcome, failure, etype = "failed", str(exc), type(exc).__name__
                    break
                w_after = abs(d.qd[k_rear] - (d.qd[k_arm] if k_arm >= 0 else 0.0))
                w_drive += self.wheel_torque * 0.5 * (w_before + w_after) * n * self.dt
                torque = abs(vd.inp[IN_RIDER_TORQUE]) + abs(vd.inp[IN_ASSIST])
                w_drive += torque * 0.5 * (s_before + abs(d.qd[k_steer])) * n * self.dt
            else:
                try:
                    sim.step(n * frames)
                    steps += n * frames
                except SimulationError as exc:
                    outcome, failure, etype = "failed", str(exc), type(exc).__name__
                    break
            if not (np.all(np.isfinite(d.q)) and np.all(np.isfinite(d.qd))):
                outcome, failure, etype = "failed", f"non-finite state at t = {d.t[0]:.4f} s", "NonFiniteState"
                break
            t = float(d.t[0])
            allowed = self.p_max * t + w_drive + store
            r = (energy() - e0) / allowed
            ratio = max(ratio, r)
            if r > 1.0:
                outcome = "failed"
                failure = (f"energy bound broken at t = {t:.4f} s: E - E0 = {energy() - e0:.1f} J > "
                           f"{allowed:.1f} J allowed")
                etype = "EnergyBound"
                break
        finite = bool(np.all(np.isfinite(d.q)) and np.all(np.isfinite(d.qd)))
        return RideResult(outcome, float(d.t[0]), steps, ratio, finite, failure, etype, time.perf_counter() - t0)


def _runs(table: np.ndarray, most: int) -> list[tuple[np.ndarray, int]]:
    """(row, count) of the table's runs of equal consecutive rows, each at most ``most`` rows long."""
    out: list[tuple[np.ndarray, int]] = []
    for row in table:
        if out and out[-1][1] < most and np.array_equal(out[-1][0], row):
            out[-1] = (out[-1][0], out[-1][1] + 1)
        else:
            out.append((row, 1))
    return out


@dataclass
class FuzzSummary:
    """Counts of a batch of rides of one vehicle."""
    vehicle: str
    rides: int = 0
    failures: int = 0
    falls: int = 0
    max_energy_ratio: float = 0.0
    wall_s: float = 0.0
    failed: list = field(default_factory=list)       # (Ride, RideResult) of each failure

    def add(self, ride: Ride, res: RideResult) -> None:
        self.rides += 1
        self.max_energy_ratio = max(self.max_energy_ratio, res.energy_ratio)
        if res.outcome == "fell":
            self.falls += 1
        if res.failed:
            self.failures += 1
            self.failed.append((ride, res))
