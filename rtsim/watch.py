"""`rtsim watch`: a terminal dashboard of a running `rtsim serve`, fed by its Zenoh topics.

Shows the sensors, a subset of the vehicle state (speed, pose, wheel speeds, tyre loads), the
actuators and the commands applied, loop health (lateness, CPU per step, overruns, skipped steps,
steal), faults, rejected-frame counters and the message rate of every topic. ``--once`` prints a
single snapshot as soon as every topic has delivered a message (or, after ``--timeout``, names the
silent ones) and exits: for tests, scripts and non-terminal output.

Exit status: 0 when every topic was heard, 1 when some stayed silent (``--once``). Bad endpoints
raise RtsimError (printed in one line by the CLI). The Zenoh session is an observer: peer mode,
scouting off, tcp on 127.0.0.1 only unless ``--allow-remote``.
"""
from __future__ import annotations

import argparse
import collections
import threading
import time

from rtsim.channels import BY_NAME, STATE

TOPICS = ("sensors", "state", "status", "commands")
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
RATE_WINDOW = 2.0          # s of arrivals a topic's rate is averaged over

_UNITS = {c.name: c.unit for c in (*BY_NAME.values(), *STATE)}   # the known channels' units
STATE_SHOWN = ("speed", "pos_x", "pos_y", "pos_z", "roll_angle", "pitch_angle", "yaw_angle",
               "vel_x", "vel_y", "yaw_rate",
               *(f"wheel_speed_{w}" for w in ("fl", "fr", "rl", "rr")),
               *(f"tyre_fz_{w}" for w in ("fl", "fr", "rl", "rr")))
ACTUATORS = ("throttle_angle", "brake_pressure", "steering_wheel_angle", "rack_position",
             "engine_speed")
COMMANDS_SHOWN = ("throttle_angle_cmd", "brake_pressure_cmd", "steering_wheel_angle_cmd")


class Monitor:
    """Latest message, message count and arrival rate per topic; fed from Zenoh's threads."""

    def __init__(self, topics=TOPICS, clock=time.monotonic):
        self._clock = clock
        self._lock = threading.Lock()
        self._last = {k: None for k in topics}
        self._count = dict.fromkeys(topics, 0)
        self._arrivals = {k: collections.deque() for k in topics}
        self._seen_at = dict.fromkeys(topics, None)
        self._first_at = dict.fromkeys(topics, None)

    def callback(self, kind: str):
        def on_message(msg: dict) -> None:
            now = self._clock()
            with self._lock:
                self._last[kind] = msg
                self._count[kind] += 1
                self._seen_at[kind] = now
                if self._first_at[kind] is None:
                    self._first_at[kind] = now
                q = self._arrivals[kind]
                q.append(now)
                while q and q[0] < now - RATE_WINDOW:
                    q.popleft()
        return on_message

    def silent(self) -> list[str]:
        with self._lock:
            return [k for k, n in self._count.items() if n == 0]

    def snapshot(self) -> dict:
        """kind -> {"msg", "count", "rate" (Hz), "age" (s since the last message)}."""
        now = self._clock()
        out = {}
        with self._lock:
            for k, msg in self._last.items():
                q = self._arrivals[k]
                while q and q[0] < now - RATE_WINDOW:
                    q.popleft()
                first = self._first_at[k]
                if first is not None and now - first >= RATE_WINDOW:
                    rate = len(q) / RATE_WINDOW          # a full window of arrivals
                elif len(q) >= 2:
                    rate = (len(q) - 1) / max(now - q[0], 1e-9)   # since the first message
                else:
                    rate = 0.0
                seen = self._seen_at[k]
                out[k] = {"msg": msg, "count": self._count[k], "rate": rate,
                          "age": None if seen is None else now - seen}
        return out


# ------------------------------------------------------------------------------------- rendering

def _num(v, spec: str = ".5g") -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, (int, float)):
        return format(v, spec)
    return str(v)


def _scaled(v, scale: float, unit: str, spec: str = ".3f") -> str:
    return "-" if not isinstance(v, (int, float)) else f"{format(v * scale, spec)} {unit}"


def _table(title: str, headers=("channel", "value", "unit")):
    from rich.table import Table
    t = Table(title=title, title_justify="left", show_edge=False, pad_edge=False, box=None,
              header_style="bold")
    for i, h in enumerate(headers):
        t.add_column(h, justify="right" if i == 1 else "left", no_wrap=True)
    return t


def _channels(title: str, msg: dict | None, names) -> object:
    t = _table(title)
    for n in names:
        t.add_row(n, _num((msg or {}).get(n)), _UNITS.get(n, ""))
    return t


def render(snap: dict, vehicle_id: str, endpoint: str):
    """A rich renderable of one snapshot (``Monitor.snapshot()``)."""
    from rich.columns import Columns
    from rich.console import Group
    from rich.text import Text

    status = snap["status"]["msg"] or {}
    state = snap["state"]["msg"]
    cmds = snap["commands"]["msg"] or {}

    head = Text()
    head.append(f"rtsim watch  {vehicle_id}", style="bold")
    head.append(f" @ {endpoint}   ")
    if status:
        head.append(f"mode {status.get('mode', '?')}  {status.get('run_state', '?')}  "
                    f"sim {_num(status.get('sim_time'), '.3f')} s  steps {_num(status.get('steps'))}  "
                    f"scenario {status.get('scenario') or '-'}")
        if status.get("message"):       # the model-fault state's line (time, step, reason, coordinate) in red
            head.append(f"\n{status['message']}",
                        style="bold red" if status.get("run_state") == "model_fault" else "italic")
    else:
        head.append("no status yet", style="yellow")

    sensor_msg = snap["sensors"]["msg"]               # the served vehicle's own sensor channels
    sensors = _channels("Sensors", sensor_msg, [n for n in (sensor_msg or {}) if n != "time"])
    vehicle = _channels("Vehicle state", state, [n for n in STATE_SHOWN if state is None or n in state])

    act = _channels("Actuators", state, ACTUATORS)
    for n in COMMANDS_SHOWN:
        act.add_row(n, _num(cmds.get(n)), _UNITS.get(n[:-4], ""))
    act.add_row("command source", str(cmds.get("source", "-")), "")

    health = _table("Loop health", ("", "value", ""))
    for label, key, scale, unit in (("lateness p50", "lateness_p50", 1e3, "ms"),
                                    ("lateness p99", "lateness_p99", 1e3, "ms"),
                                    ("lateness max", "lateness_max", 1e3, "ms"),
                                    ("cpu/step p50", "cpu_p50", 1e6, "us"),
                                    ("cpu/step p99", "cpu_p99", 1e6, "us"),
                                    ("cpu/step max", "cpu_max", 1e6, "us"),
                                    ("steal", "steal", 1e3, "ms")):
        health.add_row(label, _scaled(status.get(key), scale, unit), "")
    for key in ("overruns", "skipped_steps", "catch_up_steps", "stalls", "zenoh_dropped"):
        health.add_row(key, _num(status.get(key)), "")
    rec = status.get("recorder")
    if rec:
        health.add_row("recorder", f"{rec.get('written')} written, {rec.get('dropped')} dropped", "")

    faults = _table("Faults / CAN", ("", "value", ""))
    for name, active in (status.get("faults") or {}).items():
        faults.add_row(name, Text("FAULT", style="bold red") if active else Text("ok", style="green"), "")
    for name, n in (status.get("rejected") or {}).items():
        faults.add_row(f"rejected {name}", _num(n), "")
    faults.add_row("accepted frames", _num(status.get("accepted_frames")), "")
    if "foreign_frames" in status:      # frames with the service's own ids it did not send (second simulator)
        faults.add_row("foreign frames", _num(status.get("foreign_frames")), "")
    faults.add_row("bus errors", _num(status.get("bus_errors")), "")

    topics = _table("Topics", ("topic", "rate", "messages"))
    topics.columns[1].justify = "right"
    topics.columns[2].justify = "right"
    for k, s in snap.items():
        rate = Text("silent", style="yellow") if s["count"] == 0 else f"{s['rate']:.1f} Hz"
        topics.add_row(k, rate, str(s["count"]))

    return Group(head, Text(""), Columns([sensors, vehicle, act, health, faults, topics],
                                         padding=(1, 4)))


# ------------------------------------------------------------------------------------- command

def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--connect", metavar="ENDPOINT", action="append",
                   help=f"Zenoh endpoint of the service (repeatable; default {DEFAULT_ENDPOINT})")
    p.add_argument("--vehicle-id", default="xbw", metavar="ID", help="vehicle id of the service (default xbw)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (live view)")
    p.add_argument("--once", action="store_true",
                   help="print one snapshot once every topic has been heard (or --timeout "
                        "passed) and exit; for scripts and non-terminal output")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S",
                   help="--once: how long to wait for silent topics (default 5 s)")
    p.add_argument("--allow-remote", action="store_true",
                   help="allow a non-loopback endpoint (a bench router)")


def main(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.live import Live

    from bridge.zenoh_link import ZenohClient
    from rtsim.errors import RtsimError

    for flag, v in (("--duration", args.duration), ("--timeout", args.timeout)):
        if v is not None and not v > 0:
            raise RtsimError(f"{flag} must be a positive number of seconds, got {v}")
    connect = args.connect or [DEFAULT_ENDPOINT]
    endpoint = ", ".join(connect)
    console = Console()
    if not console.is_terminal:
        console = Console(width=120)
    monitor = Monitor()
    client = ZenohClient(args.vehicle_id, connect=connect, allow_remote=args.allow_remote)
    try:
        for k in TOPICS:
            client.subscribe(k, monitor.callback(k))
        t0 = time.monotonic()
        if args.once:
            deadline = t0 + args.timeout
            while monitor.silent() and time.monotonic() < deadline:
                time.sleep(0.02)
            console.print(render(monitor.snapshot(), args.vehicle_id, endpoint))
            silent = monitor.silent()
            if silent:
                console.print(f"silent topics (no message within {args.timeout:g} s from "
                              f"{endpoint}): {', '.join(silent)}")
                return 1
            return 0
        try:
            with Live(render(monitor.snapshot(), args.vehicle_id, endpoint), console=console,
                      refresh_per_second=4, transient=False) as live:
                while args.duration is None or time.monotonic() - t0 < args.duration:
                    time.sleep(0.25)
                    live.update(render(monitor.snapshot(), args.vehicle_id, endpoint))
        except KeyboardInterrupt:
            pass
        return 0
    finally:
        client.close()
