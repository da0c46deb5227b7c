"""`rtsim serve` command line: flags map one to one onto ServeOptions."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .server import DEFAULT_ZENOH_LISTEN, ServeOptions, Service


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="service settings TOML (see configs/service.toml); flags override it")
    p.add_argument("--scenario", help="scenario TOML or name in configs/scenarios (road, start, step; "
                                      "default hil_flat)")
    p.add_argument("--vehicle", help="vehicle TOML (default: the scenario's, else configs/vehicles/xbw.toml)")
    p.add_argument("--dt", type=float, help="fixed step, s (default: the scenario's, 0.001)")
    p.add_argument("--mode", choices=["realtime", "lockstep", "fast"],
                   help="realtime (default): paced by the wall clock; lockstep: steps only on request (CAN "
                        "SIM_STEP_REQ or Zenoh control op=step); fast: as fast as possible")
    p.add_argument("--can-interface", help="python-can interface (socketcan, remote, virtual, pcan, ...); "
                                           "default: socketcan vcan0 if present, else the loopback hub")
    p.add_argument("--can-channel", help="python-can channel (vcan0, can0, 127.0.0.1:54701, ...)")
    p.add_argument("--no-hub", action="store_true", help="do not start the embedded loopback CAN hub")
    p.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT",
                   help=f"Zenoh listen endpoint (repeatable; default {DEFAULT_ZENOH_LISTEN})")
    p.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                   help="Zenoh endpoint to connect to (a router on a bench; repeatable)")
    p.add_argument("--zenoh-allow-remote", action="store_true",
                   help="allow Zenoh endpoints off 127.0.0.1 (a real bench network)")
    p.add_argument("--no-zenoh", action="store_true", help="do not publish over Zenoh")
    p.add_argument("--record", metavar="FILE.mcap", help="record the session to MCAP")
    p.add_argument("--vehicle-id", help="key segment of the Zenoh keys and MCAP topics (default: the vehicle's id)")
    p.add_argument("--state-rate", type=float, help="state publication rate, Hz (default 100)")
    p.add_argument("--status-rate", type=float, help="status publication rate, Hz (1-10, default 10)")
    p.add_argument("--hold-pressure", type=float, help="brake pressure applied when the brake command "
                                                       "times out, kPa (default 3000)")
    p.add_argument("--max-catch-up", type=int,
                   help="after a stall, steps run back to back before the rest are skipped (default 20)")
    p.add_argument("--spin", type=float, help="busy-wait before each step, s (default 0.0002; a value >= the "
                                              "step never sleeps: for a dedicated core)")
    p.add_argument("--duration", type=float, help="stop after this many seconds of wall time")
    p.add_argument("--json", action="store_true", help="print the closing summary as JSON")


def options(args) -> ServeOptions:
    """ServeOptions from the defaults, then the --config file, then the flags given."""
    kw: dict = {}
    if args.config:
        from .config import load_service_config
        kw.update(load_service_config(args.config))
    flags = {"scenario": args.scenario and Path(args.scenario), "vehicle": args.vehicle and Path(args.vehicle),
             "dt": args.dt, "mode": args.mode, "can_interface": args.can_interface,
             "can_channel": args.can_channel, "zenoh_listen": args.zenoh_listen,
             "zenoh_connect": args.zenoh_connect, "record": args.record and Path(args.record),
             "vehicle_id": args.vehicle_id, "state_rate": args.state_rate, "status_rate": args.status_rate,
             "hold_pressure": args.hold_pressure, "max_catch_up": args.max_catch_up, "duration": args.duration,
             "spin": args.spin}
    kw.update({k: v for k, v in flags.items() if v is not None})
    for flag, key, value in (("no_hub", "start_hub", False), ("no_zenoh", "zenoh", False),
                             ("zenoh_allow_remote", "zenoh_allow_remote", True)):
        if getattr(args, flag):
            kw[key] = value
    return ServeOptions(**kw)


def main(args) -> int:
    from rtsim.compile_status import CompileProgress

    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)     # start-up and progress lines show at once in a pipe
    opts = options(args)
    with CompileProgress("rtsim", lambda line: print(line, flush=True)):
        svc = Service(opts)
    summary = svc.run()
    if args.json:
        print(json.dumps(summary, indent=2, default=str))
    else:
        print(format_summary(summary))
    return 0


def _us(x):
    return "-" if x is None else f"{x * 1e6:.0f} us"


def format_summary(s: dict) -> str:
    h = s.get("health", {})
    lines = [f"rtsim serve: stopped after {s.get('wall_s', 0):.1f} s, simulated {s.get('sim_time', 0):.3f} s "
             f"({s.get('steps', 0)} steps), state {s.get('run_state')}"
             + (f": {s['message']}" if s.get("message") else ""),
             f"  loop: cpu/step p50 {_us(h.get('step_cpu_p50_s'))} p99 {_us(h.get('step_cpu_p99_s'))} "
             f"max {_us(h.get('step_cpu_max_s'))}; lateness p50 {_us(h.get('lateness_p50_s'))} p99 "
             f"{_us(h.get('lateness_p99_s'))} max {_us(h.get('lateness_max_s'))}; overruns {h.get('overruns')}, "
             f"stalls {h.get('stalls')}, skipped {h.get('skipped_steps')}, steal "
             f"{'-' if h.get('steal_s') is None else format(h['steal_s'], '.2f') + ' s'}"]
    c = s.get("can")
    if c:
        lines.append(f"  CAN: sent {c['sent']}, received {c['received']}, accepted commands "
                     f"{s.get('accepted_frames')}, rejected {s.get('rejected')}, bus errors "
                     f"{c['send_errors'] + c['recv_errors'] + c['error_frames']}")
    r = s.get("recording")
    if r:
        lines.append(f"  recording: {r['path']} ({r['written']} messages, {r['chunks']} chunks, "
                     f"{r['dropped']} dropped)")
    return "\n".join(lines)
