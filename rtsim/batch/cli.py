"""`rtsim batch PLAN.toml`: expand the plan, skip the runs the output folder's journal already holds,
run the rest on the local pool (default) or Ray (--ray auto|ADDRESS), journal each row as it arrives
with progress and an ETA on stderr, then write results.parquet, results.csv (sorted by run id) and
report.html. Exit status 0 when every run passes, 1 when any fails or errors.

Runs that differ only by their seed while nothing in them draws from it (rtsim.batch.inputs: no sensor
noise) are simulated once, and the others get a copy of its row with `copy_of` naming it; one line at
the start says so."""
from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

from .expand import expand
from .plan import load_plan
from .results import Journal, sorted_rows, write_tables
from .run import TIMING


def add_arguments(p) -> None:
    p.add_argument("plan", metavar="PLAN.toml", help="the plan TOML (configs/batch/)")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (default: batch_<plan name>/ in the current folder); a journal "
                   "there from an interrupted batch of the same plan is resumed")
    p.add_argument("--workers", type=int, metavar="N", help="local pool: worker processes (default: one per core)")
    p.add_argument("--ray", metavar="auto|ADDRESS", help="run on Ray: 'auto' starts a local instance bound to "
                   "127.0.0.1, else the address of a running cluster (host:port)")
    p.add_argument("--retries", type=int, default=3, metavar="N",
                   help="Ray: times a run lost with its worker is retried (3)")
    p.add_argument("--no-report", action="store_true", help="skip the HTML summary")
    p.add_argument("--limit", type=int, metavar="N",
                   help="run at most this many of the missing runs (then stop; resumable)")


def columns(plan, params: list[str]) -> list[str]:
    return ["run_id", "case", "scenario", "vehicle", "seed", *params, "status", "verdict", "failed", "error",
            "simulated_s", *plan.metrics, "wall_s", *TIMING, "worker", "copy_of"]


def same_runs(specs: list[dict]) -> dict[str, str]:
    """run id -> the id of the run simulated for it: itself, or, for a run that differs from an earlier
    one of the plan only by its seed while nothing in it draws from the seed (spec "random" == []), the
    first such run (lowest seed)."""
    import json

    first: dict[str, str] = {}
    out = {}
    for s in specs:
        if s.get("random") == []:
            key = json.dumps([s["case"], s["overrides"]], sort_keys=True, default=str)
            out[s["run_id"]] = first.setdefault(key, s["run_id"])
        else:
            out[s["run_id"]] = s["run_id"]
    return out


def seed_note(plan, specs: list[dict], rep: dict[str, str]) -> str | None:
    """One line when the plan sweeps seeds and some runs draw nothing from theirs (None otherwise)."""
    copies = sum(rep[s["run_id"]] != s["run_id"] for s in specs)
    if plan.repetitions < 2 or copies == 0:
        return None
    simulated = f"{len(specs) - copies} of the {len(specs)} runs are simulated, the others are copies (column copy_of)"
    if all(s.get("random") == [] for s in specs):
        return (f"{plan.name}: note: the plan runs each point with {plan.repetitions} seeds, but no run has anything "
                f"random (no sensor noise): the seeds change nothing, so each point is simulated once: {simulated}")
    seedless = sum(s.get("random") == [] for s in specs)
    return (f"{plan.name}: note: the plan runs each point with {plan.repetitions} seeds, but {seedless} runs have "
            f"nothing random (no sensor noise): their seeds change nothing, so those are simulated once per point: "
            f"{simulated}")


def copy_row(row: dict, spec: dict, job: dict) -> dict:
    """The row of `spec`, a run identical to the simulated run of `row` but for its seed: that row, with
    its own id and seed, no wall time or worker of its own, and `copy_of` naming the simulated run (its
    per-run file, if any, copied too)."""
    if job.get("per_run", "none") != "none" and job.get("out_dir"):
        import shutil

        folder = Path(job["out_dir"]) / "runs"
        src = folder / f"{row['run_id']}.{job['per_run']}"
        if src.is_file():
            shutil.copyfile(src, folder / f"{spec['run_id']}.{job['per_run']}")
    return {**row, "run_id": spec["run_id"], "seed": spec["seed"], "wall_s": 0.0, "step_s": 0.0, "outside_s": 0.0,
            "outside_pct": float("nan"), "between_s": 0.0, "worker": "",
            "copy_of": row["run_id"]}


def timing_summary(rows: list[dict]) -> str:
    """Where the simulated runs' wall time went (rows of runs simulated now, copies left out): the time
    in the model's steps and outside them in all, the median and largest share outside per run; then the
    time the workers spent between runs (``between_s``: in no run's wall time), in all and per run, and
    the per-run share outside the steps with each run's time before it counted in (median, max)."""
    import statistics

    runs = [r for r in rows if r.get("worker") and math.isfinite(r.get("step_s", math.nan))
            and math.isfinite(r.get("wall_s", math.nan)) and r["wall_s"] > 0]
    if not runs:
        return ""
    wall = sum(r["wall_s"] for r in runs)
    step = sum(r["step_s"] for r in runs)
    pct = [r["outside_pct"] for r in runs]
    out = (f"; time in the model's steps {step:.2f} s, outside them {wall - step:.2f} s "
           f"({100.0 * (wall - step) / wall:.1f} % of {wall:.2f} s; per run median {statistics.median(pct):.1f} %, "
           f"max {max(pct):.1f} %)")
    gaps = [r for r in runs if math.isfinite(r.get("between_s", math.nan))]
    if not gaps:
        return out
    between = [r["between_s"] for r in gaps]
    with_gap = [100.0 * (r["outside_s"] + r["between_s"]) / (r["wall_s"] + r["between_s"]) for r in gaps]
    return (out + f"; between runs {sum(between):.2f} s (per run median {1e3 * statistics.median(between):.1f} ms, "
            f"max {1e3 * max(between):.1f} ms; outside the steps with it: per run median "
            f"{statistics.median(with_gap):.1f} %, max {max(with_gap):.1f} %)")


def ready_after(row: dict, arrived: float) -> float:
    """When the worker of its first `row` was ready for it (s since the batch started): the row's arrival
    `arrived` less its wall time and the worker's time before it (``between_s``, counted from when it was
    ready: rtsim.batch.run.mark_ready). NaN where the worker does not say when it was ready (Ray's)."""
    between = row.get("between_s", math.nan)
    wall = row.get("wall_s", math.nan)
    if not (math.isfinite(between) and math.isfinite(wall)):
        return math.nan
    return arrived - wall - between


def ready_summary(ready: dict[str, float]) -> str:
    """The workers' start-up, in no run's time: process start, imports, kernels loaded or compiled and the
    plan's vehicles built (rtsim.batch.executors.warm_specs), from the batch's start to the last worker's
    readiness (empty when none says)."""
    known = [v for v in ready.values() if math.isfinite(v)]
    if not known:
        return ""
    return (f"; workers ready after {max(known):.2f} s (start, kernels, the plan's vehicles built; "
            f"in no run's time)")


def main(args) -> int:
    from rtsim.errors import RtsimError

    from .progress import eta_seconds, eta_text

    plan, base = load_plan(args.plan)
    if args.workers is not None and args.workers < 1:
        raise RtsimError(f"--workers must be >= 1, got {args.workers}")
    if args.ray:
        from .executors import require_ray
        require_ray()
    specs = expand(plan, base)
    params = list(dict.fromkeys([*plan.grid, *(plan.random.params if plan.random else {})]))
    out = Path(args.out or f"batch_{plan.name}")
    out.mkdir(parents=True, exist_ok=True)
    cols = columns(plan, params)
    journal = Journal(out / "journal.jsonl", cols)
    job = {"metrics": list(plan.metrics), "param_keys": params, "per_run": plan.per_run, "out_dir": str(out.resolve()),
           "criteria": [(c.metric, c.min, c.max) for c in plan.criteria]}
    rep = same_runs(specs)
    note = seed_note(plan, specs, rep)
    if note:
        print(note, file=sys.stderr)
    missing = [s for s in specs if s["run_id"] not in journal.rows]
    waiting: dict[str, list[dict]] = {}          # simulated run id -> the runs to copy from its row
    for s in missing:
        r = rep[s["run_id"]]
        if r == s["run_id"]:
            continue
        if r in journal.rows:                    # the simulated run is back already: copied now
            journal.append(copy_row(journal.rows[r], s, job))
        else:
            waiting.setdefault(r, []).append(s)
    todo = [s for s in missing if rep[s["run_id"]] == s["run_id"]]
    if args.limit is not None:
        todo = todo[:max(0, args.limit)]
    done0 = len(specs) - len(missing)
    workers = min(args.workers or os.cpu_count() or 1, max(1, len(todo)))
    where = f"Ray {args.ray}" if args.ray else f"{workers} local workers"
    print(f"{plan.name}: {len(specs)} runs, {done0} already in {journal.path}, {len(todo)} to run ({where})",
          file=sys.stderr)
    t0 = time.perf_counter()
    n = [0]
    times: list[tuple[str, float]] = []
    ran: list[dict] = []
    ready: dict[str, float] = {}

    def on_row(row: dict) -> None:
        journal.append(row)
        ran.append(row)
        if row["worker"] and row["worker"] not in ready:
            ready[row["worker"]] = ready_after(row, time.perf_counter() - t0)
        for s in waiting.pop(row["run_id"], ()):
            journal.append(copy_row(row, s, job))
        n[0] += 1
        times.append((row["worker"], row["wall_s"]))
        el = time.perf_counter() - t0
        width = len({w for w, _ in times if w}) if args.ray else workers
        eta = eta_seconds(times, len(todo) - n[0], width, skip_first=bool(args.ray))
        print(f"[{n[0]}/{len(todo)}] {row['run_id']} {row['scenario']} {row['status']} {row['verdict']}"
              f"  elapsed {el:.0f} s, {eta_text(eta)}", file=sys.stderr, flush=True)
    try:
        if todo:
            if args.ray:
                from .executors import ray_cluster
                ray_cluster(todo, job, on_row, address=args.ray, retries=args.retries)
            else:
                from .executors import local_pool
                local_pool(todo, job, on_row, workers=args.workers)
    finally:
        journal.close()
    wall = time.perf_counter() - t0
    rows = sorted_rows(journal.rows, [s["run_id"] for s in specs])
    pq, csv_path = write_tables(rows, cols, out)
    if not args.no_report:
        from .report import write_report
        write_report(rows, plan, params, out / "report.html")
    count = {v: sum(r["verdict"] == v for r in rows) for v in ("pass", "fail", "error")}
    rate = f", {n[0] / wall:.2f} runs/s" if n[0] and wall > 0 else ""
    print(f"{plan.name}: {len(rows)}/{len(specs)} runs in the table ({n[0]} run now in {wall:.1f} s{rate}): "
          f"{count['pass']} pass, {count['fail']} fail, {count['error']} error{timing_summary(ran)}{ready_summary(ready)}"
          f" -> {csv_path}, {pq}"
          + ("" if args.no_report else f", {out / 'report.html'}"))
    return 0 if count["pass"] == len(specs) else 1
