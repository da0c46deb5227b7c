"""The controller mapping file: which FMU drives which commands from which channels, at what step.

Format (TOML, relative paths relative to the mapping file; checked on load by rtsim.configfile):

    fmu = "pi_speed.fmu"           # a co-simulation FMU, FMI 2.0 or 3.0
    step = 0.01                    # s, communication step: a whole number of the run's steps   1e-5 .. 10

    [inputs]                       # FMU input variable = channel of the vehicle's dictionary (a sensor
    v_meas = "speed"               #   channel as reported, else a state channel); converted from the
                                   #   channel's SI unit into the variable's declared unit
    [outputs]                      # FMU output variable = command it drives (at least one); converted
    throttle = "throttle_angle_cmd"    #   from the variable's declared unit into the command's SI unit

    [parameters]                   # optional: FMU parameters set before its initialisation, in the
    kp = 0.8                       #   variable's own unit

Keys are the FMU's variable names (quote names with dots: "PI.k" = 0.8). What needs the FMU or the
vehicle (a variable that does not exist, a causality or unit that does not fit, a channel the vehicle
does not have, a step that is not a multiple of the run's) is checked when the controller is opened
(rtsim.fmu.controller), one line naming this file, the key and the value.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from pydantic import Field

from rtsim.configfile import Range, Strict, load, note_read, problem


class MappingSpec(Strict):
    fmu: str = Field(min_length=1)
    step: Range(1e-5, 10.0, "s")
    inputs: dict[str, str] = {}
    outputs: dict[str, str] = Field(min_length=1)
    parameters: dict[str, Range(-1e12, 1e12)] = {}


@dataclass(frozen=True)
class Mapping:
    """A validated mapping file: its path, the spec and the FMU's resolved path (checked to exist)."""
    path: Path
    spec: MappingSpec
    fmu: Path

    @property
    def inputs(self) -> dict[str, str]:
        return dict(self.spec.inputs)

    @property
    def outputs(self) -> dict[str, str]:
        return dict(self.spec.outputs)

    @property
    def step(self) -> float:
        return self.spec.step


def load_mapping(path: str | Path) -> Mapping:
    """A mapping file, validated (ConfigError, one line, otherwise)."""
    path = Path(path)
    spec = load(MappingSpec, path)
    fmu = (path.parent / spec.fmu).resolve()
    note_read(fmu)                      # the FMU is an input of the run (a batch's run ids hash it)
    if not fmu.is_file():
        raise problem(path, "fmu", spec.fmu, f"file not found ({fmu})")
    seen: dict[str, str] = {}
    for var, cmd in spec.outputs.items():
        if cmd in seen:
            raise problem(path, f"outputs.{var}", cmd, f"already driven by outputs.{seen[cmd]}")
        seen[cmd] = var
    return Mapping(path, spec, fmu)
