"""The batch plan file (TOML through rtsim.configfile: errors name the file, the key, the value and the
allowed range).

    name = "brake_sweep"
    seed = 7                       # seeds the random sample
    repetitions = 2                # each point run with seeds seed_base, seed_base + 1, ...
    seed_base = 0
    metrics = ["stopping_distance", "peak_lateral_acceleration"]
    per_run = "none"               # or "csv" / "mcap": each run's rows beside the table

    [[cases]]                      # what is run: a scenario, optionally another vehicle file
    scenario = "../scenarios/step_steer_80kph.toml"
    vehicle = "../vehicles/eps_car.toml"
    overrides = { "scenario.duration" = 1.0 }

    [grid]                         # full factorial over dotted config paths
    "vehicle.chassis.mass_kg" = [700.0, 800.0]

    [random]                       # and/or a seeded random sample
    samples = 10
    [random.params]
    "vehicle.tyres.scale" = { uniform = [0.9, 1.1] }
    "scenario.rider.p_roll" = { choice = [200.0, 400.0] }

    [[criteria]]                   # pass/fail on metrics
    metric = "stopping_distance"
    max = 45.0

A dotted path starts with `vehicle.` or `scenario.` (which config file it changes) followed by the keys
of that file; the value replaces (or adds) that key before the file is validated, so a bad value makes
that run's recorded config error, not the batch's.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal, Optional

from pydantic import Field, model_validator

from rtsim.configfile import Range, Strict, bad, load, problem

from .metrics import METRICS

PATH_PATTERN = r"^(vehicle|scenario)\.[A-Za-z0-9_]+(\.[A-Za-z0-9_]+)*$"
Value = Any     # a TOML value: number, string, boolean, list, table


class Case(Strict):
    scenario: str = Field(min_length=1, description="scenario TOML, relative to the plan, or a name in "
                          "configs/scenarios")
    vehicle: Optional[str] = Field(default=None, description="vehicle TOML, relative to the plan, or a name in "
                                   "configs/vehicles (default: the scenario's)")
    overrides: dict[str, Value] = {}

    @model_validator(mode="after")
    def _check(self):
        _check_paths("overrides", self.overrides)
        return self


#: a metric's or a swept key's value: any finite number, in its own unit (a grid may sweep any key)
Finite = Range(-math.inf, math.inf, "the key's or metric's unit", lo_open=True, hi_open=True)


class Distribution(Strict):
    uniform: Optional[tuple[Finite, Finite]] = None
    choice: Optional[list[Value]] = Field(default=None, min_length=1)

    @model_validator(mode="after")
    def _check(self):
        if (self.uniform is None) == (self.choice is None):
            raise bad("uniform", self.uniform, "give exactly one of uniform = [lo, hi] or choice = [...]")
        if self.uniform is not None:
            lo, hi = self.uniform
            if not lo <= hi:
                raise bad("uniform", list(self.uniform), "must be [lo, hi], finite, lo <= hi")
        return self


class RandomSample(Strict):
    samples: Range(1, 1_000_000, integer=True) = Field(description="number of random points")
    params: dict[str, Distribution] = Field(min_length=1)

    @model_validator(mode="after")
    def _check(self):
        _check_paths("params", self.params)
        return self


class Criterion(Strict):
    metric: str
    min: Optional[Finite] = None
    max: Optional[Finite] = None

    @model_validator(mode="after")
    def _check(self):
        if self.metric not in METRICS:
            raise bad("metric", self.metric, f"unknown metric (known: {', '.join(METRICS)})")
        if self.min is None and self.max is None:
            raise bad("max", None, "a criterion needs min, max or both")
        return self


class Plan(Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    seed: Range(0, 2**32 - 1, integer=True) = Field(default=0, description="seed of the random sample")
    seed_base: Range(0, 2**32 - 1, integer=True) = Field(default=0, description="first run seed (sensor noise)")
    repetitions: Range(1, 10_000, integer=True) = 1
    metrics: list[str] = Field(min_length=1)
    per_run: Literal["none", "csv", "mcap"] = "none"
    cases: list[Case] = Field(min_length=1)
    grid: dict[str, list[Value]] = {}
    random: Optional[RandomSample] = None
    criteria: list[Criterion] = []

    @model_validator(mode="after")
    def _check(self):
        for i, m in enumerate(self.metrics):
            if m not in METRICS:
                raise bad(f"metrics[{i}]", m, f"unknown metric (known: {', '.join(METRICS)})")
        _check_paths("grid", self.grid)
        for k, v in self.grid.items():
            if not v:
                raise bad("grid", k, "must list at least one value for this key")
        if self.random is not None:
            both = sorted(set(self.grid) & set(self.random.params))
            if both:
                raise bad("random.params", both[0], "also in [grid]: sample or grid a key, not both")
        return self


def _check_paths(section: str, table: dict) -> None:
    import re

    for k in table:
        if not re.match(PATH_PATTERN, k):
            raise bad(section, k, "keys must be dotted paths starting with vehicle. or scenario.")


def load_plan(path: str | Path) -> tuple[Plan, Path]:
    """The validated plan and the folder its relative paths refer to; every case's files must exist."""
    path = Path(path)
    plan = load(Plan, path)
    from rtsim.vehicle.registry import SCENARIOS, VEHICLES

    for i, c in enumerate(plan.cases):
        for key, folder in (("scenario", SCENARIOS), ("vehicle", VEHICLES)):
            rel = getattr(c, key)
            if rel is None or (path.parent / rel).is_file():
                continue
            named = folder / f"{rel}.toml"          # a name of a shipped config
            if "/" not in rel and named.is_file():
                c = plan.cases[i] = c.model_copy(update={key: str(named)})
                continue
            raise problem(path, f"cases[{i}].{key}", rel, f"file not found ({(path.parent / rel).resolve()}) and "
                          f"no configs/{folder.name}/{rel}.toml")
    return plan, path.parent
