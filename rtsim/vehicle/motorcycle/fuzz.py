"""What the command fuzzing (rtsim.robustness.harness) needs of a two-wheeler: its DBC and command slots,
its energy bound's terms, the roads it runs on, the two-wheeler at a ride's start and its steps.

The two-wheeler is placed as ``rtsim serve`` places it: settled on its suspension with the rider on
(rtsim.vehicle.motorcycle.hil.TwoWheelerHil, with the served scenario's rider when the ride has one),
rolling straight at the ride's speed, every bus command valid from the start (its ``*_INVALID`` slots 0:
the bus's throttle and brakes replace the rider's demands and its assist torque adds to the rider's).
Each command period runs on its own (``hold_commands`` False): the drive's work at the wheel speed of
that period and the steering torques' work, sum of (|rider's torque| + |assist torque|) |steer rate| dt
with the mean of the steer rate's magnitude at its start and end, are summed per period (``advance``).
A fall (status FELL) is the defined end of a ride."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from rtsim.errors import SimulationError
from rtsim.jit import kernel

from .layout import K_DELTA, K_PHI_R, K_THETA
from .plant import COMMAND_SLOTS, FELL, IN_ASSIST, IN_RIDER_TORQUE, INVALID_SLOTS, MAX_WHEEL_TORQUE, plant_rider, \
    plant_step

NO_ENGINE_TOP_SPEED = 10.0         # m/s: a vehicle without an engine (the Whipple bicycle, ridden by its
                                   # rider's legs): the benchmark's speed range (Meijaard et al. 2007, 0-10 m/s)


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


class TwoWheelerFuzzRig:
    """The two-wheeler of an opened vehicle file (rtsim.vehicle.registry.OpenedVehicle) for the fuzzing."""
    rider_optional = True              # a ride runs with the served scenario's rider or without one
    eps_external_optional = False
    can_fall = True
    hold_commands = False
    drivers = ()                       # every command it takes is on the bus

    def __init__(self, opened, dt: float):
        from .ride import tyre_lean_ratio
        from .sim import static_pose

        cfg = opened.config
        self.dt = float(dt)
        self.mm = opened.model
        self.q_static = static_pose(self.mm)[0]
        self.dbc = (Path(opened.base) / cfg.interface.dbc).resolve()
        self.tyre_lean = tyre_lean_ratio(self.mm)
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

    def slot(self, name: str) -> int:
        """The command array's slot of a command channel."""
        return COMMAND_SLOTS[name]

    def road_problem(self, road_path: Path) -> str | None:
        """Why the two-wheeler cannot run on the road: its tyres run on the plane z = 0 only (the service
        refuses other roads too: rtsim.vehicle.motorcycle.kind.TwoWheelerKind.service_sim)."""
        from rtsim.road.config import FlatRoadConfig, read_road_config

        rc = read_road_config(road_path)
        if isinstance(rc, FlatRoadConfig) and rc.height == 0.0:
            return None
        return "a two-wheeler's tyres run on the plane z = 0 only"

    def new_sim(self, road_path: Path, speed: float, rider=None, eps_external: bool = True):
        """The two-wheeler at a ride's start (module docstring); ``rider`` the scenario's (None: none),
        its lean feed-forward set to this vehicle's tyres' crown correction."""
        from rtsim.road.config import read_road_config

        from .hil import TwoWheelerHil
        from .rider import RiderPar

        mu = read_road_config(road_path).mu
        if rider is not None:
            rider.par[RiderPar.TYRE_LEAN] = self.tyre_lean
        sim = TwoWheelerHil(self.mm, self.dbc, self.q_static, self.dt, speed=speed, rider=rider, mu=mu)
        sim.io.commands[[INVALID_SLOTS[n] for n in INVALID_SLOTS]] = 0.0      # every bus command valid
        return sim

    def mechanics(self, sim) -> tuple[np.ndarray, np.ndarray]:
        """(multibody mass matrix, gravity's generalized forces) of the sim."""
        s = sim.tw.sim
        return s.mech.mass_dense, s.model.q_grav

    def advance(self, sim, n: int, rider_on: bool, steps: int):
        """n steps (one command period) with the commands as written: (fell, steps done, the drive's and
        steering torques' work over them in J (module docstring), the model failure's SimulationError or
        None; ``steps``: those run before, for its message)."""
        v = sim.served()
        d, vd, parts = v.d, v.plant, v.parts
        k_rear, k_arm, k_steer = parts.idx[K_PHI_R], parts.idx[K_THETA], parts.idx[K_DELTA]
        w_before = abs(d.qd[k_rear] - (d.qd[k_arm] if k_arm >= 0 else 0.0))
        s_before = abs(d.qd[k_steer])
        status, done = two_wheeler_advance(v.m, d, v.params, vd, v.rider, parts, v.io, self.dt, n, rider_on)
        done = int(done)
        if status == FELL:
            return True, done, 0.0, None
        if status != 0:
            try:
                sim.raise_status(int(status), steps + done + 1)
            except SimulationError as exc:
                return False, done, 0.0, exc
        w_after = abs(d.qd[k_rear] - (d.qd[k_arm] if k_arm >= 0 else 0.0))
        work = self.wheel_torque * 0.5 * (w_before + w_after) * n * self.dt
        torque = abs(vd.inp[IN_RIDER_TORQUE]) + abs(vd.inp[IN_ASSIST])
        work += torque * 0.5 * (s_before + abs(d.qd[k_steer])) * n * self.dt
        return False, done, work, None
