"""Zenoh side of the HIL service: publishes ``rtsim/<vehicle_id>/<kind>`` and answers control/config
queries; :class:`ZenohClient` is the observer side (``rtsim watch``, tests, the demo ECU).

Network policy (Zenoh's defaults would send UDP multicast off the machine): every session is built by
:func:`zenoh_config`: peer mode (client when given a router), multicast and gossip scouting off,
explicit endpoints only, and only ``tcp`` on 127.0.0.1 / ::1 / localhost unless ``allow_remote=True``
(a real bench passes its router's endpoint explicitly).

Threads: subscriber callbacks and the control/config handlers run on Zenoh's own threads, never on
the caller's. Keep them short and thread-safe; control handler calls are serialised by a lock (one at
a time), config_provider calls are not.

Payloads are the JSON of bridge.payloads; keys: ``rtsim/<vid>/sensors|state|status|commands|can/rx|
can/tx`` (published), ``rtsim/<vid>/control`` and ``rtsim/<vid>/config`` (queryables).
"""
from __future__ import annotations

import ipaddress
import json
import re
import threading
import time
from typing import Any, Callable, Iterable

import zenoh

from bridge.payloads import TOPIC_KEYS, decode, encode_json
from rtsim.errors import RtsimError

CONTROL_OPS = ("reset", "pause", "resume", "load_scenario", "step", "driver", "drive", "inject_fault", "clear_fault")
DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
_VID = re.compile(r"[A-Za-z0-9_\-]+\Z")
_LOOPBACK_NAMES = ("localhost",)
_JSON = zenoh.Encoding.APPLICATION_JSON
#: control requests: numpy values made plain, NaN and infinity kept as literals (the service refuses them)
def _plain(obj):
    if hasattr(obj, "tolist"):          # numpy scalars and arrays
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


_CONTROL_ENCODER = json.JSONEncoder(allow_nan=True, separators=(",", ":"), default=_plain).encode


def _zerr(e: BaseException) -> str:
    """Zenoh's error text without the Rust source location."""
    return str(e).split(" at /", 1)[0].strip()


def _check_vehicle_id(vehicle_id: str) -> str:
    if not isinstance(vehicle_id, str) or not _VID.match(vehicle_id):
        raise RtsimError(f"vehicle id {vehicle_id!r} must be letters, digits, '_' or '-' "
                         "(it is a Zenoh key-expression chunk)")
    return vehicle_id


def check_endpoint(endpoint: str, allow_remote: bool = False, listen: bool = False) -> str:
    """Return ``endpoint`` if it is ``tcp/<loopback host>:<port>`` (host 127.0.0.1, [::1] or
    localhost; port 0 = any free port, for listening only); raise RtsimError otherwise. With
    ``allow_remote`` any ``proto/address`` locator passes (the caller chose a remote router)."""
    if not isinstance(endpoint, str) or "/" not in endpoint or not endpoint.split("/", 1)[1]:
        raise RtsimError(f"zenoh endpoint {endpoint!r} is not a locator like {DEFAULT_ENDPOINT}")
    if allow_remote:
        return endpoint
    proto, addr = endpoint.split("/", 1)
    where = f"zenoh endpoint {endpoint!r}"
    hint = "; only tcp on 127.0.0.1, [::1] or localhost is allowed unless allow_remote=True"
    if proto != "tcp":
        raise RtsimError(f"{where}: protocol {proto!r} refused{hint}")
    if "?" in addr or "#" in addr:
        raise RtsimError(f"{where}: endpoint options ('?', '#') refused{hint}")
    m = re.fullmatch(r"\[([^\]]+)\]:(\d+)|([^:\[\]]+):(\d+)", addr)
    if not m:
        raise RtsimError(f"{where}: expected HOST:PORT{hint}")
    host, port = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
    if host not in _LOOPBACK_NAMES:
        try:
            ip = ipaddress.ip_address(host)
        except ValueError:
            raise RtsimError(f"{where}: host {host!r} is not a loopback address{hint}") from None
        if str(ip) not in ("127.0.0.1", "::1"):
            raise RtsimError(f"{where}: host {host!r} is not 127.0.0.1 or ::1{hint}")
    port = int(port)
    if not (0 if listen else 1) <= port <= 65535:
        raise RtsimError(f"{where}: port {port} out of range {0 if listen else 1}..65535")
    return endpoint


def zenoh_config(listen: Iterable[str] = (), connect: Iterable[str] = (), mode: str = "peer",
                 allow_remote: bool = False, drop_wait: float = 1e-4,
                 adminspace: bool = False) -> zenoh.Config:
    """A Zenoh config that never scouts: ``mode`` "peer" (or "client" to use a router given in
    ``connect``), multicast and gossip scouting off, exactly these endpoints (checked by
    :func:`check_endpoint`). ``drop_wait`` (s): how long a congestion-control-DROP publication may
    wait for room in a full transmit queue before it is dropped (Zenoh's default is 1 ms).
    ``adminspace`` exposes the read-only admin space (used to learn the port chosen for port 0)."""
    listen, connect = list(listen), list(connect)
    if mode not in ("peer", "client"):
        raise RtsimError(f"zenoh mode {mode!r} not allowed; use 'peer' or 'client'")
    if mode == "client" and (listen or not connect):
        raise RtsimError("zenoh client mode needs a router in connect and no listen endpoints")
    if not (0 <= drop_wait <= 1):
        raise RtsimError(f"zenoh drop_wait {drop_wait} s out of range 0..1 s")
    for e in listen:
        check_endpoint(e, allow_remote, listen=True)
    for e in connect:
        check_endpoint(e, allow_remote)
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("listen/endpoints", json.dumps(listen))
    c.insert_json5("connect/endpoints", json.dumps(connect))
    c.insert_json5("transport/link/tx/queue/congestion_control/drop/wait_before_drop",
                   str(int(round(drop_wait * 1e6))))
    c.insert_json5("adminspace/enabled", "true" if adminspace else "false")
    c.insert_json5("adminspace/permissions", '{"read": true, "write": false}')
    return c


def _open(config: zenoh.Config, what: str) -> zenoh.Session:
    try:
        return zenoh.open(config)
    except zenoh.ZError as e:
        raise RtsimError(f"zenoh: cannot open the {what} session: {_zerr(e)}") from None


def _param_value(text: str):
    """Selector parameter text -> JSON value when it parses (10, 0.5, true), else the string."""
    try:
        return json.loads(text)
    except ValueError:
        return text


def parse_request(payload: bytes | None, parameters: Iterable[tuple[str, str]] = (),
                  ops: Iterable[str] = CONTROL_OPS) -> dict:
    """The request dict of a control query: selector parameters (``op=step;n=10``, values parsed as
    JSON when possible) overlaid by a JSON-object payload. Raises RtsimError when malformed."""
    req = {k: _param_value(v) for k, v in parameters}
    if payload:
        req.update(decode(payload))
    op = req.get("op")
    ops = tuple(ops)
    if op is None:
        raise RtsimError(f"control request without 'op'; allowed: {', '.join(ops)}")
    if op not in ops:
        raise RtsimError(f"unknown control op {op!r}; allowed: {', '.join(ops)}")
    return req


class ZenohLink:
    """Service side: publishers for every topic kind and the control/config queryables.

    ``publish`` never blocks on a slow or absent subscriber (congestion control DROP); a publication
    Zenoh refuses (session closed, error) is counted in :attr:`dropped`. Messages Zenoh drops inside
    its transmit queue under congestion are not reported by Zenoh and so are not counted.
    """

    def __init__(self, vehicle_id: str, listen: Iterable[str] = (DEFAULT_ENDPOINT,),
                 connect: Iterable[str] = (), mode: str = "peer", allow_remote: bool = False,
                 drop_wait: float = 1e-4):
        self.vehicle_id = _check_vehicle_id(vehicle_id)
        self._listen = list(listen)
        needs_port = any(e.rsplit(":", 1)[-1] == "0" for e in self._listen)
        self._mode = mode
        cfg = zenoh_config(self._listen, connect, mode, allow_remote, drop_wait, adminspace=needs_port)
        self._session = _open(cfg, f"service (listen {self._listen or '-'}, "
                                   f"connect {list(connect) or '-'})")
        self.dropped = 0
        self._closed = False
        self._lock = threading.Lock()           # close vs. serve
        self._handler_lock = threading.Lock()   # control handler calls, one at a time
        self._queryables: list = []
        self._endpoints = self._resolve_endpoints() if needs_port else list(self._listen)
        try:
            self._pubs = {k: self._session.declare_publisher(
                self.key(k), encoding=_JSON, congestion_control=zenoh.CongestionControl.DROP)
                for k in TOPIC_KEYS}
        except zenoh.ZError as e:
            self._session.close()
            raise RtsimError(f"zenoh: cannot declare publishers: {_zerr(e)}") from None

    def key(self, kind: str) -> str:
        return f"rtsim/{self.vehicle_id}/{kind}"

    def _resolve_endpoints(self) -> list[str]:
        zid = str(self._session.zid())
        try:
            for reply in self._session.get(f"@/{zid}/{self._mode}", timeout=2.0):
                if reply.ok is not None:
                    return list(json.loads(reply.ok.payload.to_bytes()).get("locators", []))
        except (zenoh.ZError, ValueError) as e:
            self._session.close()
            raise RtsimError(f"zenoh: cannot read the listening endpoints: {_zerr(e)}") from None
        self._session.close()
        raise RtsimError("zenoh: the admin space did not report the listening endpoints")

    @property
    def endpoints(self) -> list[str]:
        """Locators actually listened on (the chosen port when 0 was requested)."""
        return list(self._endpoints)

    # ------------------------------------------------------------------------------ publishing
    def publish(self, kind: str, payload: bytes) -> bool:
        """Publish one encoded JSON message on ``rtsim/<vid>/<kind>``; never blocks on subscribers.
        Returns False (and counts it in ``dropped``) when Zenoh refused it or the link is closed."""
        pub = self._pubs.get(kind)
        if pub is None:
            raise ValueError(f"unknown topic kind {kind!r}; allowed: {', '.join(TOPIC_KEYS)}")
        if self._closed:
            self.dropped += 1
            return False
        try:
            pub.put(payload)
        except Exception:      # ZError after close, or a payload Zenoh cannot take
            self.dropped += 1
            return False
        return True

    # ------------------------------------------------------------------------------ queries
    def serve(self, control_handler: Callable[[dict], dict], config_provider: Callable[[], Any],
              ops: Iterable[str] = CONTROL_OPS) -> None:
        """Declare the ``control`` and ``config`` queryables.

        ``control_handler(request) -> dict`` gets ``{"op": ..., **args}`` with ``op`` in ``ops``;
        its result is replied as JSON (with ``"ok": true`` added unless it sets ``ok``). A malformed
        request or a handler exception is replied as ``{"ok": false, "error": "..."}``.
        ``config_provider()`` returns the JSON-able configuration replied on ``config``.
        Both run on Zenoh's threads (see the module docstring)."""
        ops = tuple(ops)
        ctl_key, cfg_key = self.key("control"), self.key("config")

        def on_control(query):
            try:
                req = parse_request(query.payload.to_bytes() if query.payload else None,
                                    list(query.parameters), ops)
                with self._handler_lock:
                    res = control_handler(req)
                if not isinstance(res, dict):
                    raise RtsimError(f"control handler returned {type(res).__name__}, not a dict")
                body = encode_json({"ok": True, **res})
            except Exception as e:
                msg = str(e) if isinstance(e, RtsimError) else f"{type(e).__name__}: {e}"
                body = encode_json({"ok": False, "error": msg})
            self._reply(query, ctl_key, body)

        def on_config(query):
            try:
                body = encode_json(config_provider())
            except Exception as e:
                body = encode_json({"ok": False, "error": f"{type(e).__name__}: {e}"})
            self._reply(query, cfg_key, body)

        with self._lock:
            if self._closed:
                raise RtsimError("zenoh link is closed")
            if self._queryables:
                raise RtsimError("ZenohLink.serve called twice")
            try:
                self._queryables = [self._session.declare_queryable(ctl_key, on_control),
                                    self._session.declare_queryable(cfg_key, on_config)]
            except zenoh.ZError as e:
                raise RtsimError(f"zenoh: cannot declare queryables: {_zerr(e)}") from None

    @staticmethod
    def _reply(query, key: str, body: bytes) -> None:
        try:
            query.reply(key, body, encoding=_JSON)
        except Exception:      # the querier left or the session closed: nothing to tell
            pass

    # ------------------------------------------------------------------------------ closing
    def close(self) -> None:
        """Undeclare everything and close the session. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            for q in self._queryables:
                try:
                    q.undeclare()
                except Exception:
                    pass
            self._session.close()

    def __enter__(self) -> "ZenohLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ZenohClient:
    """Observer side: subscribe to a service's topics, send control requests, read its config.

    Callbacks run on Zenoh's threads and get the decoded dict; payloads that are not JSON objects
    and callback exceptions are counted in :attr:`errors` (text of the last in :attr:`last_error`)
    instead of reaching Zenoh."""

    def __init__(self, vehicle_id: str, connect: Iterable[str] = (DEFAULT_ENDPOINT,),
                 mode: str = "peer", allow_remote: bool = False):
        self.vehicle_id = _check_vehicle_id(vehicle_id)
        self.connect = list(connect)
        if not self.connect:
            raise RtsimError("ZenohClient needs at least one endpoint to connect to")
        self._session = _open(zenoh_config((), self.connect, mode, allow_remote),
                              f"observer (connect {self.connect})")
        self._subs: list = []
        self.errors = 0
        self.last_error: str | None = None
        self._closed = False
        self._lock = threading.Lock()

    def key(self, kind: str) -> str:
        return f"rtsim/{self.vehicle_id}/{kind}"

    @property
    def connected(self) -> bool:
        """True when a Zenoh peer or router is connected (the service, normally)."""
        info = self._session.info
        return bool(info.peers_zid() or info.routers_zid())

    def subscribe(self, kind: str, callback: Callable[[dict], Any], raw: bool = False) -> None:
        """Call ``callback(message_dict)`` for every message on ``rtsim/<vid>/<kind>`` (``raw``: the
        payload's JSON bytes as they came, undecoded: for a relay that only forwards them)."""
        if kind not in TOPIC_KEYS:
            raise ValueError(f"unknown topic kind {kind!r}; allowed: {', '.join(TOPIC_KEYS)}")

        def on_sample(sample):
            try:
                data = sample.payload.to_bytes()
                callback(data if raw else decode(data))
            except Exception as e:
                self.errors += 1
                self.last_error = f"{kind}: {type(e).__name__}: {e}"

        with self._lock:
            if self._closed:
                raise RtsimError("zenoh client is closed")
            self._subs.append(self._session.declare_subscriber(self.key(kind), on_sample))

    def _query(self, kind: str, payload: bytes | None, timeout: float) -> dict:
        if not timeout > 0:
            raise RtsimError(f"timeout must be positive, got {timeout}")
        key = self.key(kind)
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            try:
                replies = self._session.get(key, payload=payload, encoding=_JSON, timeout=left)
                for reply in replies:
                    if reply.ok is not None:
                        return decode(reply.ok.payload.to_bytes())
                    raise RtsimError(f"{key}: error reply: {reply.err.payload.to_bytes()!r}")
            except zenoh.ZError as e:
                raise RtsimError(f"{key}: query failed: {_zerr(e)}") from None
            # no reply at all: no queryable known yet (still connecting) -> ask again until timeout
            time.sleep(min(0.02, max(0.0, deadline - time.monotonic())))
        raise RtsimError(f"{key}: no reply within {timeout:g} s (is `rtsim serve` running for "
                         f"vehicle {self.vehicle_id!r} and reachable at {', '.join(self.connect)}?)")

    def control(self, op: str, timeout: float = 10.0, **args) -> dict:
        """Send ``{"op": op, **args}`` to ``rtsim/<vid>/control``; returns the reply dict (check
        ``reply["ok"]``). Raises RtsimError when no service answers within ``timeout`` s. A non-finite
        number goes as JSON's NaN/Infinity literal (never as null, which would mean "hand back"), so that
        the service refuses it with its reason."""
        return self._query("control", _CONTROL_ENCODER({"op": op, **args}).encode(), timeout)

    def config(self, timeout: float = 10.0) -> dict:
        """The service's configuration (reply of ``rtsim/<vid>/config``)."""
        return self._query("config", None, timeout)

    def close(self) -> None:
        """Undeclare the subscribers and close the session. Idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            for s in self._subs:
                try:
                    s.undeclare()
                except Exception:
                    pass
            self._session.close()

    def __enter__(self) -> "ZenohClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
