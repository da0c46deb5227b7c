"""`rtsim export-fmu`: any vehicle (rtsim.vehicle.registry) as an FMI 3.0 co-simulation FMU, built with
pythonfmu3 from rtsim.fmu.vehicle_slave. The FMU carries every file the vehicle and its start scenario
read (found by rtsim.configfile.recording_reads, kept in their relative layout under its resources) and a
JSON of its interface; rtsim itself is not packed: the importing Python must have it installed."""
from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

from rtsim.configfile import recording_reads
from rtsim.errors import RtsimError

from .units import SI

SLAVE = Path(__file__).resolve().parent / "vehicle_slave.py"
CONFIG = "rtsim_fmu.json"
FILES = "files"      # the vehicle's files under the FMU's resources


def export_vehicle(vehicle: str | Path | None, out: str | Path, scenario: str | Path | None = None) -> Path:
    """Write the FMU of `vehicle` (a file or a name in configs/vehicles) to `out`, starting as `scenario`
    (a file or name; default the vehicle's default scenario) places it: its road, initial state and step
    (the FMU's communication step must be a whole number of it). Returns the FMU's path."""
    try:
        from pythonfmu3.builder import FmuBuilder
    except ImportError:
        raise RtsimError("export-fmu needs pythonfmu3: pip install 'rtsim[fmu]'") from None
    from drivers.scenario import load_scenario
    from rtsim.vehicle.registry import open_vehicle, resolve_scenario

    from .served_vehicle import ServedVehicle

    out = Path(out)
    if out.suffix.lower() != ".fmu":
        raise RtsimError(f"{out}: the output must end in .fmu")
    opened = open_vehicle(vehicle)
    opened.refuse("export-fmu")
    sc_path = resolve_scenario(scenario) if scenario is not None else opened.default_scenario
    sc = load_scenario(sc_path, check_files=True)
    opened.check_scenario(sc)
    with recording_reads() as files:
        veh = ServedVehicle(opened.path, sc_path)        # builds the model: every file it reads is noted
    files |= {opened.path.resolve(), Path(sc_path).resolve()}
    root = Path(os.path.commonpath([str(f.parent) for f in files]))
    cfg = {"name": opened.path.stem, "dt": veh.dt,
           "vehicle": f"{FILES}/{opened.path.resolve().relative_to(root)}",
           "scenario": f"{FILES}/{Path(sc_path).resolve().relative_to(root)}",
           "commands": [[c, veh.units[c]] for c in veh.commands],
           "outputs": [[n, veh.units[n]] for n in veh.names],
           "units": {u: [f, e] for u, (f, e) in SI.items()}}
    with tempfile.TemporaryDirectory(prefix="rtsim_fmu_") as tmp:
        stage = Path(tmp) / "stage"
        for f in files:
            dest = stage / FILES / f.relative_to(root)
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(f, dest)
        (stage / CONFIG).write_text(json.dumps(cfg, indent=1))
        script = stage / SLAVE.name
        shutil.copy2(SLAVE, script)
        built = FmuBuilder.build_FMU(script, dest=Path(tmp) / "out", project_files={stage / FILES, stage / CONFIG},
                                     canHandleVariableCommunicationStepSize=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(built), out)
    return out
