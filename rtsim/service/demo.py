"""`rtsim demo`: the service on embedded defaults plus the demo ECU in its own process, recorded.

The service runs on this process's main thread; the demo ECU (``drivers.ecu_demo``) is a child process
that talks to it over CAN only (the same bus the service opened). ``--vehicle eps_car`` (a car with
electric power steering) runs the EPS in the loop instead: the demo EPS controller (``drivers.eps_demo``)
commands the motor current every 1 ms from the car's DBC, the driver is the scenario's inside the
service (default: the bond-graph study's first life situation, a 35 deg step steer at 80 km/h), and the
summary reports the lateral acceleration and yaw rate reached, the commands accepted and the assist.
``--vehicle motorcycle`` (a two-wheeler) serves it with its rider inside the service on its own scenario
(``motorcycle_hil``, 20 s by default, lockstep) and runs the demo rider-assist ECU
(``drivers.rider_assist_demo``: steering damper, ride-by-wire, traction control and anti-lock); the
summary reports the distance, peak roll, the rider's path offset and the assist. The ECU starts first and waits,
saying so, for the service's bus and first frames as long as the service is starting (a first run compiles
the kernels for minutes; the service shows that progress; `SUPERVISED_CONNECT_TIMEOUT`). When the ECU
finishes its manoeuvre (or
``--duration`` of simulated time) the service stops, the recording is finalised and a summary is
printed: commands accepted, distance and peak speed (from the recorded state), whether the lane change
was reached, loop health and the file written; exit 0.

Ports: the hub's (``--can-hub-port``, else ``$RTSIM_CAN_HUB_PORT``, else 54701) and Zenoh's
(``--zenoh-port``, 7447) are checked before the ECU starts or anything is built (rtsim.service.ports): a
held one ends the demo at once with one line naming the port, its flag and its holder; a hub already
running on the hub port is refused too (the demo needs a bus of its own).

The demo is supervised both ways: if the ECU process ends any other way (killed, crashed, could not
reach the service) the service stops at once, during its build as well as while it runs, and one line
``rtsim demo: error: the demo ECU process (pid N) exited with code C after T s; its last stderr line:
...`` ends a non-zero exit (the ECU's stderr is passed on as it comes and its last lines kept); if the
service fails to start or is stopped by a signal, the ECU is stopped.
"""
from __future__ import annotations

import argparse
import math
import os
import shlex
import sys
import threading
from pathlib import Path

import numpy as np

from bridge.can_bus import DEFAULT_HUB_PORT, HUB_HOST, HUB_PORT_ENV, default_hub_port, socketcan_available

from rtsim.compile_status import CompileProgress
from rtsim.errors import RtsimError

from .cli import format_summary
from .ecu_process import EcuProcess
from .server import ServeOptions, Service, resolve_scenario, resolve_vehicle

ROOT = Path(__file__).resolve().parents[2]
#: tests: the ECU command to run instead of ``python -m drivers.ecu_demo`` (shell words; the bus,
#: manoeuvre and duration arguments are appended)
ECU_COMMAND_ENV = "RTSIM_DEMO_ECU"
EPS_SCENARIO = "step_steer_80kph"     # the EPS car's demo manoeuvre (its kind's Demo.scenario)
DEFAULT_ZENOH_PORT = 7447
#: s: how long the demo's ECU waits for the service. The demo supervises the start both ways (the ECU is
#: stopped when the service fails to start), so the ECU's own bound is not what ends a failed start; a
#: first start on a busy machine compiled for more than the ECU's default 600 s and the demo failed then.
SUPERVISED_CONNECT_TIMEOUT = 86400.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--record", default="demo.mcap", metavar="FILE.mcap",
                   help="recording (default demo.mcap in the current folder)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after this much simulated time, s "
                                                  "(default: the whole manoeuvre, about 50 s)")
    p.add_argument("--manoeuvre", choices=["demo", "straight_line", "lane_change"], default="demo",
                   help="demo: the straight-line manoeuvre, then a lane change (default)")
    p.add_argument("--mode", choices=["realtime", "lockstep"],
                   help="lockstep: the ECU requests every step (deterministic, not paced); default realtime, "
                        "lockstep for an EPS car (a Python controller answering within the 3 ms watchdog on a "
                        "host without real-time scheduling is not a given)")
    p.add_argument("--no-zenoh", action="store_true", help="do not publish over Zenoh")
    p.add_argument("--vehicle", metavar="FILE|NAME",
                   help="vehicle TOML or name in configs/vehicles (default xbw; a car with [eps], "
                                     "e.g. eps_car, runs the demo EPS controller in the loop; a two-wheeler, "
                                     "e.g. motorcycle, its rider in the service and the demo rider-assist ECU)")
    p.add_argument("--scenario", metavar="FILE|NAME", help="scenario TOML or name (default: hil_flat; with an EPS car "
                                      f"{EPS_SCENARIO}, the first life situation)")
    p.add_argument("--silent-after", type=float, metavar="S",
                   help="EPS demo: the controller stops commanding after this "
                                                      "much simulated time, s (the watchdog's safe state)")
    p.add_argument("--can-interface", metavar="INTERFACE",
                   help="python-can interface (default: vcan0 if present, else the hub)")
    p.add_argument("--can-channel", metavar="CHANNEL", help="python-can channel")
    p.add_argument("--can-hub-port", type=int, metavar="PORT",
                   help="port of the loopback CAN hub the demo starts on 127.0.0.1 when there is no vcan0 and no "
                        f"--can-interface (default: ${HUB_PORT_ENV}, else {DEFAULT_HUB_PORT}); it must be free")
    p.add_argument("--zenoh-port", type=int, default=DEFAULT_ZENOH_PORT, metavar="PORT",
                   help=f"port of the service's Zenoh endpoint tcp/127.0.0.1:PORT (default {DEFAULT_ZENOH_PORT}); "
                        "every port is checked before anything is compiled")


def recorded_motion(path: Path, vehicle_id: str) -> dict:
    """Distance (m) and peak speed (m/s) from the recorded state messages."""
    from bridge.mcap_recorder import read_recording

    messages, _ = read_recording(path)
    msgs = messages.get(f"rtsim/{vehicle_id}/state", [])
    if not msgs:
        return {"distance": 0.0, "peak_speed": 0.0, "state_messages": 0}
    xy = np.array([(m.data["pos_x"], m.data["pos_y"]) for m in msgs])
    speed = np.array([m.data["speed"] for m in msgs])
    return {"distance": float(np.sum(np.hypot(*np.diff(xy, axis=0).T))), "peak_speed": float(speed.max()),
            "state_messages": len(msgs), "final_position": [float(v) for v in xy[-1]]}


class _Supervisor:
    """Ends the service when the ECU process ends (``ecu_exited``, from the ECU's watcher thread).

    While the loop runs, ``Service.stop`` ends it (a stop that lands before ``run()`` starts counts
    too). During the build, numba may be compiling
    for a minute and cannot be interrupted safely (an exception thrown into its compiler surfaces as
    an unrelated error), so the demo reports the ECU's end and exits at once: the hub child process
    ends with it (its stdin closes) and a recording begun is readable like a killed one."""

    def __init__(self):
        self.lock = threading.Lock()
        self.phase = "building"             # building -> running -> done
        self.svc: Service | None = None

    def ecu_exited(self, ecu: EcuProcess) -> None:
        with self.lock:
            if self.phase == "building":
                _fail(ecu.describe_end(", while the service was starting"))
                sys.stdout.flush()
                os._exit(1)
            if self.phase == "running":
                self.svc.stop()

    def start_running(self, svc: Service) -> None:
        """Main thread, after the build: from now on the ECU's end stops ``svc``."""
        with self.lock:
            self.phase, self.svc = "running", svc

    def finish(self) -> None:
        with self.lock:
            self.phase = "done"


def _say(line: str) -> None:
    print(line, flush=True)


def _fail(line: str) -> int:
    print(f"rtsim demo: error: {line}", file=sys.stderr, flush=True)
    return 1


def main(args) -> int:
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)     # progress lines show at once in a pipe too
    vehicle = resolve_vehicle(args.vehicle) if args.vehicle else None
    from rtsim.vehicle.registry import open_vehicle
    demo = open_vehicle(vehicle).demo           # what the vehicle's demo runs (its ECU, mode, manoeuvre)
    if args.mode is None:
        args.mode = demo.mode
    if args.duration is None:
        args.duration = demo.duration
    kw = {"vehicle": vehicle} if vehicle is not None else {}
    if args.scenario or demo.scenario:
        kw["scenario"] = resolve_scenario(args.scenario or demo.scenario)
    for flag, port in (("--can-hub-port", args.can_hub_port), ("--zenoh-port", args.zenoh_port)):
        if port is not None and not 1 <= port <= 65535:
            raise RtsimError(f"{flag} {port}: a TCP port is 1..65535")
    opts = ServeOptions(mode=args.mode, record=Path(args.record), zenoh=not args.no_zenoh,
                        can_interface=args.can_interface, can_channel=args.can_channel,
                        can_hub_port=args.can_hub_port, zenoh_listen=[f"tcp/127.0.0.1:{args.zenoh_port}"], **kw)
    opts.check()                # bad options fail before any process starts
    from .ports import check_ports, service_ports
    check_ports(service_ports(opts, "--zenoh-port"), "rtsim demo")    # every port, before the ECU and any compile
    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        raise RtsimError(f"--duration {args.duration}: must be a positive number of seconds")
    if args.silent_after is not None and not (demo.silent_after and args.silent_after > 0):
        raise RtsimError("--silent-after: only with a car with electric power steering or a two-wheeler, a "
                         "positive time in s")
    if demo.scenario is not None and args.duration is None:     # the whole manoeuvre
        from drivers.scenario import load_scenario
        args.duration = load_scenario(opts.scenario).duration
    iface, chan = args.can_interface, args.can_channel
    if iface is None:       # the service's default choice, known before it starts
        iface, chan = ("socketcan", chan or "vcan0") if socketcan_available(chan or "vcan0") else \
            ("remote", chan or f"{HUB_HOST}:{args.can_hub_port or default_hub_port()}")
    # the ECU starts first (its imports and its own kernels take seconds) and waits for the service's
    # bus and first frames (bounded, saying so); the service ends when the ECU does
    ecu_module = demo.ecu
    cmd = shlex.split(os.environ.get(ECU_COMMAND_ENV, "")) or [sys.executable, "-m", ecu_module]
    cmd = cmd + ["--can-interface", iface, "--can-channel", chan, "--manoeuvre", args.manoeuvre,
                 "--connect-timeout", f"{SUPERVISED_CONNECT_TIMEOUT:g}"]
    if args.silent_after is not None:
        cmd += ["--silent-after", str(args.silent_after)]
    if args.duration is not None:
        cmd += ["--duration", str(args.duration)]
    if args.mode == "lockstep":
        cmd += ["--lockstep"]
    sup = _Supervisor()
    ecu = None
    ecu_ended_first = False             # the ECU ended before the service stopped (its normal end)
    try:
        ecu = EcuProcess(cmd, cwd=ROOT, on_exit=sup.ecu_exited)
        _say(f"rtsim demo: demo ECU process (pid {ecu.pid}): {' '.join(cmd[1:])}")
        with CompileProgress("rtsim", _say):
            svc = Service(opts, out=_say)
        sup.start_running(svc)
        summary = svc.run()
    finally:
        sup.finish()
        if ecu is not None:
            ecu_ended_first = ecu.ended
            if not ecu_ended_first:
                ecu.stop()
    print(format_summary(summary))
    if not ecu_ended_first:             # a signal (Ctrl-C, SIGTERM) stopped the service
        print("rtsim demo: stopped before the demo ECU finished; the ECU was stopped", file=sys.stderr,
              flush=True)
        return 130
    ecu.wait(5.0)
    if ecu.returncode != 0:
        return _fail(ecu.describe_end())
    return REPORTS[demo.ecu](args, svc, summary, ecu.result)


def recorded_eps(path: Path, vehicle_id: str) -> dict:
    """From the recording: the lateral acceleration (m/s^2) and yaw rate (rad/s) reached, the motor
    current's peak (A), and when the EPS power stage was last on and first seen off after (s)."""
    from bridge.mcap_recorder import read_recording

    messages, _ = read_recording(path)
    sens = messages.get(f"rtsim/{vehicle_id}/sensors", [])
    if not sens:
        return {"samples": 0}
    d = {k: np.array([m.data[k] for m in sens], dtype=float)
         for k in ("time", "accel_y", "gyro_z", "eps_motor_current", "eps_power_stage")}
    on = np.flatnonzero(d["eps_power_stage"] > 0.5)
    off_after = np.flatnonzero((d["eps_power_stage"] < 0.5) & (np.arange(len(sens)) > (on[0] if len(on) else 0)))
    return {"samples": len(sens), "peak_accel_y": float(np.max(np.abs(d["accel_y"]))),
            "peak_yaw_rate": float(np.max(np.abs(d["gyro_z"]))),
            "peak_motor_current": float(np.max(np.abs(d["eps_motor_current"]))),
            "stage_first_on": float(d["time"][on[0]]) if len(on) else None,
            "stage_off_at": float(d["time"][off_after[0]]) if len(on) and len(off_after) else None}


def _report_eps(args, svc: Service, summary: dict, result: dict) -> int:
    """The closing lines of an EPS-in-the-loop demo: what the car and the assist did, from the recording."""
    rec = recorded_eps(Path(args.record), svc.vehicle_id)
    accepted = summary.get("accepted_frames", 0) or 0
    g = 9.80665
    print(f"rtsim demo: EPS controller sent {result.get('commands_sent', 0)} current commands over "
          f"{result.get('ecu_time', 0):.2f} s, {accepted} accepted; peak lateral acceleration "
          f"{rec.get('peak_accel_y', 0) / g:.2f} g, peak yaw rate {math.degrees(rec.get('peak_yaw_rate', 0)):.1f} deg/s, "
          f"peak motor current {rec.get('peak_motor_current', 0):.1f} A (recorded sensors)")
    if rec.get("stage_off_at") is not None:
        print(f"rtsim demo: EPS power stage off at t = {rec['stage_off_at']:.3f} s (the controller's last "
              f"command at {result.get('last_command_sample_t') or 0:.3f} s): the watchdog's safe state")
    print(f"rtsim demo: recording written to {args.record}")
    if rec.get("samples", 0) <= 0 or result.get("samples", 0) <= 0:
        return _fail("no EPS sensor sample was exchanged")
    if accepted <= 0 or rec.get("stage_first_on") is None:
        return _fail("the service accepted no command from the EPS controller (see the rejection counters above)")
    return 0


def recorded_ride(path: Path, vehicle_id: str) -> dict:
    """From a two-wheeler's recording: peak roll (rad), the rider's path offset (RMS and peak, m), the
    distance (m), the assist torque's peak (N m) and the samples recorded."""
    from bridge.mcap_recorder import read_recording

    messages, _ = read_recording(path)
    st = messages.get(f"rtsim/{vehicle_id}/state", [])
    if not st:
        return {"state_messages": 0}
    d = {k: np.array([m.data[k] for m in st], dtype=float)
         for k in ("pos_x", "pos_y", "roll_angle", "path_offset", "assist_torque")}
    return {"state_messages": len(st), "peak_roll": float(np.max(np.abs(d["roll_angle"]))),
            "path_offset_rms": float(np.sqrt(np.mean(d["path_offset"] ** 2))),
            "path_offset_max": float(np.max(np.abs(d["path_offset"]))),
            "distance": float(np.sum(np.hypot(np.diff(d["pos_x"]), np.diff(d["pos_y"])))),
            "peak_assist": float(np.max(np.abs(d["assist_torque"])))}


def _report_ride(args, svc: Service, summary: dict, result: dict) -> int:
    """The closing lines of a rider-assist demo: what the rider, the two-wheeler and the ECU did."""
    rec = recorded_ride(Path(args.record), svc.vehicle_id)
    accepted = summary.get("accepted_frames", 0) or 0
    print(f"rtsim demo: rider-assist ECU sent {result.get('commands_sent', 0)} commands over "
          f"{result.get('ecu_time', 0):.2f} s, {accepted} accepted; the rider rode {rec.get('distance', 0):.0f} m, "
          f"peak roll {math.degrees(rec.get('peak_roll', 0)):.1f} deg, path offset RMS "
          f"{rec.get('path_offset_rms', 0):.2f} m (max {rec.get('path_offset_max', 0):.2f} m), peak assist "
          f"torque {rec.get('peak_assist', 0):.2f} N m (recorded state)")
    if summary.get("run_state") == "model_fault":
        print(f"rtsim demo: the session ended in the model-fault state: {summary.get('message')}")
    print(f"rtsim demo: recording written to {args.record}")
    if result.get("samples", 0) <= 0 or rec.get("state_messages", 0) <= 0:
        return _fail("no sensor sample was exchanged")
    if accepted <= 0:
        return _fail("the service accepted no command from the rider-assist ECU (see the rejection counters above)")
    return 0


def _report(args, svc: Service, summary: dict, result: dict) -> int:
    """The closing lines of a demo whose ECU finished: what the car did, from the recording."""
    motion = recorded_motion(Path(args.record), svc.vehicle_id)
    accepted = summary.get("accepted_frames", 0) or 0
    lane = any(p.get("phase") == "lane_change" for p in result.get("phases", []))
    print(f"rtsim demo: ECU {'finished' if result.get('done') else 'stopped'} after "
          f"{result.get('ecu_time', 0):.1f} s in its {result.get('phase', '?')} phase; "
          f"{accepted} commands accepted; distance {motion['distance']:.1f} m, peak speed "
          f"{motion['peak_speed'] * 3.6:.1f} km/h (recorded state); " + (
              f"lane change reached (lateral offset {result.get('lane_offset_estimate', 0):.2f} m, ECU estimate)"
              if lane else "lane change not reached"))
    print(f"rtsim demo: recording written to {args.record}")
    if result.get("samples", 0) <= 0:
        return _fail("the demo ECU received no sensor sample from the service")
    if accepted <= 0:
        return _fail("the service accepted no command from the demo ECU (see the rejection counters above)")
    return 0


#: the closing report of each demo ECU (the vehicle's ``Demo.ecu``): what that ECU did and reported
REPORTS = {"drivers.ecu_demo": _report, "drivers.eps_demo": _report_eps, "drivers.rider_assist_demo": _report_ride}
