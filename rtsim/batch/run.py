"""One run spec (rtsim.batch.expand) -> one result row. Never raises: a config error (a bad value at one
grid point), a Newton failure, a fall or any other exception is the row's status and error text, and
the batch goes on.

The spec's dotted-path overrides are applied to the vehicle's and the scenario's TOML tables as they are
read, before validation (rtsim.configfile.overrides), so the one loader checks them like any value in
the file (file, key, value, allowed range). A worker opens and builds each distinct vehicle once
(rtsim.batch.models; ``job["build_once"] = False`` builds every run's afresh).

Where a run's wall time goes: ``step_s`` is the time inside the model's steps (NaN for a kind that does
not measure it), ``outside_s`` the rest of the run's wall time (reading and validating its files,
building or reusing the model, the start on the road, the driver and the logged rows between the steps,
the metrics) and ``outside_pct`` that rest in per cent of the wall time: step_s + outside_s = wall_s.
``between_s`` is the time the worker spent before the run, since its previous row was made (or since it
was ready, ``mark_ready``): returning that row and receiving this run (the executor's pickling and
pipes), in no run's wall time."""
from __future__ import annotations

import math
import os
import socket
import time
import traceback
from pathlib import Path

from rtsim.errors import ConfigError, SimulationError

from .inputs import open_run
from .metrics import compute
from .models import WORKER

#: the timing columns of a row, after wall_s (s, s, %, s)
TIMING = ("step_s", "outside_s", "outside_pct", "between_s")

#: perf_counter when this worker process made its last row (or was ready for its first run)
_LAST = [math.nan]


def mark_ready() -> None:
    """This worker is ready for its first run: the next row's ``between_s`` counts from now."""
    _LAST[0] = time.perf_counter()

def _simulate(spec: dict, job: dict) -> tuple[str, str, tuple, object, object, float]:
    """(status, message, columns, data, writer, step time in s) of the spec's run, on the vehicle the
    registry opens (rtsim.vehicle.registry: the spec's vehicle, else the scenario's, else the default
    car), kept by this worker from an earlier run of the same vehicle, on the worker's kept roads and
    parsed files (rtsim.road.config.keeping_roads, rtsim.configfile.keeping_tables), unless
    ``job["build_once"]`` is False."""
    from rtsim.configfile import keeping_tables
    from rtsim.road.config import keeping_roads

    once = job.get("build_once", True)
    opener = WORKER.open_run if once else open_run
    with keeping_tables(WORKER.tables if once else {}), keeping_roads(WORKER.roads if once else {}):
        sc, vehicle = opener(spec["scenario"], spec["vehicle"], spec["overrides"])
        res = vehicle.run_offline(sc, seed=spec["seed"])
    from bridge.mcap_log import write_offline
    write = {"csv": lambda p: write_offline(res, Path(p).with_suffix(".csv")),
             "mcap": lambda p: write_offline(res, Path(p).with_suffix(".mcap"))}
    return res.status, res.message, res.columns, res.data, write, res.step_s


def timing(wall: float, step: float, between: float = math.nan) -> dict:
    """The timing columns of a run of `wall` s of which `step` s were in the model's steps, `between` s
    spent by its worker before it since its previous row."""
    if not math.isfinite(step):
        return {"step_s": math.nan, "outside_s": math.nan, "outside_pct": math.nan, "between_s": between}
    outside = wall - step
    return {"step_s": step, "outside_s": outside, "outside_pct": 100.0 * outside / wall if wall > 0 else math.nan,
            "between_s": between}


def verdict(status: str, metrics: dict, criteria: list) -> tuple[str, str]:
    """("pass" | "fail" | "error", the failed criteria or the reason)."""
    if status in ("config_error", "error"):
        return "error", ""
    failed = [] if status == "ok" else [status]
    for metric, lo, hi in criteria:
        v = metrics.get(metric, math.nan)
        if not math.isfinite(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
            failed.append(f"{metric}={v:.6g} not in [{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]")
    return ("fail" if failed else "pass"), "; ".join(failed)


def run_one(spec: dict, job: dict) -> dict:
    """The result row of one run: run id, case, scenario, vehicle, seed, the swept parameters, status
    (ok, fall, failed, config_error, error), verdict, failed criteria, error text, simulated time (s),
    the metrics, wall time (s), the timing columns (TIMING) and the worker (host:pid)."""
    t0 = time.perf_counter()
    between = t0 - _LAST[0]
    status, error, columns, data, step = "ok", "", (), None, 0.0
    try:
        status, error, columns, data, write, step = _simulate(spec, job)
        if job.get("per_run", "none") != "none" and job.get("out_dir"):
            folder = Path(job["out_dir"]) / "runs"
            folder.mkdir(parents=True, exist_ok=True)
            write[job["per_run"]](folder / f"{spec['run_id']}.{job['per_run']}")
    except ConfigError as exc:
        status, error = "config_error", str(exc)
    except SimulationError as exc:
        status, error = "failed", str(exc)
    except Exception as exc:  # noqa: BLE001  (one run's bug must not end the batch: recorded with its place)
        tb = traceback.extract_tb(exc.__traceback__)[-1]
        status, error = "error", f"{type(exc).__name__}: {exc} ({Path(tb.filename).name}:{tb.lineno})"
    metrics = compute(job["metrics"], columns, data) if data is not None and len(data) else \
        {m: math.nan for m in job["metrics"]}
    ver, failed = verdict(status, metrics, job.get("criteria", []))
    simulated = float(data[-1, 0]) if data is not None and len(data) else math.nan
    t1 = time.perf_counter()
    wall = t1 - t0
    _LAST[0] = t1
    return {"run_id": spec["run_id"], "case": spec["case"], "scenario": Path(spec["scenario"]).stem,
            "vehicle": Path(spec["vehicle"]).stem if spec["vehicle"] else "", "seed": spec["seed"],
            **{k: spec["params"].get(k) for k in job["param_keys"]},
            "status": status, "verdict": ver, "failed": failed, "error": error, "simulated_s": simulated,
            **metrics, "wall_s": wall, **timing(wall, step, between), "worker": f"{socket.gethostname()}:{os.getpid()}"}


def lost_row(spec: dict, job: dict, reason: str) -> dict:
    """The row of a run whose worker never returned (its process died on every attempt)."""
    return {"run_id": spec["run_id"], "case": spec["case"], "scenario": Path(spec["scenario"]).stem,
            "vehicle": Path(spec["vehicle"]).stem if spec["vehicle"] else "", "seed": spec["seed"],
            **{k: spec["params"].get(k) for k in job["param_keys"]}, "status": "error", "verdict": "error",
            "failed": "", "error": reason, "simulated_s": math.nan, **{m: math.nan for m in job["metrics"]},
            "wall_s": math.nan, **{c: math.nan for c in TIMING}, "worker": ""}


def warm(spec: dict, job: dict, full: bool = False) -> None:
    """Load (or compile) a worker's kernels once: the spec's run cut to 20 ms (``full``: the whole run),
    its result dropped."""
    if not full:
        spec = {**spec, "overrides": {**spec["overrides"], "scenario.duration": 0.02}}
    run_one(spec, {**job, "per_run": "none", "criteria": []})
