"""What the command fuzzing (rtsim.robustness.harness) needs of a car: its DBC and command slots, its
energy bound's terms, the roads it runs on, the car at a ride's start and its steps.

The car is placed as ``rtsim serve`` places it: on the road at ``START_XY`` heading +x at the ride's
speed (rtsim.vehicle.car.sim.VehicleSim). Its commands are held between command periods, so equal
consecutive command rows run in one call (``hold_commands``). The EPS car's driver (the scenario's, in
the loop) writes the commands its DBC does not carry (``drivers``); a ride may hand the motor current to
the bus or leave it to the built-in law (``eps_external_optional``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rtsim.errors import SimulationError

from .step import CMD_MOTOR_INVALID, COMMAND_SLOTS

START_XY = (2.0, 0.0)              # m: where a car starts (on every shipped road, the campus lane's too)


class CarFuzzRig:
    """The car of an opened vehicle file (rtsim.vehicle.registry.OpenedVehicle) for the fuzzing."""
    rider_optional = False            # no rider to take off
    can_fall = False                  # a car's ride ends by time or a model failure only
    hold_commands = True

    def __init__(self, opened, dt: float):
        from ..kit.powertrain import describe, powertrain_config

        cfg = opened.config
        self.dt = float(dt)
        self.model = opened.model
        self.eps_external_optional = cfg.eps is not None
        self.dbc = (Path(opened.base) / cfg.interface.dbc).resolve()
        self.drivers = tuple(n for n in COMMAND_SLOTS if n != "motor_current_cmd") \
            if self.eps_external_optional else ()
        pt = powertrain_config(cfg.powertrain or None, "powertrain")
        e, g = pt.engine, pt.gearbox
        self.top_speed = e.rev_limit / (g.ratios[-1] * g.final_drive) * g.wheel_radius
        self.p_max = describe(pt)["peak_power_kW"] * 1e3
        self.e_flywheel = 0.5 * e.inertia * e.rev_limit ** 2
        self._roads: dict = {}

    def slot(self, name: str) -> int:
        """The command array's slot of a command channel."""
        return COMMAND_SLOTS[name]

    def road_problem(self, road_path: Path) -> str | None:
        """Why the car cannot run on the road (None: it runs on every road)."""
        return None

    def new_sim(self, road_path: Path, speed: float, rider=None, eps_external: bool = True):
        """The car at a ride's start (module docstring); ``rider`` is not used."""
        from rtsim.road.config import load_road

        from .sim import VehicleSim

        key = Path(road_path)
        if key not in self._roads:
            self._roads[key] = load_road(key)
        sim = VehicleSim(self.model, self._roads[key], self.dt, brake_pressure=0.0, position=START_XY, speed=speed)
        if self.eps_external_optional and eps_external:
            sim.external_eps(True)
            sim.io.commands[CMD_MOTOR_INVALID] = 0.0
        return sim

    def mechanics(self, sim) -> tuple[np.ndarray, np.ndarray]:
        """(multibody mass matrix, gravity's generalized forces) of the sim."""
        return sim.sim.mech.mass_dense, sim.sim.model.q_grav

    def advance(self, sim, n: int, rider_on: bool, steps: int):
        """n steps with the commands as written: (fell, steps done, drive work beyond ``p_max t`` in J,
        the model failure's SimulationError or None)."""
        try:
            sim.step(n)
        except SimulationError as exc:
            return False, 0, 0.0, exc
        return False, n, 0.0, None
