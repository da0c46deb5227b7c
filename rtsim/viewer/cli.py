"""`rtsim view`: serve the driving-simulator page of a running `rtsim serve` (see rtsim.viewer.server).

Binds 127.0.0.1 unless ``--bind`` names another address; an address off loopback (the page then drives the
car from another machine: only on a bench network you trust) needs ``--web-allow-remote``, prints a warning,
and makes a random per-session token that any driving request must carry (it is in the URL printed). Joins the service over Zenoh as an observer (peer mode,
scouting off, tcp on 127.0.0.1 unless ``--allow-remote``). Given recordings (``rtsim view A.mcap [B.mcap]``)
it serves them instead, without Zenoh: the page plays them with a timeline, two side by side.
"""
from __future__ import annotations

import argparse
import ipaddress
import secrets
import socket
import sys

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
DEFAULT_PORT = 8470


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("recordings", nargs="*", metavar="FILE.mcap",
                   help="play these recordings of rtsim serve instead (one, or two side by side) with a timeline")
    p.add_argument("--connect", metavar="ENDPOINT", action="append",
                   help=f"Zenoh endpoint of the service (repeatable; default {DEFAULT_ENDPOINT})")
    p.add_argument("--vehicle-id", metavar="ID", help="vehicle id of the service (default: the one that answers)")
    p.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="address the web server listens on (default 127.0.0.1: this machine only; another than "
                        "loopback only with --web-allow-remote)")
    p.add_argument("--web-allow-remote", action="store_true",
                   help="let the web server bind an address off loopback (other machines can then open the page): "
                        "a warning is printed and driving needs the per-session token in the URL printed")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, metavar="PORT",
                   help=f"web server port (default {DEFAULT_PORT}; "
                                                                   "0: any free port)")
    p.add_argument("--allow-remote", action="store_true", help="allow a non-loopback Zenoh endpoint")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")


def is_loopback(host: str) -> bool:
    """True for "localhost" and any loopback address (127.0.0.0/8, ::1)."""
    try:
        return host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def remote_policy(bind: str, allow_remote: bool) -> tuple[str | None, str | None]:
    """(session token, warning line) for binding ``bind``: (None, None) on loopback; a fresh random token
    and the warning off loopback with ``allow_remote``; RtsimError off loopback without it."""
    from rtsim.errors import RtsimError

    if is_loopback(bind):
        return None, None
    if not allow_remote:
        raise RtsimError(f"rtsim view: --bind {bind}: not a loopback address, and the page can drive the car; "
                         f"give --web-allow-remote to serve it to other machines (driving then needs the "
                         f"session token in the URL printed)")
    warning = (f"rtsim view: warning: the web server binds {bind}, off loopback: other machines can open the page; "
               f"driving requests need this session's token, in the URL printed below: share it only with who "
               f"may drive the car")
    return secrets.token_urlsafe(16), warning


def page_url(bind: str, port: int, token: str | None) -> str:
    """The page's URL as printed: the bind address (this machine's name for an unspecified address) and
    the session token's query when there is one."""
    host = socket.gethostname() if bind in ("0.0.0.0", "::", "") else bind
    host = f"[{host}]" if ":" in host else host
    return f"http://{host}:{port}/" + (f"?token={token}" if token else "")


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
    token, warning = remote_policy(args.bind, args.web_allow_remote)
    check_libraries()
    if len(args.recordings) > 2:
        raise RtsimError(f"rtsim view: at most two recordings side by side, got {len(args.recordings)}")
    if args.recordings:
        from .recording import Recording

        recs = [Recording(f) for f in args.recordings]
        for r in recs:                        # first: what each file lost and how its session ended
            print(f"rtsim view: {r.path}: {r.health}", flush=True)
        server = ViewServer(None, args.bind, args.port, recordings=recs, token=token)
        what = " and ".join(f"{r.path.name} ({r.vehicle_id}, {r.duration:.1f} s)"
                            for r in recs)
    else:
        connect = args.connect or [DEFAULT_ENDPOINT]
        vid = args.vehicle_id or discover_vehicle_id(connect, args.allow_remote)
        server = ViewServer(Relay(vid, connect, args.allow_remote), args.bind, args.port, token=token)
        what = f"vehicle {vid} at {', '.join(connect)}"

    def started(s):
        if warning:
            print(warning, file=sys.stderr, flush=True)
        print(f"rtsim view: {what}; open {page_url(s.bind, s.port, token)} (stop with Ctrl-C)", flush=True)

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
