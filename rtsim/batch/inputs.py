"""What a run reads: its scenario and vehicle opened exactly as the run opens them (its dotted-path
overrides applied as the files are read), and the resolved set of every input file the config loaders
read on the way (rtsim.configfile.recording_reads): the plan's scenario and vehicle files, the vehicle file
a scenario names (or the default car), tyre files, the road file and the survey it names, recorded
inputs and path files, DBCs where read. A run id hashes the content of each of these files (not their
modification times), so editing any of them, however deeply nested, gives the run a new id.

A run whose configs cannot be opened (a bad value at one grid point) hashes the files read up to the
error: the error is what those files make of the run."""
from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class RunInputs:
    """files: resolved path -> sha256 of its bytes ("missing" when it cannot be read); random: what the
    run's seed draws (names of the random elements: () nothing, so every seed gives the same run; None
    when the vehicle's kind does not say, so the seed is taken to matter)."""
    files: dict[str, str]
    random: tuple[str, ...] | None


def split_overrides(overrides: dict) -> tuple[dict, dict]:
    """(vehicle overrides, scenario overrides), the `vehicle.` / `scenario.` prefix removed."""
    veh, scen = {}, {}
    for k, v in overrides.items():
        head, _, rest = k.partition(".")
        (veh if head == "vehicle" else scen)[rest] = v
    return veh, scen


def open_run(scenario: str | Path, vehicle: str | Path | None, overrides: dict, build: bool = True, kept=None):
    """(scenario, opened vehicle) of a run as it runs: the scenario file, then the vehicle (the given
    file, else the scenario's, else the default car), both read under the run's overrides; with
    ``build`` the model is built under them too (their values are read on load). ConfigError (or the
    vehicle's RtsimError refusing a batch) when they cannot be. ``kept``: a worker's opened vehicles
    (rtsim.batch.models.OpenedVehicles), asked for the scenario and the vehicle first, else for a built
    vehicle of the same file whose overrides differ in plain parameters only (the model is then built on
    it), and given the ones opened."""
    from rtsim.configfile import overrides as with_overrides
    from rtsim.vehicle.registry import DEFAULT_VEHICLE, open_vehicle

    scen = Path(scenario)
    veh_over, scen_over = split_overrides(overrides)
    files = {}                                  # read at each load: filled before the file it names is read
    with with_overrides(files):
        sc = _scenario(scen, scen_over, files, kept)
        vpath = Path(vehicle) if vehicle else (sc.vehicle_path or DEFAULT_VEHICLE)
        opened = None if kept is None else kept.get(vpath, veh_over)
        if opened is not None:
            opened.check_scenario(sc)
            return sc, opened
        files[vpath.resolve()] = veh_over
        opened = open_vehicle(vpath)
        opened.refuse("batch")
        opened.check_scenario(sc)
        if build:
            like = None if kept is None else kept.built_like(vpath, veh_over)
            if like is not None:
                opened.build_on(*like)
            opened.model
        if kept is not None:
            kept.put(vpath, veh_over, opened)
    return sc, opened


def _scenario(scen: Path, scen_over: dict, files: dict, kept):
    """The run's scenario: the kept one of this file and overrides, else read (under ``files``, the
    overrides of the loads in progress) and kept."""
    from drivers.scenario import load_scenario

    sc = None if kept is None else kept.scenario(scen, scen_over)
    if sc is None:
        files[scen.resolve()] = scen_over
        sc = load_scenario(scen, check_files=True)
        if kept is not None:
            kept.keep_scenario(scen, scen_over, sc)
    return sc


def keep_scenario(scenario: str | Path, overrides: dict, kept) -> None:
    """Read a run's scenario as open_run reads it and keep it in ``kept`` (a worker's opened vehicles),
    with what its runs' drivers share made (the followers' parameters, range-checked when made), so
    that the run finds it ready; a scenario that cannot be read is left for the run to report."""
    from rtsim.configfile import overrides as with_overrides
    from rtsim.errors import RtsimError

    files = {}
    with with_overrides(files):
        try:
            _scenario(Path(scenario), split_overrides(overrides)[1], files, kept).driver()
        except RtsimError:
            pass


def digest(path: Path) -> str:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return "missing"


def _road_reads(road: Path) -> frozenset[Path]:
    """The files the road loader reads for the road file `road` (a road is never overridden)."""
    from rtsim.configfile import recording_reads
    from rtsim.road.config import load_road

    with recording_reads() as seen:
        try:
            load_road(road)
        except Exception:  # noqa: BLE001  (the run meets the same error and records it; the files read count)
            pass
    return frozenset(seen)


def run_inputs(scenario: str | Path, vehicle: str | Path | None, overrides: dict,
               roads: dict | None = None) -> RunInputs:
    """The files a run reads (with their content hashes) and what its seed draws; the configs are
    loaded, not the model built (10-20 ms a run once the loaders are imported). ``roads``: a cache of
    the road loader's reads by road file, for one expansion (a mesh road takes about a second to load).
    Never raises for a config error: the files read up to it are the run's inputs."""
    from rtsim.configfile import recording_reads
    from rtsim.errors import RtsimError

    roads = {} if roads is None else roads
    random: tuple[str, ...] | None = ()
    with recording_reads() as seen:
        try:
            sc, opened = open_run(scenario, vehicle, overrides, build=False)
        except RtsimError:
            sc = opened = None                   # the run will stop at the same error: no seed in it
        except Exception:  # noqa: BLE001  (a loader's bug: the run records it; its seed may matter)
            sc = opened = random = None
        if sc is not None:
            if sc.road_path not in roads:
                roads[sc.road_path] = _road_reads(sc.road_path)
            seen |= roads[sc.road_path]
            try:
                found = opened.kind.random_elements(opened, sc)
                random = None if found is None else tuple(found)
            except Exception:  # noqa: BLE001  (a kind that cannot tell: the seed is taken to matter)
                random = None
    return RunInputs({str(p): digest(p) for p in sorted(seen)}, random)
