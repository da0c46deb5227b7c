"""One run spec (rtsim.batch.expand) -> one result row. Never raises: a config error (a bad value at one
grid point), a Newton failure, a fall or any other exception is the row's status and error text, and
the batch goes on.

The spec's dotted-path overrides are applied to the vehicle's and the scenario's TOML tables as they are
read, before validation (rtsim.configfile.overrides), so the one loader checks them like any value in
the file (file, key, value, allowed range)."""
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

def _simulate(spec: dict, job: dict) -> tuple[str, str, tuple, object, object]:
    """(status, message, columns, data, writer) of the spec's run, on the vehicle the registry opens
    (rtsim.vehicle.registry: the spec's vehicle, else the scenario's, else the default car)."""
    sc, vehicle = open_run(spec["scenario"], spec["vehicle"], spec["overrides"])
    res = vehicle.run_offline(sc, seed=spec["seed"])
    from bridge.mcap_log import write_offline
    write = {"csv": lambda p: write_offline(res, Path(p).with_suffix(".csv")),
             "mcap": lambda p: write_offline(res, Path(p).with_suffix(".mcap"))}
    return res.status, res.message, res.columns, res.data, write


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
    the metrics, wall time (s) and the worker (host:pid)."""
    t0 = time.perf_counter()
    status, error, columns, data = "ok", "", (), None
    try:
        status, error, columns, data, write = _simulate(spec, job)
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
    return {"run_id": spec["run_id"], "case": spec["case"], "scenario": Path(spec["scenario"]).stem,
            "vehicle": Path(spec["vehicle"]).stem if spec["vehicle"] else "", "seed": spec["seed"],
            **{k: spec["params"].get(k) for k in job["param_keys"]},
            "status": status, "verdict": ver, "failed": failed, "error": error, "simulated_s": simulated,
            **metrics, "wall_s": time.perf_counter() - t0, "worker": f"{socket.gethostname()}:{os.getpid()}"}


def lost_row(spec: dict, job: dict, reason: str) -> dict:
    """The row of a run whose worker never returned (its process died on every attempt)."""
    return {"run_id": spec["run_id"], "case": spec["case"], "scenario": Path(spec["scenario"]).stem,
            "vehicle": Path(spec["vehicle"]).stem if spec["vehicle"] else "", "seed": spec["seed"],
            **{k: spec["params"].get(k) for k in job["param_keys"]}, "status": "error", "verdict": "error",
            "failed": "", "error": reason, "simulated_s": math.nan, **{m: math.nan for m in job["metrics"]},
            "wall_s": math.nan, "worker": ""}


def warm(spec: dict, job: dict) -> None:
    """Load (or compile) a worker's kernels once: the spec's run cut to 20 ms, its result dropped."""
    short = {**spec, "overrides": {**spec["overrides"], "scenario.duration": 0.02}}
    run_one(short, {**job, "per_run": "none", "criteria": []})
