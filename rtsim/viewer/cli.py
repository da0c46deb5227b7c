"""`rtsim view`: serve the driving-simulator page of a running `rtsim serve` (see rtsim.viewer.server).

Binds 127.0.0.1 unless ``--bind`` names another address (the page then drives the car from another
machine: only on a bench network you trust). Joins the service over Zenoh as an observer (peer mode,
scouting off, tcp on 127.0.0.1 unless ``--allow-remote``). Given recordings (``rtsim view A.mcap [B.mcap]``)
it serves them instead, without Zenoh: the page plays them with a timeline, two side by side.
"""
from __future__ import annotations

import argparse

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_PORT = 8470


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recordings", nargs="*", metavar="FILE.mcap",
                   help="play these recordings of rtsim serve instead (one, or two side by side) with a timeline")
    p.add_argument("--connect", metavar="ENDPOINT", action="append",
                   help=f"Zenoh endpoint of the service (repeatable; default {DEFAULT_ENDPOINT})")
    p.add_argument("--vehicle-id", help="vehicle id of the service (default: the one that answers)")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="address the web server listens on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"web server port (default {DEFAULT_PORT}; "
                                                                   "0: any free port)")
    p.add_argument("--allow-remote", action="store_true", help="allow a non-loopback Zenoh endpoint")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")


def main(args: argparse.Namespace) -> int:
    import asyncio
    import signal

    from rtsim.errors import RtsimError

    from .relay import Relay, discover_vehicle_id
    from .server import ViewServer, check_libraries

    if not 0 <= args.port <= 65535:
        raise RtsimError(f"--port {args.port} out of range 0..65535")
    if args.duration is not None and not args.duration > 0:
        raise RtsimError(f"--duration must be a positive number of seconds, got {args.duration}")
    check_libraries()
    if len(args.recordings) > 2:
        raise RtsimError(f"rtsim view: at most two recordings side by side, got {len(args.recordings)}")
    if args.recordings:
        from .recording import Recording

        recs = [Recording(f) for f in args.recordings]
        for r in recs:                        # first: what each file lost and how its session ended
            print(f"rtsim view: {r.path}: {r.health}", flush=True)
        server = ViewServer(None, args.bind, args.port, recordings=recs)
        what = " and ".join(f"{r.path.name} ({r.vehicle_id}, {r.duration:.1f} s)"
                            for r in recs)
    else:
        connect = args.connect or [DEFAULT_ENDPOINT]
        vid = args.vehicle_id or discover_vehicle_id(connect, args.allow_remote)
        server = ViewServer(Relay(vid, connect, args.allow_remote), args.bind, args.port)
        what = f"vehicle {vid} at {', '.join(connect)}"

    def started(s):
        host = s.bind if ":" not in s.bind else f"[{s.bind}]"
        print(f"rtsim view: {what}; open http://{host}:{s.port}/ (stop with Ctrl-C)", flush=True)

    async def run():
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        if args.duration is not None:
            loop.call_later(args.duration, stop.set)
        await server.serve(stop, started)

    try:
        asyncio.run(run())
    except OSError as exc:
        raise RtsimError(f"rtsim view: cannot listen on {args.bind}:{args.port}: {exc}") from None
    finally:
        server.close()
    return 0
