"""The vehicle registry: the one place that knows which kinds of vehicle exist and opens a vehicle file.

``open_vehicle(path)`` reads the file once, takes its ``kind`` (a car when it has none) and hands the
validated config to that kind's assembly (``KINDS``: the kind's name -> the module of its
``VehicleKind``). A file may name its own assembly module instead (``assembly = "package.module"``, or
a Python file relative to the vehicle file, ``assembly = "my_assembly.py"``; a module defining ``KIND``),
so a new vehicle is one config plus one assembly module, with no change here.

What differs between vehicles is an attribute or a method of its ``VehicleKind`` (how it is built and
described, the scenarios it accepts, how the service and the offline runner step it, its demo, which
commands apply to it), never a branch on the kind's name in the callers. A command that does not apply
to a vehicle asks ``refuse(command)``, which raises one line saying why.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from rtsim.configfile import load_toml
from rtsim.errors import ConfigError, RtsimError

ROOT = Path(__file__).resolve().parents[2]
VEHICLES = ROOT / "configs" / "vehicles"
SCENARIOS = ROOT / "configs" / "scenarios"

#: kind name (the vehicle file's ``kind``) -> the module whose ``KIND`` is its VehicleKind
KINDS = {
    "car": "rtsim.vehicle.car.kind",
    "two_wheeler": "rtsim.vehicle.motorcycle.kind",
}
DEFAULT_KIND = "car"
DEFAULT_VEHICLE = VEHICLES / "xbw.toml"

#: the commands that take a vehicle (the bar of the vehicle interface: each runs on every vehicle or
#: refuses in one line)
COMMANDS = ("describe", "run", "serve", "demo", "resim", "validate", "eigen", "statics", "energy", "feel",
            "view", "batch", "export-fmu")


def resolve_config(name: str | Path, what: str, folder: Path) -> Path:
    """A config path, or a bare name of <folder>/<name>.toml (ConfigError naming both when neither is)."""
    p = Path(name)
    if p.exists():
        return p
    if p.suffix or len(p.parts) > 1:           # a path, not a bare name: no shipped config to look up
        raise ConfigError(f"{what} {str(name)!r}: no such file")
    cand = folder / f"{name}.toml"
    if cand.exists():
        return cand
    raise ConfigError(f"{what} {str(name)!r}: no such file and no configs/{folder.name}/{name}.toml")


def resolve_vehicle(name: str | Path) -> Path:
    """A vehicle path, or a bare name of configs/vehicles/<name>.toml."""
    return resolve_config(name, "vehicle", VEHICLES)


def resolve_scenario(name: str | Path) -> Path:
    """A scenario path, or a bare name of configs/scenarios/<name>.toml."""
    return resolve_config(name, "scenario", SCENARIOS)


@dataclass
class OfflineRun:
    """An offline run of any vehicle (``VehicleKind.run_offline``): rows at the scenario's output rate,
    the run's status (``ok``, ``fall``, ``failed``), a summary (what the manoeuvre measured; may be empty)
    and how to write the rows (``write(path)``: .csv or .mcap)."""
    columns: tuple[str, ...]
    data: Any                    # (n, len(columns)) array
    wall_s: float
    steps: int
    status: str = "ok"
    message: str = ""
    fault: Any = None            # rtsim.model_fault.ModelFault that ended the run early, if any
    summary: dict = field(default_factory=dict)
    line: str = ""               # one console line: what was simulated, how fast, where to
    vehicle_id: str = ""
    channels: Any = None         # the columns' ChannelDictionary (an MCAP's schemas)
    scene: Any = None            # what the 3D scene is drawn from (bridge.mcap_log.write_run's ``sim``)
    step_s: float = float("nan")  # s of wall time inside the model's steps (NaN: the kind does not measure it)

    def column(self, name: str):
        return self.data[:, self.columns.index(name)]

    def write_csv(self, path: str | Path) -> None:
        """The rows as CSV: a header of the columns, values to 9 significant digits. (MCAP: the app layer
        writes it, bridge.mcap_log.write_offline.)"""
        import csv

        with Path(path).open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(self.columns)
            for r in self.data:
                w.writerow([f"{v:.9g}" for v in r])


@dataclass(frozen=True)
class Demo:
    """What `rtsim demo` runs against a vehicle: the ECU module, the loop's mode, the scenario (None: the
    service's default for the vehicle), the duration (None: the ECU's own), whether the ECU may fall
    silent (``--silent-after``). The closing report is the ECU's (rtsim.service.demo.REPORTS)."""
    ecu: str
    mode: str = "realtime"
    scenario: str | None = None
    duration: float | None = None
    silent_after: bool = False


#: VehicleKind.plain's answers by (kind's class, key), this process's
_PLAIN: dict = {}


class VehicleKind:
    """A kind of vehicle: everything the commands need that differs between vehicles. Subclasses (one per
    assembly) set the attributes and implement the methods; ``opened`` is the ``OpenedVehicle``."""
    name: str = ""
    default_scenario: str = "hil_flat"         # served (and demoed) when no scenario is given
    not_for: dict[str, str] = {}               # command -> why it does not apply to this kind

    def load(self, data: dict, path: Path) -> tuple[Any, Path]:
        """(validated config, the folder its relative paths refer to) from the file's table."""
        raise NotImplementedError

    def build(self, opened: "OpenedVehicle") -> Any:
        """The compiled vehicle model (immutable arrays), built from the config (seconds: cached by
        ``OpenedVehicle.model``)."""
        raise NotImplementedError

    def describe(self, opened: "OpenedVehicle") -> dict:
        """The model's size and key parameters in SI units; every kind reports ``DESCRIBE_FIELDS``."""
        raise NotImplementedError

    #: the vehicle file's plain parameters: fnmatch patterns of dotted keys whose values the build turns into
    #: numbers of the model's arrays without changing its topology (``plain``, ``rebuild``); none by default
    plain_parameters: tuple[str, ...] = ()
    #: keys a pattern of plain_parameters matches that do change the topology
    not_plain: tuple[str, ...] = ()

    def plain(self, key: str) -> bool:
        """Whether the dotted key of the vehicle file is a plain parameter of this kind (the answer kept
        per kind and key: a batch asks it for each key of each run)."""
        from fnmatch import fnmatchcase

        found = _PLAIN.get((type(self), key))
        if found is None:
            found = _PLAIN[type(self), key] = key not in self.not_plain and any(
                fnmatchcase(key, p) for p in self.plain_parameters)
        return found

    def rebuild(self, opened: "OpenedVehicle", built: "OpenedVehicle", changed=None) -> Any:
        """The model of ``opened``, whose config differs from the built vehicle ``built``'s in plain
        parameters only (``changed``: those dotted keys, when known): equal to ``build(opened)`` bit for
        bit, taking what ``built`` computed that they do not change (the default builds afresh)."""
        return self.build(opened)

    def scenario_problem(self, opened: "OpenedVehicle", sc) -> str | None:
        """Why the scenario cannot drive this vehicle (None: it can)."""
        return None

    def run_offline(self, opened: "OpenedVehicle", sc, progress: Callable[[float], None] | None = None,
                    seed: int = 0) -> OfflineRun:
        raise NotImplementedError

    def service_sim(self, opened: "OpenedVehicle", sc, dt: float | None, models: dict, rider: bool):
        """The vehicle at the scenario's start as the service steps it (its ``served()`` tuple)."""
        raise NotImplementedError

    def random_elements(self, opened: "OpenedVehicle", sc) -> list[str] | None:
        """What the seed of an offline run (``run_offline(seed=)``) draws in this vehicle driven by this
        scenario, one name each ("sensor noise on yaw_rate"); [] when nothing is random, so every seed
        gives the same run (a batch then simulates it once); None: not known, the seed may matter."""
        return None

    def demo(self, opened: "OpenedVehicle") -> Demo:
        raise NotImplementedError

    def user_inputs(self, opened: "OpenedVehicle"):
        """What a person may drive (rtsim.vehicle.kit.user_inputs.UserInputs): channels, ranges, full
        scales, the bus command each competes with, the page's groups of them."""
        raise NotImplementedError

    def validation(self, opened: "OpenedVehicle"):
        """The vehicle's validation profile (rtsim.vehicle.validation.ValidationProfile): what `rtsim
        validate` replays, compares and fits, and the replayer it re-simulates the vehicle with."""
        raise NotImplementedError

    def drawing(self, opened: "OpenedVehicle"):
        """How the vehicle is drawn (rtsim.vehicle.kit.drawing.Drawing: the 3D scene's and the viewer's
        description), from its config."""
        raise NotImplementedError

    def fuzz_rig(self, opened: "OpenedVehicle", dt: float):
        """What the command fuzzing (rtsim.robustness.harness) needs of the vehicle: its DBC, command slots,
        energy bound's terms, roads, the vehicle at a ride's start and its steps (rtsim.vehicle.car.fuzz
        states the interface)."""
        raise NotImplementedError


#: the fields `rtsim describe --json` reports for every vehicle (a kind adds its own after them), in SI
#: units: masses per body (kg), the geometry in the vehicle's design frame (m; wheel_centres one row per
#: wheel, front first), the channel dictionary's names (sensors, commands, state)
DESCRIBE_FIELDS = ("name", "id", "kind", "file", "n_coordinates", "n_constraints", "n_dof", "mass", "masses",
                   "geometry", "channels")
DESCRIBE_GEOMETRY = ("wheelbase", "track_front", "track_rear", "cg_height", "cg_to_front_axle", "wheel_centres")


@dataclass
class OpenedVehicle:
    """A vehicle file, opened: its path, kind, validated config and (built on first use) its model."""
    path: Path
    kind: VehicleKind
    config: Any
    base: Path
    _model: Any = None

    @property
    def name(self) -> str:
        return self.kind.name

    @property
    def model(self):
        if self._model is None:
            self._model = self.kind.build(self)
        return self._model

    def build_on(self, built: "OpenedVehicle", changed=None) -> None:
        """Build the model on the built vehicle ``built``, whose config differs from this one's in plain
        parameters only (``changed``: those dotted keys, when known; ``VehicleKind.rebuild``: the fresh
        build's model, bit for bit)."""
        if self._model is None:
            self._model = self.kind.rebuild(self, built, changed)

    def describe(self) -> dict:
        info = self.kind.describe(self)
        missing = [k for k in DESCRIBE_FIELDS if k not in info] + \
            [f"geometry.{k}" for k in DESCRIBE_GEOMETRY if k not in info.get("geometry", {})]
        if missing:
            raise RuntimeError(f"{type(self.kind).__name__}.describe lacks {', '.join(missing)}")
        geometry = {**{k: info["geometry"][k] for k in DESCRIBE_GEOMETRY}, **info["geometry"]}
        return {**{k: info[k] for k in DESCRIBE_FIELDS}, **info, "geometry": geometry}

    def refuse(self, command: str) -> None:
        """RtsimError (one line) when ``command`` does not apply to this vehicle."""
        why = self.kind.not_for.get(command)
        if why is not None:
            raise RtsimError(f"rtsim {command} does not apply to {self.path.name} (a {self.kind.name}): {why}")

    def check_scenario(self, sc) -> None:
        """ConfigError (one line) when the scenario cannot drive this vehicle."""
        why = self.kind.scenario_problem(self, sc)
        if why is not None:
            raise ConfigError(f"{sc.path}: cannot drive {self.path.name} (a {self.kind.name}): {why}")

    def run_offline(self, sc, progress=None, seed: int = 0) -> OfflineRun:
        self.check_scenario(sc)
        return self.kind.run_offline(self, sc, progress, seed)

    def service_sim(self, sc, dt: float | None = None, models: dict | None = None, rider: bool = True):
        self.check_scenario(sc)
        return self.kind.service_sim(self, sc, dt, {} if models is None else models, rider)

    @property
    def demo(self) -> Demo:
        return self.kind.demo(self)

    @property
    def user_inputs(self):
        """What a person may drive of the vehicle (the service's loop and config, the viewer's controls)."""
        return self.kind.user_inputs(self)

    @property
    def default_scenario(self) -> Path:
        return resolve_scenario(self.kind.default_scenario)

    @property
    def validation(self):
        """The vehicle's validation profile (rtsim.vehicle.validation), for `rtsim validate`."""
        return self.kind.validation(self)


def kind_of(data: dict, path: Path) -> VehicleKind:
    """The VehicleKind of a vehicle file's table: its ``assembly`` module's, else its ``kind``'s."""
    assembly = data.get("assembly")
    name = data.get("kind", DEFAULT_KIND)
    if assembly is not None:
        module_name, key = str(assembly), "assembly"
    elif name in KINDS:
        module_name, key = KINDS[name], "kind"
    else:
        raise ConfigError(f"{path}: kind = {name!r}: unknown vehicle kind (allowed: {', '.join(KINDS)}; or name "
                          f"an assembly module with assembly = \"package.module\")")
    try:
        module = _assembly_file(path, module_name) if module_name.endswith(".py") else \
            importlib.import_module(module_name)
    except ImportError as exc:
        raise ConfigError(f"{path}: {key} = {module_name!r}: cannot import it ({exc})") from None
    kind = getattr(module, "KIND", None)
    if not isinstance(kind, VehicleKind):
        raise ConfigError(f"{path}: {key} = {module_name!r}: the module defines no KIND (a VehicleKind)")
    return kind


def _assembly_file(vehicle_file: Path, name: str):
    """The assembly module of a Python file named relative to the vehicle file, loaded once per process
    (kept in sys.modules under a name made from its resolved path, so opening the vehicle again reuses
    it and the vehicle's compiled stages are registered once)."""
    import hashlib
    import importlib.util
    import sys

    file = (Path(vehicle_file).parent / name).resolve()
    if not file.is_file():
        raise ImportError(f"no such file {file}")
    mod_name = f"_rtsim_assembly_{file.stem}_{hashlib.sha1(str(file).encode()).hexdigest()[:10]}"
    module = sys.modules.get(mod_name)
    if module is None:
        spec = importlib.util.spec_from_file_location(mod_name, file)
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        try:
            spec.loader.exec_module(module)
        except BaseException:
            del sys.modules[mod_name]
            raise
    return module


def open_vehicle(path: str | Path | None) -> OpenedVehicle:
    """Open a vehicle file (a path or a name in configs/vehicles; None: the default car): read it once,
    choose its kind, validate it with the kind's loader. The model is built on first use."""
    p = resolve_vehicle(path) if path is not None else DEFAULT_VEHICLE
    data = load_toml(p)
    kind = kind_of(data, p)
    table = {k: v for k, v in data.items() if k != "assembly"}
    cfg, base = kind.load(table, p)
    return OpenedVehicle(p, kind, cfg, base)
