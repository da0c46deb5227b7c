"""Any vehicle (rtsim.vehicle.registry.open_vehicle) stepped from outside by its commands, its channels
read after each step: what the vehicle FMU (rtsim.fmu.vehicle_slave) runs. The vehicle starts as the
scenario places it (road, initial state, step), with no driver: every command is an input, held between
calls of `advance`.

Outputs are the sensor channels as reported, then the state channels that are not also sensor channels
(the columns of `rtsim run`, rtsim.vehicle.offline.columns_of, without time and the power audit)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rtsim.boundcall import bind
from rtsim.errors import RtsimError
from rtsim.mbs.model import OK

from .vehicle_step import advance, read_channels


def output_names(channels) -> tuple[str, ...]:
    """The channels the vehicle FMU outputs (see the module docstring)."""
    return (*channels.sensor_names, *(n for n in channels.state_names if n not in channels.sensor_names))


class ServedVehicle:
    """The vehicle file at the scenario's start; `set_commands`, `advance(h)`, `outputs` (a float array in
    `names` order)."""

    def __init__(self, vehicle: str | Path, scenario: str | Path):
        from drivers.scenario import load_scenario
        from rtsim.vehicle.registry import open_vehicle

        self.opened = open_vehicle(vehicle)
        self.sc = load_scenario(scenario, check_files=True)
        self.sim = sim = self.opened.service_sim(self.sc, None, rider=False)
        self.dt = float(sim.dt)
        ch = sim.vm.channels
        self.channels = ch
        self.commands = tuple(c for c in ch.command_names if c in sim.command_slots)
        self.units = {c.name: c.unit for c in ch.sensors + ch.commands + ch.state}
        self.slots = np.array([sim.command_slots[c] for c in self.commands], dtype=np.int64)
        self.names = output_names(ch)
        self._sens = np.zeros(len(ch.sensors))
        self._state = np.zeros(len(ch.state))
        self._keep = np.array([ch.state_names.index(n) for n in self.names[len(ch.sensors):]], dtype=np.int64)
        self.outputs = np.zeros(len(self.names))
        self.v = sim.served()
        io = sim.io
        for c in self.commands:                     # every command is given: none is invalid
            if c in sim.invalid_slots:
                io.commands[sim.invalid_slots[c]] = 0.0
        if set(sim.eps_commands) & set(self.commands):
            sim.external_eps(True)                  # the commanded motor current replaces the built-in law
        self.steps = 0
        # bound once (rtsim.boundcall): a direct call would unbox the vehicle's ~100 arrays at every step
        self._advance = bind(advance, self.v, n_free=2)
        self._read_channels = bind(read_channels, self.v, self._sens, self._state, n_free=0)
        self._read()

    def set_commands(self, values) -> None:
        """The commands (SI units, `commands` order) held from now on."""
        self.v.io.commands[self.slots] = values

    def advance(self, h: float) -> None:
        """h s (a whole number of the vehicle's steps) with the commands held; the outputs after it."""
        n = int(round(h / self.dt))
        if n < 1 or abs(n * self.dt - h) > 1e-9 * max(h, self.dt):
            raise RtsimError(f"communication step {h!r} s is not a whole number of the vehicle's step {self.dt!r} s")
        status, done = self._advance(self.dt, n)
        self.steps += done
        if status != OK:
            self.sim.raise_status(status, self.steps + 1)
        self._read()

    def _read(self) -> None:
        self._read_channels()
        ns = self._sens.shape[0]
        self.outputs[:ns] = self._sens
        self.outputs[ns:] = self._state[self._keep]
