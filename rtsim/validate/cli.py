"""`rtsim validate --vehicle FILE --runs PATH... --report DIR`: repetitions of one manoeuvre (CSV or
MCAP) against the vehicle model; names the missing effect, writes the model with it and the report.
Standalone: `python -m rtsim.validate.cli ...`. Heavy imports happen in main (the parser stays cheap).

The command is an application (the apps layer): it wires the workflow to what sits above it, the
bridge's MCAP reader for recorded runs and the batch's Ray executor for `--ray`."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", required=True, type=Path, metavar="FILE", help="vehicle TOML of the model to validate")
    p.add_argument("--runs", required=True, nargs="+", type=Path, metavar="FILE",
                   help="repetitions of one manoeuvre: CSV files (column time [s] + sensor channels, SI) or "
                        "MCAP recordings of the service, or folders holding them")
    p.add_argument("--report", required=True, type=Path, metavar="DIR",
                   help="output folder: report.html, summary.json, plots, "
                                                               "the new vehicle config")
    p.add_argument("--road", type=Path, metavar="FILE",
                   help="road TOML the runs were driven on (default configs/roads/flat.toml)")
    p.add_argument("--rate", type=float, default=100.0, metavar="HZ", help="comparison grid rate, Hz (default 100)")
    p.add_argument("--align", default="xcorr", metavar="METHOD",
                   help="'xcorr' (cross-correlation of the inputs, default) or 'event:<channel>[:<fraction>]'")
    p.add_argument("--compare", nargs="+", metavar="CHANNEL",
                   help="output channels to compare (default: wheel_speed_fl..rr, "
                                                "accel_x; + accel_y, gyro_z, roll when steering)")
    p.add_argument("--accel-frame", choices=("body", "level"),
                   help="frame of the runs' accel_x/y/z: 'body' (the IMU's axes, senses gravity when the body rolls "
                        "or pitches) or 'level' (yaw-aligned horizontal frame, as INS loggers output); default: as "
                        "the runs declare it (CSV comment '# accel_frame: level' or MCAP metadata), else body")
    p.add_argument("--min-runs", type=int, default=3, metavar="N",
                   help="stop unless N runs pass the data checks (default 3: a band from fewer runs is too wide to "
                        "judge by; lower it knowingly, the report then says so at its top)")
    p.add_argument("--max-iterations", type=int, default=4, metavar="N", help="effects added at most (default 4)")
    p.add_argument("--workers", type=int, default=2, metavar="N",
                   help="processes fitting candidates in parallel (default 2)")
    p.add_argument("--ray", metavar="auto|ADDRESS", help="re-simulate on Ray: 'auto' starts a local instance on "
                                                        "127.0.0.1, else a cluster's address (same results)")
    p.add_argument("--no-progress", action="store_true", help="no progress display")


class RichProgress:
    """Stage-by-stage progress on stderr (rich), shown from the first stage on: an error before it (a bad
    vehicle file, a missing run) is the only output."""

    def __init__(self):
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
        self.p = Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                          TimeElapsedColumn(), console=Console(stderr=True), transient=False)
        self.task = None
        self.started = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stage("", None)
        if self.started:
            self.p.stop()

    def stage(self, text: str, total: int | None = None) -> None:
        if self.task is not None:
            self.p.update(self.task, completed=self.p.tasks[-1].total)
        if text and not self.started:
            self.p.start()
            self.started = True
        self.task = self.p.add_task(text, total=total or 1) if text else None

    def advance(self, n: int = 1) -> None:
        if self.task is not None:
            self.p.advance(self.task, n)


def main(args: argparse.Namespace) -> int:
    from contextlib import nullcontext

    from bridge.mcap_recorder import read_recording

    from . import report
    from .configwrite import write_config
    from .data import DataError
    from .tasks import RayWorkers
    from .workflow import Options, run

    ray = None
    if args.ray:
        from rtsim.batch.executors import ray_init, ray_map
        ray = RayWorkers(args.ray, ray_init, ray_map)
    opts = Options(vehicle=args.vehicle, runs=list(args.runs), report=args.report, road=args.road, rate=args.rate,
                   align=args.align, max_iterations=args.max_iterations, workers=args.workers, ray=ray,
                   compare=args.compare, accel_frame=args.accel_frame, min_runs=args.min_runs,
                   read_mcap=read_recording)
    prog = nullcontext(None) if args.no_progress else RichProgress()
    with prog as pr:
        opts.progress = pr
        try:
            res = run(opts)
        except DataError as exc:
            if getattr(exc, "runs", None) is not None:      # too few runs: the runs and reasons, kept
                report.write_stopped(exc.runs, str(exc), args.report)
            raise
        if pr:
            pr.stage("writing the report", None)
        if res.effects:
            out = args.report / f"{args.vehicle.stem}_validated.toml"
            res.config_path = out
            res.diff = write_config(args.vehicle, [*res.effects], out,
                                    f"effects identified by `rtsim validate` from {res.bench.n} run(s); "
                                    "value +- 95 % half-width")
        summ = report.write(res, args.report)
    verdict = summ["verdict"]
    if verdict["notice"]:
        print(verdict["notice"])
    first, *rest = verdict["text"].splitlines()
    print(f"verdict: {first}")
    for line in rest:
        print(f"  {line}")
    print(f"accelerometer frame: {res.accel_frame}")
    for c, m in summ["after"].items():
        b = summ["before"][c]
        ins = lambda x: "no band" if x is None else f"{100 * x:.0f} % inside"   # noqa: E731
        print(f"  {c:<16} RMS {b['rms']:.4g} -> {m['rms']:.4g}, {ins(b['inside_band'])} -> {ins(m['inside_band'])}")
    if res.diff:
        print(res.diff)
    print(f"report: {args.report / 'report.html'} ({res.timings['total']:.1f} s, "
          f"{res.timings['simulations']} simulations)")
    return 0


def _standalone(argv: list[str] | None = None) -> int:
    from rtsim.errors import RtsimError
    p = argparse.ArgumentParser(prog="rtsim validate", description=__doc__.splitlines()[0])
    add_arguments(p)
    args = p.parse_args(argv)
    try:
        return main(args)
    except RtsimError as exc:
        print(f"rtsim validate: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(_standalone())
