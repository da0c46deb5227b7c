"""`rtsim batch PLAN.toml`: expand the plan, skip the runs the output folder's journal already holds,
run the rest on the local pool (default) or Ray (--ray auto|ADDRESS), journal each row as it arrives
with progress and an ETA on stderr, then write results.parquet, results.csv (sorted by run id) and
report.html. Exit status 0 when every run passes, 1 when any fails or errors."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from .expand import expand
from .plan import load_plan
from .results import Journal, sorted_rows, write_tables


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
            "simulated_s", *plan.metrics, "wall_s", "worker"]


def main(args) -> int:
    from rtsim.errors import RtsimError

    plan, base = load_plan(args.plan)
    if args.workers is not None and args.workers < 1:
        raise RtsimError(f"--workers must be >= 1, got {args.workers}")
    specs = expand(plan, base)
    params = list(dict.fromkeys([*plan.grid, *(plan.random.params if plan.random else {})]))
    out = Path(args.out or f"batch_{plan.name}")
    out.mkdir(parents=True, exist_ok=True)
    cols = columns(plan, params)
    journal = Journal(out / "journal.csv", cols)
    todo = [s for s in specs if s["run_id"] not in journal.rows]
    if args.limit is not None:
        todo = todo[:max(0, args.limit)]
    job = {"metrics": list(plan.metrics), "param_keys": params, "per_run": plan.per_run, "out_dir": str(out.resolve()),
           "criteria": [(c.metric, c.min, c.max) for c in plan.criteria]}
    done0 = len(specs) - len([s for s in specs if s["run_id"] not in journal.rows])
    where = f"Ray {args.ray}" if args.ray else f"{args.workers or os.cpu_count()} local workers"
    print(f"{plan.name}: {len(specs)} runs, {done0} already in {journal.path}, {len(todo)} to run ({where})",
          file=sys.stderr)
    t0 = time.perf_counter()
    n = [0]

    def on_row(row: dict) -> None:
        journal.append(row)
        n[0] += 1
        el = time.perf_counter() - t0
        eta = el / n[0] * (len(todo) - n[0])
        print(f"[{n[0]}/{len(todo)}] {row['run_id']} {row['scenario']} {row['status']} {row['verdict']}"
              f"  elapsed {el:.0f} s, ETA {eta:.0f} s", file=sys.stderr, flush=True)
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
          f"{count['pass']} pass, {count['fail']} fail, {count['error']} error -> {csv_path}, {pq}"
          + ("" if args.no_report else f", {out / 'report.html'}"))
    return 0 if count["pass"] == len(specs) else 1
