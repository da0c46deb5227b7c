"""The viewer's Zenoh side: what the service publishes, kept for the pages, and the user's commands sent on.

Nothing here may slow the service: the subscriber callbacks (Zenoh's threads) only append the payload's
JSON bytes as they came, with a sequence number and the arrival time, to bounded deques (the oldest
fall off: a page that pulls rarely misses samples, nothing queues without bound); pages take what is
new since their last pull (``Relay.batch``) at their own frame rate. The user's commands go to the
service's ``drive`` control op from one thread (``DriveSender``); a command that arrives while one is
in flight replaces any waiting one (latest wins), so a fast input device never builds a queue.
"""
from __future__ import annotations

import collections
import itertools
import json
import threading
import time
from typing import Callable

from bridge.zenoh_link import ZenohClient, zenoh_config
from rtsim.errors import RtsimError

KEEP = {"state": 1024, "sensors": 2048, "commands": 256, "status": 8}
BATCH_MAX = 512           # samples of one kind per pull (the newest)


def discover_vehicle_id(connect: list[str], allow_remote: bool = False, timeout: float = 10.0) -> str:
    """The vehicle id of the service at ``connect`` (the first that answers ``rtsim/*/config``)."""
    import zenoh

    session = zenoh.open(zenoh_config((), connect, "peer", allow_remote))
    try:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for reply in session.get("rtsim/*/config", timeout=min(2.0, max(0.1, deadline - time.monotonic()))):
                if reply.ok is not None:
                    return str(reply.ok.key_expr).split("/")[1]
            time.sleep(0.1)
    finally:
        session.close()
    raise RtsimError(f"no rtsim service answered at {', '.join(connect)} within {timeout:g} s "
                     f"(is `rtsim serve` running? give --vehicle-id if several are)")


class Relay:
    """Subscriptions to one service's topics (see the module docstring) and its configuration."""

    def __init__(self, vehicle_id: str, connect: list[str], allow_remote: bool = False):
        self.client = ZenohClient(vehicle_id, connect=connect, allow_remote=allow_remote)
        self.vehicle_id = vehicle_id
        self._n = itertools.count(1)
        self.rings = {k: collections.deque(maxlen=n) for k, n in KEEP.items()}
        self.received = dict.fromkeys(KEEP, 0)
        for kind in KEEP:
            self.client.subscribe(kind, self._keeper(kind), raw=True)

    def _keeper(self, kind: str) -> Callable[[bytes], None]:
        ring, n, received = self.rings[kind], self._n, self.received

        def keep(data: bytes) -> None:          # Zenoh's thread: an append, nothing else
            ring.append((next(n), time.time(), data))
            received[kind] += 1
        return keep

    def config(self, timeout: float = 10.0) -> dict:
        return self.client.config(timeout=timeout)

    def batch(self, last: dict[str, int]) -> str:
        """A ``data`` message (JSON text) of every sample newer than ``last[kind]`` (updated), the newest
        ``BATCH_MAX`` per kind; each kind a list of the payloads as published, with ``rx``: the arrival
        time (s, this machine's wall clock) of the newest."""
        parts = ['{"type":"data","server_time":%r' % time.time()]
        for kind, ring in self.rings.items():
            snap = list(ring)                   # (the deque may grow meanwhile: a copy is consistent)
            since = last.get(kind, 0)
            new = [item for item in snap[-BATCH_MAX:] if item[0] > since]
            if kind == "status" and new:
                new = new[-1:]
            if not new:
                continue
            last[kind] = new[-1][0]
            parts.append(',"%s":[%s],"%s_rx":%r' % (kind, ",".join(d.decode() for _, _, d in new), kind, new[-1][1]))
        return "".join(parts) + "}"

    def close(self) -> None:
        self.client.close()


class DriveSender:
    """Sends the user's commands to the service's ``drive`` op, one at a time, the latest waiting one next;
    ``done(request, reply, seconds)`` is called on this thread after each (seconds: the query's round trip)."""

    def __init__(self, client: ZenohClient, done: Callable[[dict, dict, float], None]):
        self.client = client
        self.done = done
        self._pending: dict | None = None
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.sent = 0
        self.replaced = 0
        self._thread = threading.Thread(target=self._run, name="rtsim-view-drive", daemon=True)
        self._thread.start()

    def submit(self, request: dict) -> None:
        with self._lock:
            if self._pending is not None:
                self.replaced += 1
            self._pending = request
        self._wake.set()

    def _run(self) -> None:
        while not self._stop.is_set():
            if not self._wake.wait(0.2):
                continue
            with self._lock:
                req, self._pending = self._pending, None
                self._wake.clear()
            if req is None:
                continue
            args = {k: v for k, v in req.items() if k not in ("type", "t_page", "op") and not k.startswith("_")}
            t0 = time.perf_counter()
            try:
                reply = self.client.control("drive", timeout=2.0, **args)
            except RtsimError as exc:
                reply = {"ok": False, "error": str(exc)}
            self.sent += 1
            self.done(req, reply, time.perf_counter() - t0)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        self._thread.join(2.0)


def encode(obj: dict) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)
