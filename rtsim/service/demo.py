"""`rtsim demo`: the service on embedded defaults plus the demo ECU in its own process, recorded.

The service runs on this process's main thread; the demo ECU (``drivers.ecu_demo``) is a child process
that talks to it over CAN only (the same bus the service opened). When the ECU finishes its manoeuvre
(or ``--duration`` of simulated time) the service stops, the recording is finalised and a summary is
printed: distance and peak speed (from the recorded state), the ECU's own estimates, loop health and
the file written.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np

from bridge.can_bus import HUB_HOST, default_hub_port, socketcan_available

from .cli import format_summary
from .server import ServeOptions, Service


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--record", default="demo.mcap", metavar="FILE.mcap",
                   help="recording (default demo.mcap in the current folder)")
    p.add_argument("--duration", type=float, help="stop after this much simulated time, s "
                                                  "(default: the whole manoeuvre, about 50 s)")
    p.add_argument("--manoeuvre", choices=["demo", "straight_line", "lane_change"], default="demo",
                   help="demo: the straight-line manoeuvre, then a lane change (default)")
    p.add_argument("--mode", choices=["realtime", "lockstep"], default="realtime",
                   help="lockstep: the ECU requests every step (deterministic, not paced)")
    p.add_argument("--no-zenoh", action="store_true", help="do not publish over Zenoh")
    p.add_argument("--can-interface", help="python-can interface (default: vcan0 if present, else the hub)")
    p.add_argument("--can-channel", help="python-can channel")


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


def main(args) -> int:
    opts = ServeOptions(mode=args.mode, record=Path(args.record), zenoh=not args.no_zenoh,
                        can_interface=args.can_interface, can_channel=args.can_channel)
    iface, chan = args.can_interface, args.can_channel
    if iface is None:       # the service's default choice, known before it starts
        iface, chan = ("socketcan", chan or "vcan0") if socketcan_available(chan or "vcan0") else \
            ("remote", chan or f"{HUB_HOST}:{default_hub_port()}")
    # the ECU starts first (its imports take seconds) and connects once the service's bus is up
    cmd = [sys.executable, "-m", "drivers.ecu_demo", "--can-interface", iface, "--can-channel", chan,
           "--manoeuvre", args.manoeuvre]
    if args.duration is not None:
        cmd += ["--duration", str(args.duration)]
    if args.mode == "lockstep":
        cmd += ["--lockstep"]
    print(f"rtsim demo: demo ECU process: {' '.join(cmd[1:])}")
    ecu = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[2])
    try:
        svc = Service(opts)
    except BaseException:
        ecu.kill()
        raise
    result: dict = {}

    def watch():
        out, _ = ecu.communicate()
        lines = [ln for ln in out.splitlines() if ln.startswith("{")]
        if lines:
            result.update(json.loads(lines[-1]))
        svc.stop()
    threading.Thread(target=watch, daemon=True).start()
    try:
        summary = svc.run()
    finally:
        if ecu.poll() is None:
            ecu.terminate()
            try:
                ecu.wait(5)
            except subprocess.TimeoutExpired:
                ecu.kill()
    print(format_summary(summary))
    motion = recorded_motion(Path(args.record), svc.vehicle_id)
    print(f"rtsim demo: {result.get('phase', '?')} phase reached, ECU {'finished' if result.get('done') else 'stopped'} "
          f"after {result.get('ecu_time', 0):.1f} s; distance {motion['distance']:.1f} m, peak speed "
          f"{motion['peak_speed'] * 3.6:.1f} km/h (recorded state); ECU estimates: distance "
          f"{result.get('distance_estimate', 0):.1f} m, lane offset {result.get('lane_offset_estimate', 0):.2f} m")
    print(f"rtsim demo: recording written to {args.record}")
    return 0 if result.get("samples", 0) > 0 else 1
