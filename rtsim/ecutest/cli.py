"""`rtsim test CATALOG.toml`: run an ECU test catalogue (rtsim.ecutest.catalog) and write its reports.

Cases run on ``--workers`` processes (default 1), each with its own loopback CAN hub and its own service, one
case at a time; a case's row is journalled as it arrives (rtsim.batch.results.Journal: flushed and synced),
so an interrupted run resumes in the same ``--out`` folder with the cases it has not finished (a case's run
id hashes the catalogue's settings, the case, every config file it reads and the ECU scripts it names: an
edit runs it again). Workers die with this process, however it ends (rtsim.batch.executors.die_with_parent).
Then: ``junit.xml`` (JUnit XML), the results table on stdout and ``report.html`` (each case's plots).
Exit status 0 when every case passes, 1 when one fails or errors, 2 for a bad catalogue."""
from __future__ import annotations

import multiprocessing as mp
import os
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from pathlib import Path

from rtsim.errors import ConfigError, RtsimError


def add_arguments(p) -> None:
    p.add_argument("catalogue", metavar="CATALOG.toml", help="the test catalogue (configs/tests/)")
    p.add_argument("--out", metavar="DIR", help="output folder (default: test_<catalogue name>/ here); a journal "
                   "there from an interrupted run of the same catalogue is resumed")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="cases run side by side, each worker with its own CAN hub and service (default 1)")
    p.add_argument("--mode", choices=["lockstep", "realtime"],
                   help="override the catalogue's mode (lockstep: deterministic, the ECU requests every step)")
    p.add_argument("-k", dest="select", metavar="TEXT", help="run only the cases whose name contains TEXT")
    p.add_argument("--junit", metavar="FILE", help="JUnit XML file (default: <out>/junit.xml)")
    p.add_argument("--no-html", action="store_true", help="skip the HTML report")


def _init(parent: int) -> None:
    from rtsim.batch.executors import die_with_parent
    die_with_parent(parent)


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """End the pool's workers (each takes its hub, service and ECU with it)."""
    for p in list(getattr(pool, "_processes", {}).values()):
        if p.is_alive():
            p.terminate()
    pool.shutdown(wait=True, cancel_futures=True)


def make_pool(workers: int) -> ProcessPoolExecutor:
    """The worker processes (spawned; each dies with this process); end them with ``stop_pool``."""
    return ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn"), initializer=_init,
                               initargs=(os.getpid(),))


def run_catalogue(path: str | Path, out: Path, workers: int = 1, mode: str | None = None, select: str | None = None,
                  say=print, pool: ProcessPoolExecutor | None = None) -> tuple[object, list[dict]]:
    """Run the catalogue's (selected) cases not in ``out``'s journal; (catalogue, rows in catalogue order).
    ``pool``: worker processes to use (make_pool; kept, their kernels loaded, for the next catalogue) instead
    of a pool of ``workers`` started and stopped here."""
    from rtsim.batch.results import Journal

    from .case import COLUMNS, case_id
    from .catalog import load_catalogue

    cat = load_catalogue(path)
    if mode is not None and mode != cat.spec.mode:
        if cat.external is not None and mode == "lockstep":
            raise ConfigError(f"{path}: --mode lockstep: an ECU already on the bus (ecu.channel) runs in realtime")
        if cat.spec.ecu is None and mode != "lockstep":
            raise ConfigError(f"{path}: --mode {mode}: a catalogue without [ecu] steps its controller FMU in lockstep")
        cat.spec = cat.spec.model_copy(update={"mode": mode})
    if workers < 1:
        raise ConfigError(f"--workers {workers}: at least 1")
    if cat.external is not None:
        workers = 1                                  # one bus, one service at a time
    picked = [i for i, c in enumerate(cat.spec.cases) if select is None or select in c.name]
    ids = {i: case_id(cat, i) for i in picked}
    out.mkdir(parents=True, exist_ok=True)
    journal = Journal(out / "journal.jsonl", COLUMNS)
    todo = [i for i in picked if ids[i] not in journal.rows]
    if len(todo) < len(picked):
        say(f"rtsim test: resuming: {len(picked) - len(todo)} of {len(picked)} cases done already in {out}")
    try:
        if todo:
            _run(path, out, todo, ids, min(workers, len(todo)), journal, say, pool)
    finally:
        journal.close()
    rows = [journal.rows[ids[i]] for i in picked if ids[i] in journal.rows]
    return cat, rows


def _run(path, out: Path, todo: list[int], ids: dict, workers: int, journal, say, given=None) -> None:
    from .case import run_case

    pool = given or make_pool(workers)
    try:
        pending = {pool.submit(run_case, str(Path(path).resolve()), i, str(out.resolve()), ids[i]): i for i in todo}
        while pending:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                i = pending.pop(f)
                try:
                    row = f.result()
                except Exception as exc:  # noqa: BLE001  (a worker lost: not journalled, so a resume runs it)
                    raise RtsimError(f"the worker running case {_name(path, i)!r} was lost ({type(exc).__name__}: "
                                     f"{' '.join(str(exc).split())}); the finished cases are kept: run the same "
                                     "command again to resume") from None
                journal.append(row)
                say(f"rtsim test: {row['name']}: {row['status']} ({float(row.get('wall_s') or 0):.1f} s wall)")
    finally:
        if given is None:
            stop_pool(pool)


def _name(path, i: int) -> str:
    from .catalog import load_catalogue
    return load_catalogue(path).spec.cases[i].name


def main(args) -> int:
    from .report import table, write_html, write_junit

    path = Path(args.catalogue)
    out = Path(args.out) if args.out else None
    if out is None:
        from .catalog import load_catalogue
        out = Path(f"test_{load_catalogue(path).spec.name}")
    cat, rows = run_catalogue(path, out, args.workers, args.mode, args.select,
                              say=lambda line: print(line, file=sys.stderr, flush=True))
    junit = write_junit(cat.spec.name, rows, Path(args.junit) if args.junit else out / "junit.xml")
    print(table(rows))
    print(f"rtsim test: JUnit XML {junit}")
    if not args.no_html:
        print(f"rtsim test: report {write_html(cat, rows, out, out / 'report.html')}")
    return 0 if rows and all(r["status"] == "passed" for r in rows) else 1
