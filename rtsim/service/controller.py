"""A controller FMU (the served scenario's ``controller``, rtsim.fmu) as a command source of the service's
loop. It drives the vehicle's *user channels* (rtsim.vehicle.kit.user_inputs: a car's throttle, brake and
steering-wheel angle) through the user source, so it has the user source's priority: it replaces the
scenario's in-loop driver always and a bus ECU's command only where the bus holds no valid, timely command
(or while the user has taken over). Beside an ECU on the bus it drives what the ECU does not command;
instead of one it drives everything it maps.

Timing: before the step from t_k = k dt with k a multiple of its step, it reads the channels the loop
sampled after step k (the sensor sample as packed for the bus, sensor faults included, and the observer's
state; at k = 0 the vehicle's channels at the start), communicates, and its commands (clipped to the user
channels' ranges) act from that step on. Its step must be a whole number of the sensor and state periods
it reads. Each change is logged as a change of the user source (topic ``user``, cause ``controller``)."""
from __future__ import annotations

import numpy as np

from rtsim.boundcall import bind
from rtsim.configfile import problem
from rtsim.fmu.controller import open_source
from rtsim.fmu.vehicle_step import read_channels


class LoopController:
    """A controller bound to the served vehicle ``sim`` and its loop's sample periods (steps): a mapping's
    FMU, or a command source written in Python (rtsim.fmu.controller.open_source), the same way."""

    def __init__(self, sim, controller, dt: float, sensor_every: int, state_every: int):
        inputs = sim.user_inputs
        table = inputs.table()
        self.source = src = open_source(controller, sim.vm.channels, {n: r[2] for n, r in table.items()}, dt)
        where = getattr(src, "mapping", None)
        where = where.path if where is not None else type(src).__name__
        ratio = src.step / dt
        if abs(ratio - round(ratio)) > 1e-9 * max(1.0, ratio) or round(ratio) < 1:
            raise problem(where, "step", src.step, f"must be a whole multiple of the run's step dt = {dt:g} s")
        every = int(round(ratio))
        unknown = [c for c in src.outputs if c not in table]
        if unknown:
            raise problem(where, "outputs", ", ".join(unknown), f"not a user channel of the served vehicle "
                          f"(those are: {', '.join(table)})")
        ch = sim.vm.channels
        self.pick = [(0, ch.sensor_names.index(n)) if n in ch.sensor_names else (1, ch.state_names.index(n))
                     for n in src.inputs]
        for kind, each, what in ((0, sensor_every, "sensor"), (1, state_every, "state")):
            if any(k == kind for k, _ in self.pick) and every % each:
                raise problem(where, "step", src.step, f"must be a whole number of the service's "
                              f"{what} period ({each * dt:g} s): it reads {what} channels")
        self.every = every
        names = list(inputs.names)
        self.slots = np.array([names.index(c) for c in src.outputs], dtype=np.int64)
        self.lo = np.array([table[c][0] for c in src.outputs])
        self.hi = np.array([table[c][1] for c in src.outputs])
        self.x = np.zeros(len(self.pick))
        self._sens = np.zeros(len(ch.sensors))
        self._state = np.zeros(len(ch.state))
        self._start = bind(read_channels, sim.served(), self._sens, self._state, n_free=0)
        src.start(0.0)

    def communicate(self, k: int, t: float, values: np.ndarray, state: np.ndarray, usr: np.ndarray) -> None:
        """At step k (time t): the channels (the loop's samples ``values``, ``state``; at k = 0 read from the
        vehicle), one communication step, the commands into the user source ``usr``."""
        if k == 0:
            self._start()
            values, state = self._sens, self._state
        for i, (kind, j) in enumerate(self.pick):
            self.x[i] = values[j] if kind == 0 else state[j]
        usr[self.slots] = np.clip(self.source.communicate(t, self.x), self.lo, self.hi)

    def close(self) -> None:
        self.source.close()
