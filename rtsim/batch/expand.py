"""A plan expanded into run specs: cases x (grid points x random samples) x repetitions, each spec a
plain dict (picklable, JSON-able) that names its files, its dotted-path overrides and its seed, and a
run id: a hash of what determines the run's result (the content of every file the run reads, nested ones
included: rtsim.batch.inputs; the overrides; the seed), so a resumed batch recognises the runs it already
has and a changed config file, a tyre or road file among them, makes new ones."""
from __future__ import annotations

import hashlib
import itertools
import json
import os
from pathlib import Path

import numpy as np

from .inputs import run_inputs, split_overrides
from .plan import Plan

__all__ = ["expand", "points", "split_overrides"]


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
    """Every run of the plan, in plan order. Each spec holds its id, its files, overrides, swept
    parameters and seed, the files it reads (`inputs`: resolved path -> sha256) and what its seed draws
    (`random`: names; [] nothing; None not known)."""
    specs = []
    pts = points(plan)
    roads: dict = {}
    for ci, case in enumerate(plan.cases):
        scen = (base / case.scenario).resolve()
        veh = (base / case.vehicle).resolve() if case.vehicle else None
        for p in pts:
            overrides = {**case.overrides, **p}
            inputs = run_inputs(scen, veh, overrides, roads)
            files = {Path(os.path.relpath(f, base)).as_posix(): h for f, h in inputs.files.items()}
            for rep in range(plan.repetitions):
                seed = plan.seed_base + rep
                ident = {"case": [case.scenario, case.vehicle], "files": files, "overrides": overrides, "seed": seed}
                run_id = hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:16]
                specs.append({"run_id": run_id, "case": ci, "scenario": str(scen),
                              "vehicle": None if veh is None else str(veh), "overrides": overrides,
                              "params": dict(p), "seed": seed, "inputs": dict(inputs.files),
                              "random": None if inputs.random is None else list(inputs.random)})
    return specs
