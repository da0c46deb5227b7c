"""Rides of drawn command sequences (rtsim.robustness.commands) through the vehicle step the HIL service
uses, offline, with the outcome of each.

The step, the start and the energy bound's terms are the vehicle's own (its fuzz rig,
``VehicleKind.fuzz_rig``: rtsim.vehicle.car.fuzz, rtsim.vehicle.motorcycle.fuzz). The step is the
service's (rtsim.service.vehicles ``vehicle_advance``): for a car, its
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

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .commands import CommandSpace, Ride, command_space, expand

ROOT = Path(__file__).resolve().parents[2]
ROADS_DIR = ROOT / "configs" / "roads"
VEHICLES_DIR = ROOT / "configs" / "vehicles"
SPRING_DROP_M = 0.25               # m: the weight's drop that bounds the springs' and actuators' release
TOLERANCE_SHARE = 0.01             # of the start's kinetic energy: the integrator's tolerances
CHECK_S = 0.01                     # s: the longest a car runs between the checks (state, energy)


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


class FuzzTarget:
    """One vehicle file, built once, ready to ride drawn sequences on the shipped roads it can run on. What
    differs between vehicles (their command slots, the energy bound's terms, the roads, the start and the
    steps) is the vehicle's own fuzz rig (``VehicleKind.fuzz_rig``: rtsim.vehicle.car.fuzz,
    rtsim.vehicle.motorcycle.fuzz)."""

    def __init__(self, vehicle: str | Path, dt: float = 1e-3):
        from drivers.scenario import load_scenario
        from rtsim.vehicle.registry import open_vehicle

        self.path = Path(vehicle)
        self.dt = float(dt)
        opened = open_vehicle(self.path)
        self.rig = rig = opened.kind.fuzz_rig(opened, self.dt)
        self.space: CommandSpace = command_space(rig.dbc, rig.drivers)
        self.slots = np.array([rig.slot(c.name) for c in self.space.commands], dtype=np.int64)
        self.eps = rig.eps_external_optional
        self.top_speed, self.p_max, self.e_flywheel = rig.top_speed, rig.p_max, rig.e_flywheel
        # the served scenario's rider rides a vehicle that has one (rtsim serve's default scenario)
        self.scenario = load_scenario(opened.default_scenario, check_files=True) if rig.rider_optional else None
        self.skipped_roads: dict[str, str] = {}
        roads = []
        for p in shipped_roads():
            why = rig.road_problem(p)
            if why is None:
                roads.append(p.stem)
            else:
                self.skipped_roads[p.stem] = why
        self.roads = tuple(roads)
        self.steps_per_frame = max(1, int(round(self.space.frame_s / self.dt)))

    @property
    def name(self) -> str:
        return self.path.stem

    @property
    def can_fall(self) -> bool:
        """A fall is a defined end of this vehicle's rides (a two-wheeler's)."""
        return self.rig.can_fall

    # ---- one ride ----------------------------------------------------------------------------------
    def new_sim(self, ride: Ride):
        """The vehicle at the ride's start (module docstring)."""
        rider = self.scenario.rider() if self.scenario is not None and ride.rider else None
        return self.rig.new_sim(ROADS_DIR / f"{ride.road}.toml", ride.speed, rider=rider,
                                eps_external=bool(ride.eps_external))

    def ride(self, ride: Ride) -> RideResult:
        """Run the ride (module docstring) and return its outcome."""
        if ride.road not in self.roads:
            raise ValueError(f"{self.name}: road {ride.road!r} is not one it runs on ({', '.join(self.roads)})")
        t0 = time.perf_counter()
        rig = self.rig
        sim = self.new_sim(ride)
        table = expand(ride.segments, self.space.rest())
        if ride.eps_external is False and self.eps:      # the built-in law: the bus's current is not read
            keep = [i for i, c in enumerate(self.space.commands) if c.source != "bus"]
        else:
            keep = list(range(len(self.space.commands)))
        slots = self.slots[keep]
        table = table[:, keep]
        mass, q_grav = rig.mechanics(sim)
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
        # held commands run in one call for up to CHECK_S (the checks at its end); a vehicle whose drive and
        # steering work are summed per command period runs each period on its own
        runs = _runs(table, max(1, int(round(CHECK_S / self.space.frame_s)))) if rig.hold_commands \
            else [(row, 1) for row in table]
        for row, frames in runs:
            sim.io.commands[slots] = row
            fell, done, work, error = rig.advance(sim, n * frames, ride.rider, steps)
            steps += int(done)
            if fell:
                outcome = "fell"
                break
            if error is not None:
                outcome, failure, etype = "failed", str(error), type(error).__name__
                break
            w_drive += work
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
