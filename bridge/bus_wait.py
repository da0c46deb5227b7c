"""Waiting, bounded and out loud, for a service that may still be starting.

A client started beside the service (the demo ECU under `rtsim demo`, a bench tool) can be up long
before the service's bus is: on a fresh machine the service compiles its kernels for a minute or more
first. ``wait_for_bus`` retries ``open_bus`` while the hub is not reachable (``BusUnavailable``) and
fails at once on anything else (an unknown interface does not fix itself); ``Waiting`` prints a line
every ``every`` s while a wait lasts, so the user knows what the client is waiting for.
"""
from __future__ import annotations

import argparse
import math
import time
from typing import Callable

from rtsim.errors import RtsimError

from .can_bus import BusUnavailable, open_bus


def bus_name(interface: str | None, channel: str | None) -> str:
    """How a bus is named in messages: the hub's address, else ``interface channel``."""
    if interface in (None, "remote") and channel:
        return channel
    return " ".join(str(x) for x in (interface or "default", channel) if x)


class Waiting:
    """Reports a wait: ``tick(what)`` prints ``"<prefix>: waiting for <what> (N s)..."`` each time
    another ``every`` s have passed since ``start`` (monotonic s); ``done(what)`` prints how long it
    took, if anything was reported. ``elapsed`` is in s."""

    def __init__(self, prefix: str, say: Callable[[str], None], every: float = 10.0,
                 start: float | None = None):
        self.prefix, self.say, self.every = prefix, say, every
        self.start = time.monotonic() if start is None else start
        self.reported = 0                   # lines printed so far

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.start

    def tick(self, what: str) -> None:
        n = int(self.elapsed // self.every)
        if n > self.reported:
            self.reported = n
            self.say(f"{self.prefix}: waiting for {what} ({self.elapsed:.0f} s)...")

    def done(self, what: str) -> None:
        if self.reported:
            self.say(f"{self.prefix}: {what} after {self.elapsed:.0f} s")


def wait_for_bus(interface: str | None, channel: str | None, deadline: float, waiting: Waiting,
                 retry: float = 0.25):
    """Open the bus, retrying while its hub is not reachable, until ``deadline`` (monotonic s).
    Raises RtsimError: at once for a bus that cannot work (unknown interface, bad channel, missing
    package), at the deadline with the last cause when the hub never came."""
    where = bus_name(interface, channel)
    while True:
        try:
            bus = open_bus(interface, channel)
        except BusUnavailable as exc:
            left = deadline - time.monotonic()
            if left <= 0:
                raise RtsimError(f"no CAN bus at {where} after {waiting.elapsed:.0f} s ({exc.reason}); "
                                 f"is the service running (`rtsim serve`)?") from None
            waiting.tick(f"the service's CAN bus at {where}")
            time.sleep(min(retry, left))
            continue
        waiting.done(f"on the service's CAN bus at {where}")
        return bus


def positive_seconds(text: str) -> float:
    """argparse type: a positive, finite number of seconds."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (v > 0 and math.isfinite(v)):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a positive number of seconds")
    return v


def add_client_arguments(p: argparse.ArgumentParser) -> None:
    """The bus and waiting options every CAN client of the service takes (the demo ECUs)."""
    p.add_argument("--can-interface", metavar="INTERFACE")
    p.add_argument("--can-channel", metavar="CHANNEL")
    p.add_argument("--duration", type=positive_seconds, metavar="S", help="stop after this much simulated time, s")
    p.add_argument("--lockstep", action="store_true", help="request the steps (service in --mode lockstep)")
    p.add_argument("--timeout", type=positive_seconds, default=5.0, metavar="S",
                   help="give up after this long without frames once they flowed, s (default 5)")
    p.add_argument("--connect-timeout", type=positive_seconds, default=600.0, metavar="S",
                   help="wait at most this long for the service: its CAN bus, then its first sensor frames "
                        "(a first run on a fresh machine compiles for a minute or more), s (default 600)")
    p.add_argument("--report-every", type=positive_seconds, default=10.0, metavar="S",
                   help="while waiting for the service, say so this often, s (default 10)")
