"""A plan expanded into run specs: cases x (grid points x random samples) x repetitions, each spec a
plain dict (picklable, JSON-able) that names its files, its dotted-path overrides and its seed, and a
run id: a hash of what determines the run's result (the files' contents, the overrides, the seed), so a
resumed batch recognises the runs it already has and a changed config file makes new ones."""
from __future__ import annotations

import hashlib
import itertools
import json
from pathlib import Path

import numpy as np

from .plan import Plan


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def points(plan: Plan) -> list[dict]:
    """The parameter points: the grid's full factorial (keys in file order) times the random sample
    (seeded by plan.seed: the same plan gives the same points on any machine)."""
    keys = list(plan.grid)
    grid = [dict(zip(keys, combo)) for combo in itertools.product(*(plan.grid[k] for k in keys))] or [{}]
    if plan.random is None:
        return grid
    rng = np.random.default_rng(plan.seed)
    sample = []
    for _ in range(plan.random.samples):
        p = {}
        for k, d in plan.random.params.items():
            if d.uniform is not None:
                p[k] = float(rng.uniform(*d.uniform))
            else:
                p[k] = d.choice[int(rng.integers(len(d.choice)))]
        sample.append(p)
    return [{**g, **s} for g in grid for s in sample]


def expand(plan: Plan, base: Path) -> list[dict]:
    """Every run of the plan, in plan order."""
    specs = []
    pts = points(plan)
    for ci, case in enumerate(plan.cases):
        scen = (base / case.scenario).resolve()
        veh = (base / case.vehicle).resolve() if case.vehicle else None
        files = {"scenario": _digest(scen), "vehicle": _digest(veh) if veh else None}
        for p in pts:
            for rep in range(plan.repetitions):
                seed = plan.seed_base + rep
                overrides = {**case.overrides, **p}
                ident = {"case": [case.scenario, case.vehicle], "files": files, "overrides": overrides, "seed": seed}
                run_id = hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:16]
                specs.append({"run_id": run_id, "case": ci, "scenario": str(scen),
                              "vehicle": None if veh is None else str(veh), "overrides": overrides,
                              "params": dict(p), "seed": seed})
    return specs


def split_overrides(overrides: dict) -> tuple[dict, dict]:
    """(vehicle overrides, scenario overrides), the `vehicle.` / `scenario.` prefix removed."""
    veh, scen = {}, {}
    for k, v in overrides.items():
        head, _, rest = k.partition(".")
        (veh if head == "vehicle" else scen)[rest] = v
    return veh, scen
