"""The `rtsim` command: one entry point, one subcommand per job.

    rtsim serve    the HIL service (CAN, Zenoh, MCAP)      rtsim demo     service + demo ECU, recorded
    rtsim watch    live dashboard over Zenoh               rtsim play     recorded frames back on the bus
    rtsim view     the driving simulator in the browser (the live car, keyboard and gamepad)
    rtsim resim    re-run a recording, compare the state   rtsim run      a scenario offline to CSV/MCAP
    rtsim bench    benchmarks                              rtsim describe the vehicle model
    rtsim validate field runs vs the model: find, fit and add the missing effect, report
    rtsim plot     figures of a run (CSV or MCAP) as PNG
    rtsim energy   the power audit of a run                rtsim feel     steering feel of a run (EPS car)
    rtsim eigen    a two-wheeler's modes against speed     rtsim statics  a two-wheeler at rest, rider on
    rtsim inverse  a motorcycle's steering and drive torques for a path and speed
    rtsim batch    a plan of runs (scenarios x vehicles x parameters x seeds), local pool or Ray
    rtsim faults   the fault catalogue (--list) and fault-file checks
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from rtsim.errors import RtsimError

_T_IMPORT = time.perf_counter()


def _fmt(v, spec):
    return format("-" if v is None else v, spec if v is not None else ">" + spec.lstrip("<>^").split(".")[0].rstrip("ef"))


def _cpu_list(text: str) -> set[int]:
    """A CPU list as given on the command line ("1" or "1,3")."""
    try:
        cpus = {int(x) for x in text.split(",") if x.strip()}
    except ValueError:
        raise RtsimError(f"--pages-cpus {text!r}: not a comma-separated list of CPU numbers") from None
    if not cpus or min(cpus) < 0:
        raise RtsimError(f"--pages-cpus {text!r}: not a list of CPU numbers")
    return cpus


def _bench(args) -> int:
    from rtsim.benchmarks import PROBLEMS
    from rtsim.benchmarks.runner import run_problem, scaling, startup_seconds

    if args.suite == "service":
        from rtsim.benchmarks.service import format_report, run_service_bench
        if not (args.duration > 0 and math.isfinite(args.duration)):
            raise RtsimError(f"--duration must be a positive number of seconds, got {args.duration}")
        if not 0 <= args.pages <= 16:
            raise RtsimError(f"--pages must be 0..16, got {args.pages}")
        if not 0 <= args.ws_clients <= 16:
            raise RtsimError(f"--ws-clients must be 0..16, got {args.ws_clients}")
        if not 0 <= args.pages_nice <= 19:
            raise RtsimError(f"--pages-nice must be 0..19, got {args.pages_nice}")
        res = run_service_bench(args.duration, record=not args.no_record, zenoh=not args.no_zenoh, ecu=args.ecu,
                                spin=args.spin, foxglove=args.foxglove, pages=args.pages,
                                pages_nice=args.pages_nice, ws_clients=args.ws_clients, loop_cpu=args.loop_cpu,
                                loop_priority=args.loop_priority, faults=args.faults or (),
                                pages_cpus=_cpu_list(args.pages_cpus) if args.pages_cpus else None)
        print(json.dumps(res, indent=2) if args.json else format_report(res))
        return 0
    if args.suite == "dispatch":
        from rtsim.benchmarks.dispatch import dispatch_costs, format_report
        res = dispatch_costs()
        print(json.dumps(res, indent=2) if args.json else format_report(res))
        return 0
    if args.suite == "fmu":
        from rtsim.benchmarks.fmu import fmu_costs, format_report
        res = fmu_costs()
        print(json.dumps(res, indent=2) if args.json else format_report(res))
        return 0
    if args.suite == "fuzz":
        from pathlib import Path

        from rtsim.robustness.bench import run_fuzz_bench
        if args.count < 1:
            raise RtsimError(f"--count must be at least 1, got {args.count}")
        vehicles = [Path(v) for v in args.vehicle] if args.vehicle else None
        for v in vehicles or ():
            if not v.is_file():
                raise RtsimError(f"--vehicle {v}: no such file")
        res = run_fuzz_bench(vehicles, args.count, args.seed, Path(args.failures) if args.failures else None,
                             out=(lambda line: None) if args.json else (lambda line: print(line, flush=True)))
        if args.json:
            print(json.dumps(res, indent=2))
        return 1 if any(r["failures"] for r in res) else 0
    if args.suite == "vehicle" and args.stages:
        from rtsim.benchmarks.stages import format_stages, stages_suite
        res = stages_suite()
        print(json.dumps(res, indent=2) if args.json else format_stages(res))
        return 0
    if args.suite == "vehicle":
        from rtsim.benchmarks.vehicle import suite
        results = suite()
        if args.json:
            print(json.dumps(results, indent=2))
            return 0
        for r in results:
            print(f"{r['scenario']:<36} {r['us_per_step']:7.1f} us/step  "
                  f"({r['newton_iterations_per_step']:.2f} Newton iterations, "
                  f"{r['factorizations_per_step']:.1f} factorizations per step)")
            for part, us in r["parts_us_per_step"].items():
                print(f"    {part:<70} {us:6.1f} us  {100 * r['share'][part]:5.1f} %")
        return 0
    if args.problem and args.problem not in PROBLEMS:
        raise RtsimError(f"unknown problem {args.problem!r}; choose from {', '.join(PROBLEMS)}")
    for flag, value in (("--dt", args.dt), ("--t-end", args.t_end)):
        if value is not None and not (value > 0 and math.isfinite(value)):
            raise RtsimError(f"{flag} must be a positive number of seconds, got {value}")
    ready = startup_seconds()
    names = [args.problem] if args.problem else list(PROBLEMS)
    results = [run_problem(n, args.dt, args.t_end) for n in names]
    scale = scaling() if args.scaling else None
    if args.json:
        print(json.dumps(results if scale is None else {"problems": results, "scaling": scale}, indent=2))
        return 0
    head = f"{'problem':<10} {'dt [s]':>8} {'t_end':>6} {'steps':>7} {'wall [s]':>8} {'us/step':>8} " \
           f"{'max|Phi|':>9} {'max|dPhi|':>9} {'energy drift':>12}  final"
    print(head)
    print("-" * len(head))
    for r in results:
        final = ", ".join(f"{k}={v:.6f}" for k, v in r["final"].items())
        print(f"{r['problem']:<10} {r['dt']:>8.0e} {r['t_end']:>6.3g} {r['steps']:>7d} {r['wall_s']:>8.3f} "
              f"{r['us_per_step']:>8.2f} {r['max_position_constraint_violation']:>9.1e} "
              f"{r['max_velocity_constraint_violation']:>9.1e} {_fmt(r['energy_drift'], '>12.2e')}  {final}")
    if scale:
        print("\nN-four-bar cost per step (dt = 1 ms):")
        for s in scale:
            print(f"  N = {s['N']:>3}: {s['n_coordinates']:>4} coordinates, {s['us_per_step']:8.2f} us/step")
    print(f"\nkernels ready in {ready:.2f} s (compiled on a cold cache, loaded on a warm one); "
          f"process start to results {time.perf_counter() - _T_IMPORT:.2f} s")
    return 0


def _run(args) -> int:
    """A scenario offline on its vehicle (rtsim.vehicle.registry): rows to CSV/MCAP, the summary (what the
    manoeuvre measured, when the vehicle reports one) to the console and --summary; exit status
    MODEL_FAULT_EXIT when the model failed or the vehicle fell."""
    from pathlib import Path

    from drivers.scenario import load_scenario
    from rtsim.compile_status import configs_first
    from rtsim.vehicle.registry import open_vehicle, resolve_scenario

    out = args.out
    if Path(out).suffix.lower() not in (".csv", ".mcap"):
        raise RtsimError(f"{out}: output must end in .csv or .mcap")
    with configs_first():       # both files validated before a compile notice (the scenario's check compiles)
        sc = load_scenario(resolve_scenario(args.scenario), check_files=True)
        # refused before the vehicle is built: on a first start that build compiles for minutes
        if sc.spec.faults and not args.no_faults:
            raise RtsimError(f"{sc.name}: the scenario arms {len(sc.spec.faults)} fault(s) "
                             f"({', '.join(f.id for f in sc.spec.faults)}); "
                             "an offline run does not inject faults: serve it (rtsim serve --scenario), run it as "
                             "an ECU test case (rtsim test), or pass --no-faults to run it without them")
        vehicle = open_vehicle(args.vehicle if args.vehicle is not None else sc.vehicle_path)
        vehicle.refuse("run")
        vehicle.check_scenario(sc)
    shown = [-1]

    def progress(frac):
        pct = int(frac * 100)
        if pct // 5 != shown[0] // 5 and sys.stderr.isatty():
            print(f"\r{sc.name}: {pct:3d} %", end="", file=sys.stderr, flush=True)
            shown[0] = pct
    res = vehicle.run_offline(sc, progress)
    from bridge.mcap_log import write_offline
    write_offline(res, out)
    if res.summary:
        text = json.dumps(res.summary, indent=2)
        if args.summary:
            Path(args.summary).write_text(text + "\n")
        print(text)
    print(f"{'' if not sys.stderr.isatty() else chr(13)}{res.line} -> {out}; status {res.status}"
          f"{': ' + res.message if res.message else ''}")
    if args.plot is not None:
        _write_figures(res.columns, res.data, args.plot or None, out, sc.name)
    if res.fault is not None:
        return _model_fault_exit(res.fault, len(res.data), out)
    return 0 if res.status == "ok" else MODEL_FAULT_EXIT


def _export_fmu(args) -> int:
    """`rtsim export-fmu`: the vehicle as an FMU (rtsim.fmu.export)."""
    from rtsim.fmu.export import export_vehicle

    out = export_vehicle(args.vehicle, args.out, args.scenario)
    print(f"{out}: FMI 3.0 co-simulation FMU of {args.vehicle}")
    return 0


MODEL_FAULT_EXIT = 3      # `rtsim run`: the model failed (a two-wheeler: or fell); the rows up to it are written


def _model_fault_exit(fault, rows: int, out) -> int:
    """An offline run that a model failure ended: the failure beside the output (``<out>.model_fault.json``:
    step, time, reason, coordinate), one line on stderr, exit status MODEL_FAULT_EXIT."""
    from pathlib import Path

    side = Path(out).with_suffix(".model_fault.json")
    side.write_text(json.dumps(fault.as_dict(), indent=2) + "\n")
    if sys.stderr.isatty():
        print("\r", end="", file=sys.stderr)
    print(f"rtsim run: {fault.line()}; {rows} rows up to it -> {out} (the failure: {side})", file=sys.stderr)
    return MODEL_FAULT_EXIT


def _energy(args) -> int:
    from bridge.run_files import read_energy
    from rtsim.vehicle.car.energy import summarise

    try:
        t, series = read_energy(args.run)
    except (OSError, ValueError) as exc:
        raise RtsimError(str(exc)) from None
    print(summarise(t, series))
    return 0


def _feel(args) -> int:
    from pathlib import Path

    from rtsim.analyses.feel import steering_feel, table
    from bridge.run_files import read_recorded

    for flag, value in (("--at", args.at), ("--half-width", args.half_width)):
        if not (value > 0 and math.isfinite(value)):
            raise RtsimError(f"{flag} must be a positive number of g, got {value}")
    columns, data = read_recorded(args.run)
    feel = steering_feel(columns, data, start=args.start, end=args.end, at=args.at,
                         half_width=args.half_width, source=args.run)
    if args.json:
        print(json.dumps(feel.as_dict(), indent=2))
    else:
        from rich.console import Console
        Console().print(table(feel, Path(args.run).name))
    if args.plot is not None:
        from rtsim.analyses.feel_figures import write_feel_figures
        from rtsim.analyses.figures import default_dir
        for path in write_feel_figures(columns, data, feel, args.plot or default_dir(args.run), Path(args.run).stem):
            print(f"figure -> {path}")
    return 0


def _plot(args) -> int:
    from pathlib import Path

    from bridge.run_files import read_recorded

    columns, data = read_recorded(args.run)
    _write_figures(columns, data, args.out, args.run, Path(args.run).stem)
    return 0


def _write_figures(columns, data, out_dir, source, title) -> None:
    """Figures of a run into `out_dir` (None: beside `source`, <stem>_plots/); prints the files written."""
    from rtsim.analyses.figures import default_dir, write_run_figures

    written = write_run_figures(columns, data, out_dir or default_dir(source), title)
    if not written:
        print(f"{source}: none of the plotted channels present, no figures written")
    for path in written:
        print(f"figure -> {path}")


def _describe(args) -> int:
    """The vehicle's size and key parameters (every vehicle: rtsim.vehicle.registry.DESCRIBE_FIELDS)."""
    from rtsim.vehicle.registry import open_vehicle

    vehicle = open_vehicle(args.vehicle)
    vehicle.refuse("describe")
    info = vehicle.describe()
    if args.json:
        print(json.dumps(info, indent=2))
    else:
        for k, v in info.items():
            print(f"{k:32s} {v}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from rtsim import __version__

    p = argparse.ArgumentParser(prog="rtsim", description="Real-time HIL vehicle simulator")
    p.add_argument("--version", action="version", version=f"rtsim {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bench", help="run the multibody benchmark problems (IFToMM A01-A05) and time them")
    b.add_argument("--problem", metavar="NAME",
                   help="run one problem: pendulum, fourbar, fourbar2, fourbar40, andrews, bricard, flyball")
    b.add_argument("--dt", type=float, metavar="S", help="time step, s (default: the problem's real-time step)")
    b.add_argument("--t-end", type=float, metavar="S", help="end time, s (default: the problem's)")
    b.add_argument("--json", action="store_true", help="print a JSON list, one object per problem")
    b.add_argument("--scaling", action="store_true", help="also time the N-four-bar for N = 1, 2, 10, 40, 100")
    b.add_argument("--suite", choices=["mbs", "vehicle", "service", "dispatch", "fuzz", "fmu"], default="mbs",
                   help="mbs: the IFToMM benchmark problems (default); vehicle: the vehicle model's cost per "
                        "step; service: the HIL service's real-time budget under load (CAN, Zenoh, MCAP, ECU); "
                        "dispatch: the cost of a call into a kernel, direct and bound (rtsim.boundcall); "
                        "fuzz: command sequences drawn in each vehicle's DBC ranges (rtsim.robustness); "
                        "fmu: the cost of one controller FMU call and of the car as an FMU (docs/fmu.md)")
    b.add_argument("--stages", action="store_true",
                   help="vehicle suite: each vehicle's step stage by stage instead (formulation and force stages, "
                        "Newton iterations and factorizations per step; docs/benchmarks.md)")
    b.add_argument("--count", type=int, default=2000, metavar="N",
                   help="fuzz suite: rides drawn per vehicle (2000)")
    b.add_argument("--vehicle", action="append", metavar="FILE",
                   help="fuzz suite: a vehicle TOML to fuzz (repeatable; default: every shipped vehicle)")
    b.add_argument("--seed", type=int, default=0, metavar="N", help="fuzz suite: the draw's seed (0)")
    b.add_argument("--failures", metavar="FILE",
                   help="fuzz suite: append each failing ride, as drawn, as a JSON line to FILE")
    b.add_argument("--duration", type=float, default=60.0, metavar="S", help="service suite: wall seconds to run (60)")
    b.add_argument("--faults", action="append", metavar="FILE",
                   help="service suite: arm the [[faults]] of this file in the service (repeatable)")
    b.add_argument("--no-record", action="store_true", help="service suite: without the MCAP recording")
    b.add_argument("--no-zenoh", action="store_true", help="service suite: without Zenoh")
    b.add_argument("--foxglove", action="store_true",
                   help="service suite: with the Foxglove server and a client subscribed to every topic")
    b.add_argument("--spin", type=float, default=0.0002, metavar="S",
                   help="service suite: busy-wait before each step, s (>= 0.001: never sleep)")
    b.add_argument("--pages", type=int, default=0, metavar="N",
                   help="service suite: also N pages of `rtsim view` in headless Chromium, drawing the live car")
    b.add_argument("--pages-nice", type=int, default=19, metavar="N",
                   help="service suite: CPU priority (nice) of the pages' browser and view server (19: lowest; 0: "
                        "the loop's)")
    b.add_argument("--ws-clients", type=int, default=0, metavar="N",
                   help="service suite: also N WebSocket clients of `rtsim view` pulling the samples as a page "
                        "does, without drawing (the view server's own cost)")
    b.add_argument("--loop-cpu", type=int, metavar="CPU",
                   help="service suite: pin the loop thread alone to this CPU, everything else of the bench off it")
    b.add_argument("--loop-priority", type=int, metavar="P",
                   help="service suite: the loop thread under SCHED_FIFO at priority P (1-99; needs the privilege)")
    b.add_argument("--pages-cpus", metavar="LIST",
                   help="service suite: CPUs of the pages' browser, the view server and the WebSocket clients "
                        "(e.g. 1 or 1,2)")
    b.add_argument("--ecu", choices=["light", "demo"], default="light",
                   help="service suite: command-only ECU (default) or the demo ECU decoding every frame")
    b.set_defaults(func=_bench)
    r = sub.add_parser("run", help="run a scenario offline as fast as possible and write CSV (a motorcycle's "
                       "scenario: also its summary); exit status 3 if the model failed (the rows up to the failure written, "
                       "the failure beside them in <out>.model_fault.json) or the motorcycle fell")
    r.add_argument("--vehicle", metavar="FILE|NAME",
                   help="vehicle TOML or name in configs/vehicles (default: the scenario's, else xbw)")
    r.add_argument("--scenario", required=True, metavar="FILE|NAME", help="scenario TOML or name in configs/scenarios")
    r.add_argument("--out", required=True, metavar="FILE", help="output file: .csv or .mcap")
    r.add_argument("--no-faults", action="store_true",
                   help="run a scenario that arms [[faults]] without them (an offline run injects none)")
    r.add_argument("--summary", metavar="JSON", help="two-wheeler scenarios: also write the summary (measured "
                   "against the manoeuvre's analytic references) to this JSON file")
    r.add_argument("--plot", nargs="?", const="", metavar="DIR",
                   help="also write PNG figures (lateral acceleration, tyre loads, steering) into DIR "
                        "(default: <output stem>_plots/ beside the output)")
    r.set_defaults(func=_run)
    ef = sub.add_parser("export-fmu", help="write an FMI 3.0 co-simulation FMU of a vehicle: its commands as "
                        "inputs, its channels as outputs (docs/fmu.md)")
    ef.add_argument("--vehicle", required=True, metavar="FILE|NAME", help="vehicle TOML or name in configs/vehicles")
    ef.add_argument("--scenario", metavar="FILE|NAME", help="where the FMU starts: the scenario's road, initial "
                    "state and step (its inputs are not used; default: the vehicle's default scenario)")
    ef.add_argument("--out", required=True, metavar="FILE.fmu", help="the FMU to write")
    ef.set_defaults(func=_export_fmu)
    en = sub.add_parser("energy", help="the power audit of a recorded run: every port's energy and the balance")
    en.add_argument("run", metavar="RUN.mcap|.csv", help="a run's MCAP or CSV (rtsim run --out)")
    en.set_defaults(func=_energy)
    fe = sub.add_parser("feel", help="steering feel of a recorded run: torque against lateral acceleration "
                        "(gradients, hysteresis), angle gradient, the EPS motor's current, voltage and power")
    fe.add_argument("run", metavar="RUN.mcap|.csv",
                    help="a run's MCAP or CSV (rtsim run --out) of a car with electric power steering")
    fe.add_argument("--from", dest="start", type=float, metavar="S",
                    help="start of the analysed window, s (default: the steady cycles of the steering input)")
    fe.add_argument("--to", dest="end", type=float, metavar="S", help="end of the analysed window, s")
    fe.add_argument("--at", type=float, default=0.1, metavar="G",
                    help="lateral acceleration of the second gradient, g (0.1)")
    fe.add_argument("--half-width", type=float, default=0.02, metavar="G",
                    help="half-width of the local fits' window, g (0.02)")
    fe.add_argument("--json", action="store_true", help="print the report as JSON")
    fe.add_argument("--plot", nargs="?", const="", metavar="DIR",
                    help="also write PNG figures (torque against lateral acceleration; motor current, voltage "
                         "and power) into DIR (default: <run stem>_plots/ beside the run)")
    fe.set_defaults(func=_feel)
    pl = sub.add_parser("plot", help="write PNG figures of a recorded run (CSV or MCAP)")
    pl.add_argument("run", metavar="RUN.mcap|.csv", help="the run: .csv (header row) or .mcap recording")
    pl.add_argument("--out", metavar="DIR", help="folder for the figures (default: <run stem>_plots/ beside it)")
    pl.set_defaults(func=_plot)
    d = sub.add_parser("describe", help="print the vehicle model's size and key parameters")
    d.add_argument("--vehicle", metavar="FILE|NAME", help="vehicle TOML or name in configs/vehicles (default xbw)")
    d.add_argument("--json", action="store_true")
    d.set_defaults(func=_describe)
    for name, module, text in _DELEGATED:
        sp = sub.add_parser(name, help=text)
        sp.set_defaults(func=_delegate(module))
        _import(module).add_arguments(sp)
    st = sub.add_parser("statics", help="a two-wheeler at rest with the rider on: wheel loads, sag, attitude (JSON)")
    st.set_defaults(func=lambda args: _import("rtsim.analyses.eigen_cli").statics_main(args))
    _import("rtsim.analyses.eigen_cli").add_statics_arguments(st)
    return p


#: subcommands whose arguments and main live in their own module: (name, module, help)
_DELEGATED = (
    ("serve", "rtsim.service.cli", "run the HIL service: the vehicle behind CAN, Zenoh state, MCAP recording"),
    ("demo", "rtsim.service.demo", "the service plus a demo ECU process driving over CAN, recorded"),
    ("watch", "rtsim.watch", "live terminal dashboard of a running service (Zenoh)"),
    ("view", "rtsim.viewer.cli", "the driving simulator in the browser: a local web page of the live car, "
     "driven by keyboard or gamepad"),
    ("play", "bridge.player", "put recorded CAN frames back on the bus with their original timing"),
    ("resim", "rtsim.service.resim", "re-run a recording (or a CAN log of commands) and compare the state"),
    ("validate", "rtsim.validate.cli", "compare the model with repeated field runs, name and add the missing effect"),
    ("eigen", "rtsim.analyses.eigen_cli", "a two-wheeler's modes against speed in straight running (root locus, JSON)"),
    ("batch", "rtsim.batch.cli", "run a plan of scenarios x vehicles x parameters (grid or random) x seeds on a "
     "local pool or Ray: results table, metrics, pass/fail, HTML summary; resumable"),
    ("faults", "rtsim.faults.cli", "the fault catalogue (--list): sensor, bus and actuator faults a session can "
     "inject; or check fault files"),
    ("test", "rtsim.ecutest.cli", "run an ECU test catalogue: cases of scenario, faults and expectations against an "
     "ECU on the bus; JUnit XML, results table, HTML report; resumable"),
    ("inverse", "rtsim.analyses.inverse", "a motorcycle's inverse dynamics: the steering and drive "
     "torques that follow a path at a speed"),
)


def _import(module: str):
    import importlib

    return importlib.import_module(module)


def _delegate(module: str):
    return lambda args: _import(module).main(args)


def _report_faults() -> None:
    """A crash (a segmentation fault in compiled code, an abort) prints every thread's Python stack on
    stderr before the process dies, and SIGUSR1 prints them without stopping it: ``kill -USR1 <pid>``
    shows where a service that does not answer or does not exit is waiting."""
    import faulthandler
    import signal

    try:
        if not faulthandler.is_enabled():               # (pytest, for one, enables its own)
            faulthandler.enable(all_threads=True)
        if hasattr(signal, "SIGUSR1"):
            faulthandler.register(signal.SIGUSR1, all_threads=True, chain=False)
    except (RuntimeError, ValueError, AttributeError, OSError):   # no usable stderr (closed, or None)
        pass


def main(argv: list[str] | None = None) -> int:
    from rtsim.compile_status import COMPILING_COMMANDS, command_progress

    args = build_parser().parse_args(argv)
    _report_faults()
    try:
        if args.command in COMPILING_COMMANDS:
            with command_progress(args.command):
                return args.func(args)
        return args.func(args)
    except RtsimError as exc:
        print(f"rtsim: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:          # output piped into head & co.
        return 0


if __name__ == "__main__":
    sys.exit(main())
