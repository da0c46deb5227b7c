"""A two-wheeler ready for the HIL service (`rtsim serve --vehicle configs/vehicles/motorcycle.toml`): settled
on its suspension with the rider on, placed at the scenario's start, rolling at its speed, with the
rider (or none: ``--rider off``) inside the compiled step (rtsim.vehicle.motorcycle.plant)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rtsim.channels import ChannelDictionary, two_wheeler_channels
from .rider import rider as make_rider

from .build import MotorcycleModel
from .config import MotorcycleConfig
from .inputs import USER_INPUTS
from .layout import NAMES, POINTS, VECTORS
from .plant import COMMAND_SLOTS, FALL_ROLL, FELL, INVALID_SLOTS, NCOMMAND, PlantIO, make_plant
from .sim import Fall, TwoWheelerSim
from .served import LoopTwoWheeler  # the served tuple; importing it registers the stages


@dataclass(frozen=True)
class ServedTwoWheeler:
    """What the service shows of the vehicle it serves: its configuration, interface and DBC."""
    config: MotorcycleConfig
    channels: ChannelDictionary
    dbc: Path
    model: MotorcycleModel


def place(mm: MotorcycleModel, q: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    """q moved on the ground plane: turned by yaw (rad) about the vertical through the origin, then
    shifted by (x, y) m. The rear contact point at the origin lands at (x, y)."""
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = q.copy()
    for name in POINTS + VECTORS:
        k = mm.bike.idx[NAMES.index(name)]
        if k < 0:
            continue
        out[k:k + 3] = rot @ q[k:k + 3]
        if name in POINTS:
            out[k:k + 2] += (x, y)
    return out




class TwoWheelerHil:
    """The served two-wheeler (see the module docstring): the interface the service's loop needs
    (``served``, command slots, channel counts, ``raise_status``) over a TwoWheelerSim."""

    command_slots = COMMAND_SLOTS
    invalid_slots = INVALID_SLOTS
    eps_commands = ()                 # no electric power steering
    user_inputs = USER_INPUTS         # what a person may drive (the vehicle's own: set by its kind)

    def fault_actuators(self) -> dict:
        """The actuators a fault may act on (rtsim.faults; see the car's VehicleSim.fault_actuators): none
        declared yet, so an actuator fault on a two-wheeler is refused."""
        return {}

    def __init__(self, mm: MotorcycleModel, dbc: Path, q_static: np.ndarray, dt: float, speed: float = 0.0,
                 x: float = 0.0, y: float = 0.0, yaw: float = 0.0, rider=None, mu: float = 1.0):
        self.tw = TwoWheelerSim(mm, dt=dt, speed=speed, q=place(mm, q_static, x, y, yaw), mu=mu)
        self.dt = self.tw.dt
        self.m, self.data = self.tw.model, self.tw.data
        self.parts = self.tw.parts
        self.sim = self.tw.sim
        self.vm = ServedTwoWheeler(mm.config, two_wheeler_channels(), dbc, mm)
        self.nsensor = len(self.vm.channels.sensors)
        self.nstate = len(self.vm.channels.state)
        self.rider_on = rider is not None
        # without a rider the step still needs one of the rider's type: a straight line it never reads
        self.rider = rider if rider is not None else make_rider(np.array([0.0, 1.0]), np.zeros(2))
        self.params, self.state = make_plant(mm, self.rider_on)
        self.io = PlantIO(np.zeros(NCOMMAND))
        self.io.commands[[INVALID_SLOTS[n] for n in INVALID_SLOTS]] = 1.0     # no command yet

    @property
    def drawing(self):
        """How the two-wheeler is drawn (rtsim.vehicle.motorcycle.drawing)."""
        from .drawing import two_wheeler_drawing
        return two_wheeler_drawing(self.vm.config)

    def served(self) -> "LoopTwoWheeler":
        """The two-wheeler as the service's compiled step takes it: one named tuple
        (rtsim.vehicle.motorcycle.served, which registers its stages)."""
        return LoopTwoWheeler(self.m, self.data, self.params, self.state, self.rider, self.parts, self.io)

    def seed_sensor_noise(self, seed: int) -> None:
        """(The two-wheeler's sensors are ideal: nothing to seed.)"""

    def raise_status(self, status: int, step: int) -> None:
        """The exception of a failed step's status: a fall, or the multibody step's failure."""
        if status == FELL:
            t = step * self.dt
            tyres = "both tyres off the road" if abs(self.tw.roll) <= FALL_ROLL else \
                f"roll {np.degrees(self.tw.roll):.0f} deg"
            raise Fall(f"{self.vm.config.id}: fell at t = {t:.3f} s ({tyres})", t)
        self.sim._raise(status, step)
