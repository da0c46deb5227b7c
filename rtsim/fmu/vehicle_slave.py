"""The vehicle FMU's model (pythonfmu3 packs this file into the FMU with the vehicle's files; see
rtsim.fmu.export): an FMI 3.0 co-simulation slave whose inputs are the vehicle's commands and whose
outputs are its channels (rtsim.fmu.served_vehicle), in their SI units. It runs rtsim itself, so the
Python that loads the FMU must have rtsim installed (docs/fmu.md)."""
import json
from pathlib import Path

from pythonfmu3 import Fmi3Causality, Fmi3Slave, Fmi3Variability, Float64
from pythonfmu3.unit import Unit

CONFIG = "rtsim_fmu.json"      # written by rtsim.fmu.export beside this file in the FMU's resources


class RtsimVehicle(Fmi3Slave):

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        res = Path(self.resources)
        self.cfg = cfg = json.loads((res / CONFIG).read_text())
        self.author = "rtsim"
        self.description = f"rtsim vehicle {cfg['name']}: its commands in, its channels out (SI units)"
        self.time = 0.0
        self._cmd = [0.0] * len(cfg["commands"])
        self._out = [0.0] * len(cfg["outputs"])
        self._veh = None
        used = sorted({u for _, u in cfg["commands"] + cfg["outputs"] if u != "1"})
        self.register_units([Unit(u, factor=cfg["units"][u][0], **cfg["units"][u][1]) for u in used])
        self.register_variable(Float64("time", causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous))
        for i, (name, unit) in enumerate(cfg["commands"]):
            self.register_variable(Float64(
                name, causality=Fmi3Causality.input, start=0.0, unit=None if unit == "1" else unit,
                getter=lambda i=i: self._cmd[i], setter=lambda x, i=i: self._cmd.__setitem__(i, float(x))))
        for i, (name, unit) in enumerate(cfg["outputs"]):
            self.register_variable(Float64(
                name, causality=Fmi3Causality.output, unit=None if unit == "1" else unit,
                getter=lambda i=i: float(self._out[i])))

    def exit_initialization_mode(self):
        from rtsim.fmu.served_vehicle import ServedVehicle

        res = Path(self.resources)
        self._veh = ServedVehicle(res / self.cfg["vehicle"], res / self.cfg["scenario"])
        self._out = self._veh.outputs

    def do_step(self, current_time, step_size):
        self._veh.set_commands(self._cmd)
        self._veh.advance(step_size)
        self._out = self._veh.outputs
        return True
