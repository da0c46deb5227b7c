"""`rtsim serve` command line: the flags are derived from the settings' declarations (rtsim.service.config)."""
from __future__ import annotations

import json
import sys

from .config import add_arguments, options
from .server import Service

__all__ = ["add_arguments", "options", "main"]


def main(args) -> int:
    from rtsim.compile_status import CompileProgress

    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)     # start-up and progress lines show at once in a pipe
    opts = options(args)
    opts.check()
    from .ports import check_ports, service_ports
    for line in check_ports(service_ports(opts), "rtsim serve", join_hub=True):   # before any compile
        print(line, flush=True)
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
