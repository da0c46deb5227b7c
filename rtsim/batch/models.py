"""A worker's opened vehicles, kept across its runs: each distinct vehicle (its file and the run's vehicle
overrides) is read, validated and built once per worker process, and every later run of it gets the same
opened vehicle, whose compiled model is immutable arrays (each run makes its own state: rtsim.vehicle's
``run_offline`` builds a fresh simulation on it). Likewise each distinct scenario (its file and the run's
scenario overrides) is read and validated once per worker (0.7 ms a run otherwise); a loaded scenario is
not changed by the runs on it (each run builds its own driver from it).

A run whose vehicle overrides differ from every kept one's is another vehicle: read and validated (its
values are read on load, so a bad one is that run's config error as before). When they differ from a kept
vehicle of the same file in the kind's plain parameters only (``VehicleKind.plain``: a mass, a
stiffness, a damper, a gain; the car's list is rtsim.vehicle.car.plain) its model is built on that one
(``VehicleKind.rebuild``: the car's keys declared in place reach copies of the kept model's affected
arrays, the others build on its corner fits and symbolic analysis; bit for bit a fresh build's); any
other difference (a tyre model, a hardpoint: the topology or
the fits) builds it from scratch. The input files are taken not to change during a batch (a run id
hashes them at the start: rtsim.batch.inputs).

The worker keeps at most ``KEEP`` vehicles (the least recently used goes first), so a random sweep
over a continuous parameter does not fill its memory."""
from __future__ import annotations

import json
from collections import OrderedDict
from pathlib import Path

from .inputs import open_run

KEEP = 32
#: scenarios kept per worker (a few tens of kB each)
KEEP_SCENARIOS = 256


class OpenedVehicles:
    """(resolved vehicle file, its overrides) -> opened vehicle with its model built; ``built`` counts the
    vehicles opened and built (``rebuilt`` of them on a kept one), ``reused`` the runs that got a kept
    one."""

    def __init__(self, keep: int = KEEP, keep_scenarios: int = KEEP_SCENARIOS):
        self.keep, self.keep_scenarios = keep, keep_scenarios
        self.kept: OrderedDict = OrderedDict()
        self.built = 0
        self.rebuilt = 0
        self.reused = 0
        self.roads: dict = {}        # the roads built in this worker (rtsim.road.config.keeping_roads)
        self.tables: dict = {}       # the TOML files parsed in this worker (rtsim.configfile.keeping_tables)
        self._paths: dict = {}       # vehicle file as given -> its resolved path
        self._overrides: dict = {}   # a kept vehicle's overrides as keyed (JSON) -> read back (built_like)
        self.scenarios: OrderedDict = OrderedDict()    # (scenario file as given, overrides key) -> Scenario

    def open_run(self, scenario: str | Path, vehicle: str | Path | None, overrides: dict):
        """(scenario, opened vehicle) of a run, as rtsim.batch.inputs.open_run opens them (same loaders,
        same order, same errors), the vehicle a kept one when this worker opened it before."""
        return open_run(scenario, vehicle, overrides, kept=self)

    def scenario(self, path: Path, scen_over: dict):
        """The kept scenario of this file and overrides (None: not read yet, or no longer kept)."""
        key = (path, overrides_key(scen_over))
        sc = self.scenarios.get(key)
        if sc is not None:
            self.scenarios.move_to_end(key)
        return sc

    def keep_scenario(self, path: Path, scen_over: dict, sc) -> None:
        """Keep a scenario just read (the least recently used out beyond ``keep_scenarios``)."""
        self.scenarios[(path, overrides_key(scen_over))] = sc
        while len(self.scenarios) > self.keep_scenarios:
            self.scenarios.popitem(last=False)

    def _key(self, vpath: Path, veh_over: dict) -> tuple[str, str]:
        return self._resolved(vpath), overrides_key(veh_over)

    def _resolved(self, vpath: Path) -> str:
        """The vehicle file's resolved path, resolved once per worker (a few file-system calls each time;
        the input files do not move during a batch)."""
        found = self._paths.get(vpath)
        if found is None:
            found = self._paths[vpath] = str(Path(vpath).resolve())
        return found

    def get(self, vpath: Path, veh_over: dict):
        """The kept vehicle of this file and overrides (None: not opened yet, or no longer kept)."""
        key = self._key(vpath, veh_over)
        opened = self.kept.get(key)
        if opened is not None:
            self.kept.move_to_end(key)
            self.reused += 1
        return opened

    def built_like(self, vpath: Path, veh_over: dict):
        """(the most recently used kept vehicle of this file whose overrides differ from ``veh_over`` in its
        kind's plain parameters only, the dotted keys that differ; a key set in one and not the other counts
        as differing); None when there is none. Counted in ``rebuilt``."""
        file = self._resolved(vpath)
        new = json.loads(json.dumps(veh_over, sort_keys=True, default=repr))
        for (kfile, kover), opened in reversed(self.kept.items()):
            if kfile != file:
                continue
            over = self._overrides[kover]
            changed = {k for k in over.keys() | new.keys() if over.get(k, _MISSING) != new.get(k, _MISSING)}
            if all(opened.kind.plain(k) for k in changed):
                self.rebuilt += 1
                return opened, changed
        return None

    def put(self, vpath: Path, veh_over: dict, opened) -> None:
        """Keep a vehicle just opened and built (the least recently used out beyond ``keep``)."""
        key = self._key(vpath, veh_over)
        self.kept[key] = opened
        if key[1] not in self._overrides:
            self._overrides[key[1]] = json.loads(key[1])
        self.built += 1
        while len(self.kept) > self.keep:
            (_, gone), _ = self.kept.popitem(last=False)
            if all(k[1] != gone for k in self.kept):
                self._overrides.pop(gone, None)


_MISSING = object()


def overrides_key(veh_over: dict) -> str:
    """A run's vehicle overrides as one string (JSON, keys sorted): equal for the same vehicle."""
    return json.dumps(veh_over, sort_keys=True, default=repr)

#: this worker process's vehicles (one batch runs per process at a time)
WORKER = OpenedVehicles()
