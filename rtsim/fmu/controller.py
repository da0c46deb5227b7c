"""A controller FMU as a command source: every `step` s of simulated time the run hands it the values of
its input channels, it advances the FMU by one communication step and returns the commands it drives,
which are held until its next step.

A command source (what the offline runner takes, rtsim.vehicle.offline.run's ``controller``) has:
``inputs`` (channel names), ``outputs`` (command names), ``step`` (s), ``start(t0)``,
``communicate(t, x) -> y`` (x: the input channels' values in SI units at time t; y: the commands in SI
units for [t, t + step)) and ``close()``. `FmuController` is the one that runs an FMU through fmpy
(FMI 2.0 or 3.0 co-simulation); a controller written in Python with the same members runs the same way
(the tests compare the two).

Sequence per communication point t_k = k * step: set the FMU's inputs to the channels at t_k, doStep(t_k,
step), read its outputs: the commands for [t_k, t_k + step).
"""
from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import numpy as np

from rtsim.channels import ChannelDictionary
from rtsim.configfile import problem
from rtsim.errors import RtsimError

from .mapping import Mapping, load_mapping
from .units import SI, conversion

_REAL = ("Real", "Float64", "Float32")


def channel_units(channels: ChannelDictionary) -> dict[str, str]:
    """Every channel a controller may read (sensors first: a name that is both is the sensor as reported),
    name -> SI unit."""
    out = {c.name: c.unit for c in channels.state}
    out.update({c.name: c.unit for c in channels.sensors})
    return out


def read_description(fmu: Path, source: Path, key: str = "fmu"):
    """The FMU's model description, validated by fmpy; ConfigError (one line) naming `source` and `key`
    when it is not a readable FMU, fails the validation or is not a co-simulation FMU of FMI 2.0 or 3.0."""
    from fmpy import read_model_description
    from fmpy.model_description import ValidationError

    if not zipfile.is_zipfile(fmu):
        raise problem(source, key, str(fmu.name), "not an FMU (not a zip archive)")
    try:
        md = read_model_description(str(fmu), validate=True)
    except ValidationError as exc:
        first = exc.problems[0] if getattr(exc, "problems", None) else str(exc)
        raise problem(source, key, str(fmu.name), f"its modelDescription.xml fails fmpy's validation: {first}") from None
    except Exception as exc:  # noqa: BLE001 (fmpy raises many kinds on a broken archive)
        raise problem(source, key, str(fmu.name), f"cannot read its modelDescription.xml: {exc}") from None
    if md.fmiVersion not in ("2.0", "3.0"):
        raise problem(source, key, str(fmu.name), f"FMI {md.fmiVersion}: rtsim steps FMI 2.0 and 3.0 FMUs")
    if md.coSimulation is None:
        raise problem(source, key, str(fmu.name), "wrong FMI kind: a model-exchange FMU; rtsim steps "
                      "co-simulation FMUs (export it for co-simulation)")
    return md


class FmuController:
    """A mapping file's FMU bound to a vehicle's channels and commands (see the module docstring).

    channels: the vehicle's channel dictionary (inputs may name its sensor and state channels);
    commands: the command names this run lets a controller drive, with their SI units; dt: the run's
    step (s), of which the communication step must be a whole multiple."""

    def __init__(self, mapping: Mapping | str | Path, channels: ChannelDictionary, commands: dict[str, str],
                 dt: float):
        m = mapping if isinstance(mapping, Mapping) else load_mapping(mapping)
        self.mapping = m
        src = m.path
        self.md = md = read_description(m.fmu, src)
        self.fmi3 = md.fmiVersion == "3.0"
        ratio = m.step / dt
        if abs(ratio - round(ratio)) > 1e-9 * max(1.0, ratio) or round(ratio) < 1:
            raise problem(src, "step", m.step, f"must be a whole multiple of the run's step dt = {dt:g} s")
        self.every = int(round(ratio))
        self.step = self.every * dt
        by_name = {v.name: v for v in md.modelVariables}
        avail = channel_units(channels)

        def var(key: str, name: str, value: str, causality: str):
            v = by_name.get(name)
            want = [n for n, x in by_name.items() if x.causality == causality]
            if v is None:
                raise problem(src, key, value, f"missing variable: the FMU has no variable {name!r} (its "
                              f"{causality}s: {', '.join(want) or 'none'})")
            if v.causality != causality:
                raise problem(src, key, value, f"wrong causality: the FMU's {name!r} is {v.causality}, not {causality}")
            if v.type not in _REAL:
                raise problem(src, key, value, f"the FMU's {name!r} is of type {v.type}; rtsim exchanges floats")
            return v

        def unit_of(v):
            return v.unit or (v.declaredType.unit if v.declaredType is not None else None)

        self.inputs: tuple[str, ...] = tuple(m.inputs.values())
        self.outputs: tuple[str, ...] = tuple(m.outputs.values())
        # per direction: value references and the linear map fmu = a * channel + b (outputs inverted)
        maps = {}
        for side, causality, table, known, what in (
                ("inputs", "input", m.inputs, avail, "a sensor or state channel of the vehicle (its channels"),
                ("outputs", "output", m.outputs, commands, "a command this run takes (allowed")):
            vr, a, b = [], [], []
            for name, ch in table.items():
                key = f"{side}.{name}"
                if ch not in known:
                    raise problem(src, key, ch, f"not {what}: {', '.join(known)})")
                v = var(key, name, ch, causality)
                conv = conversion(known[ch], md, unit_of(v))
                if isinstance(conv, str):
                    raise problem(src, key, ch, conv)
                vr.append(v.valueReference)
                a.append(conv[0])
                b.append(conv[1])
            maps[side] = (vr, np.array(a), np.array(b))
        self._in_vr, self._in_a, self._in_b = maps["inputs"]
        self._out_vr, self._out_a, self._out_b = maps["outputs"]
        self._par = []
        for name, value in m.spec.parameters.items():
            v = by_name.get(name)
            if v is None or v.causality != "parameter":
                raise problem(src, f"parameters.{name}", value, "missing variable: the FMU has no parameter "
                              f"{name!r} (its parameters: {', '.join(n for n, x in by_name.items() if x.causality == 'parameter') or 'none'})")
            self._par.append((v.valueReference, float(value)))
        self._fmu = None
        self._dir = None

    # ---- the command source ---------------------------------------------------------------------------
    def start(self, t0: float = 0.0) -> None:
        """Instantiate and initialise the FMU at time t0 (again after a previous run: a fresh instance)."""
        from fmpy import extract

        self.close()
        self._dir = extract(str(self.mapping.fmu))
        try:
            fmu = open_slave(self.md, self._dir, self.mapping.path.stem, t0, self._par)
        except Exception as exc:  # noqa: BLE001 (an FMU's failure comes as fmpy's exception of its status)
            raise RtsimError(f"{self.mapping.path}: fmu = {self.mapping.spec.fmu!r}: cannot initialise it: {exc}") from None
        self._set, self._get = (fmu.setFloat64, fmu.getFloat64) if self.fmi3 else (fmu.setReal, fmu.getReal)
        self._fmu = fmu

    def communicate(self, t: float, x: np.ndarray) -> np.ndarray:
        """The commands for [t, t + step) from the input channels' values x (SI) at t."""
        fmu = self._fmu
        if len(self._in_vr):
            self._set(self._in_vr, list(self._in_a * x + self._in_b))
        try:
            fmu.doStep(t, self.step)
        except Exception as exc:  # noqa: BLE001
            raise RtsimError(f"{self.mapping.path}: the FMU failed its step at t = {t:.6f} s: {exc}") from None
        y = np.array(self._get(self._out_vr))
        return (y - self._out_b) / self._out_a

    def close(self) -> None:
        if self._fmu is not None:
            try:
                self._fmu.terminate()
            finally:
                self._fmu.freeInstance()
            self._fmu = None
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None



def open_source(controller, channels: ChannelDictionary, commands: dict[str, str], dt: float):
    """The command source a run drives with: a mapping (Mapping or its file) opens its FMU as an
    FmuController; anything else is taken as a command source already (a controller written in Python with
    the members of the module docstring), so both stand in the same place of a run."""
    if isinstance(controller, (Mapping, str, Path)):
        return FmuController(controller, channels, commands, dt)
    return controller


def open_slave(md, unzipdir, name: str, t0: float = 0.0, parameters=()):
    """An extracted co-simulation FMU (fmpy's model description `md`, FMI 2.0 or 3.0) instantiated as
    `name`, its float `parameters` ((value reference, value), ...) set, initialised at time t0."""
    from fmpy.fmi2 import FMU2Slave
    from fmpy.fmi3 import FMU3Slave

    fmi3 = md.fmiVersion == "3.0"
    fmu = (FMU3Slave if fmi3 else FMU2Slave)(guid=md.guid, unzipDirectory=str(unzipdir), instanceName=name,
                                            modelIdentifier=md.coSimulation.modelIdentifier)
    fmu.instantiate()
    try:
        if not fmi3:
            fmu.setupExperiment(startTime=t0)
        if parameters:
            (fmu.setFloat64 if fmi3 else fmu.setReal)([vr for vr, _ in parameters], [x for _, x in parameters])
        if fmi3:
            fmu.enterInitializationMode(startTime=t0)
        else:
            fmu.enterInitializationMode()
        fmu.exitInitializationMode()
    except BaseException:
        fmu.freeInstance()
        raise
    return fmu
