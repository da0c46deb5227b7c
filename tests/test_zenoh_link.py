"""The Zenoh link (bridge.zenoh_link): two sessions over tcp/127.0.0.1 on a free port, publish and
subscribe of every kind, control and config queries incl. errors and malformed requests, DROP
congestion control (a blocked subscriber never blocks publish), loopback-only endpoints, and the
sockets a session opens (TCP on 127.0.0.1 only, no UDP: no multicast scouting)."""
from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from bridge.payloads import encode_json, encode_sensors, encode_state
from bridge.zenoh_link import ZenohClient, ZenohLink, check_endpoint, parse_request, zenoh_config
from rtsim.channels import SENSOR_NAMES, STATE_NAMES
from rtsim.errors import RtsimError
from waits import EVENT

VID = "xbw"
ANY_PORT = "tcp/127.0.0.1:0"


def wait_for(pred, timeout=EVENT, what="condition"):
    """Poll ``pred`` (a deadlock guard, not a timing assertion)."""
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} not reached within {timeout} s")
        time.sleep(0.005)


@pytest.fixture
def link():
    lk = ZenohLink(VID, listen=(ANY_PORT,))
    try:
        yield lk
    finally:
        lk.close()


@pytest.fixture
def client(link):
    cl = ZenohClient(VID, connect=link.endpoints)
    try:
        wait_for(lambda: cl.connected, what="client connected")
        yield cl
    finally:
        cl.close()


# ------------------------------------------------------------------------------ endpoints / config

@pytest.mark.parametrize("ep", ["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/localhost:1"])
def test_loopback_endpoints_accepted(ep):
    assert check_endpoint(ep) == ep


@pytest.mark.parametrize("ep,fragment", [
    ("tcp/0.0.0.0:7447", "not 127.0.0.1"),
    ("tcp/[::]:7447", "not 127.0.0.1"),
    ("tcp/192.168.1.20:7447", "not 127.0.0.1"),
    ("tcp/127.0.0.2:7447", "not 127.0.0.1"),
    ("tcp/example.com:7447", "not a loopback address"),
    ("udp/127.0.0.1:7447", "protocol 'udp' refused"),
    ("quic/127.0.0.1:7447", "protocol 'quic' refused"),
    ("tcp/127.0.0.1:7447#iface=eth0", "options"),
    ("tcp/127.0.0.1", "expected HOST:PORT"),
    ("tcp/127.0.0.1:70000", "out of range"),
    ("tcp/127.0.0.1:0", "out of range 1..65535"),      # port 0 only for listening
    ("127.0.0.1:7447", "not a locator"),
])
def test_non_loopback_endpoints_rejected(ep, fragment):
    with pytest.raises(RtsimError, match="allow_remote|not a locator|out of range") as e:
        check_endpoint(ep)
    assert fragment in str(e.value)
    assert check_endpoint(ep, allow_remote=True) == ep if "/" in ep else True


def test_links_and_clients_refuse_remote_endpoints_before_opening():
    with pytest.raises(RtsimError, match="0.0.0.0"):
        ZenohLink(VID, listen=("tcp/0.0.0.0:0",))
    with pytest.raises(RtsimError, match="10.0.0.1"):
        ZenohLink(VID, listen=(ANY_PORT,), connect=("tcp/10.0.0.1:7447",))
    with pytest.raises(RtsimError, match="192.168.0.9"):
        ZenohClient(VID, connect=("tcp/192.168.0.9:7447",))
    with pytest.raises(RtsimError, match="vehicle id"):
        ZenohLink("x/*", listen=(ANY_PORT,))
    with pytest.raises(RtsimError, match="client mode needs a router"):
        zenoh_config(listen=(ANY_PORT,), mode="client")
    with pytest.raises(RtsimError, match="mode 'router'"):
        zenoh_config(mode="router")
    c = zenoh_config(listen=("tcp/192.168.1.20:7447",), connect=("tcp/10.1.1.1:7447",), allow_remote=True)
    assert json.loads(c.get_json("listen/endpoints")) == ["tcp/192.168.1.20:7447"]


def test_config_never_scouts():
    c = zenoh_config(listen=(ANY_PORT,), connect=("tcp/127.0.0.1:7447",))

    def get(key, cfg=c):
        return json.loads(cfg.get_json(key))

    assert get("mode") == "peer"
    assert get("scouting/multicast/enabled") is False
    assert get("scouting/gossip/enabled") is False
    assert get("listen/endpoints") == [ANY_PORT]
    assert get("connect/endpoints") == ["tcp/127.0.0.1:7447"]
    assert get("listen/endpoints", zenoh_config()) == []   # no default tcp/[::]:0 listener
    assert get("mode", zenoh_config(connect=("tcp/127.0.0.1:1",), mode="client")) == "client"


def test_port_zero_reports_the_chosen_port_and_a_busy_port_is_an_error(link):
    (ep,) = link.endpoints
    host, port = ep.rsplit(":", 1)
    assert host == "tcp/127.0.0.1" and 0 < int(port) < 65536
    with pytest.raises(RtsimError, match="cannot open the service .*session.*in use"):
        ZenohLink(VID, listen=(ep,))


# ------------------------------------------------------------------------------ sockets

def _socket_inodes() -> set[str]:
    out = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            out.add(target[8:-1])
    return out


def _addr(hexaddr: str) -> str:
    host, port = hexaddr.split(":")
    if len(host) == 8:
        ip = ".".join(str(b) for b in bytes.fromhex(host)[::-1])
    else:   # IPv6: four little-endian 32-bit words
        words = [bytes.fromhex(host[i:i + 8])[::-1] for i in range(0, 32, 8)]
        raw = b"".join(words)
        ip = ":".join(raw[i:i + 2].hex() for i in range(0, 16, 2))
    return f"{ip}:{int(port, 16)}"


def _inet_sockets() -> dict[str, tuple[str, str, str]]:
    """inode -> (protocol, local address, remote address) for this network namespace."""
    out = {}
    for proto in ("tcp", "tcp6", "udp", "udp6", "raw", "raw6"):
        p = Path("/proc/net") / proto
        if not p.exists():
            continue
        for line in p.read_text().splitlines()[1:]:
            f = line.split()
            out[f[9]] = (proto, _addr(f[1]), _addr(f[2]))
    return out


LOOPBACK = ("127.0.0.1", "0000:0000:0000:0000:0000:0000:0000:0001", "0.0.0.0")


@pytest.mark.skipif(not Path("/proc/self/fd").exists() or not Path("/proc/net/tcp").exists(),
                    reason="needs Linux /proc to list the process's sockets")
def test_sessions_open_only_loopback_tcp_sockets():
    before = _socket_inodes()
    lk = ZenohLink(VID, listen=(ANY_PORT,))
    cl = None
    try:
        cl = ZenohClient(VID, connect=lk.endpoints)
        wait_for(lambda: cl.connected, what="client connected")
        lk.serve(lambda r: {}, lambda: {})
        cl.control("pause", timeout=EVENT)
        table = _inet_sockets()
        new = [table[i] for i in _socket_inodes() - before if i in table]
        assert any(proto.startswith("tcp") for proto, _l, _r in new)
        for proto, local, remote in new:
            assert proto in ("tcp", "tcp6"), f"unexpected {proto} socket {local} (multicast scouting?)"
            assert local.rsplit(":", 1)[0] in LOOPBACK[:2], f"{proto} socket bound to {local}"
            assert remote.rsplit(":", 1)[0] in LOOPBACK, f"{proto} socket connected to {remote}"
    finally:
        if cl is not None:
            cl.close()
        lk.close()


# ------------------------------------------------------------------------------ publish / subscribe

def _payloads(i):
    t = i * 0.002
    sensors = np.arange(len(SENSOR_NAMES)) * 0.5 + i
    state = np.linspace(-1, 1, len(STATE_NAMES)) * (i + 1)
    return {
        "sensors": encode_sensors(t, sensors),
        "state": encode_state(t, state),
        "status": encode_json({"time": t, "steps": i, "message": "hello"}),
        "commands": encode_json({"time": t, "brake_pressure_cmd": 250.0 + i, "source": "zenoh"}),
        "can/rx": encode_json({"id": 0x100, "dlc": 1, "data": f"{i % 256:02x}", "time": t}),
        "can/tx": encode_json({"id": 0x200, "dlc": 0, "data": "", "time": t}),
    }


def test_publish_subscribe_every_kind(link, client):
    from bridge.payloads import TOPIC_KEYS, decode
    got = {k: [] for k in TOPIC_KEYS}
    for k in TOPIC_KEYS:
        client.subscribe(k, got[k].append)
    i = 0
    deadline = time.monotonic() + EVENT
    while not all(got.values()):       # the subscriptions reach the link (milliseconds when quiet)
        for k, b in _payloads(i).items():
            assert link.publish(k, b)
        i += 1
        time.sleep(0.005)
        assert time.monotonic() < deadline, {k: len(v) for k, v in got.items()}
    sent = {k: [decode(_payloads(j)[k]) for j in range(i)] for k in TOPIC_KEYS}
    for k, msgs in got.items():
        first = sent[k].index(msgs[0])
        assert msgs == sent[k][first:first + len(msgs)], k     # same content, in order
    assert got["sensors"][0]["accel_y"] == 0.5 + got["sensors"][0]["time"] / 0.002
    assert link.dropped == 0 and client.errors == 0


def test_bad_payloads_are_counted_by_the_client(link, client):
    got = []
    client.subscribe("status", got.append)
    wait_for(lambda: (link.publish("status", b"not json"), link.publish("status", b'{"ok":1}'),
                      got)[2], what="status received")
    assert got[0] == {"ok": 1}
    assert client.errors >= 1 and "not JSON" in client.last_error
    with pytest.raises(ValueError, match="unknown topic kind"):
        link.publish("nope", b"{}")
    with pytest.raises(ValueError, match="unknown topic kind"):
        client.subscribe("nope", print)


def test_publish_without_subscriber_and_after_close():
    lk = ZenohLink(VID, listen=(ANY_PORT,))
    try:
        assert all(lk.publish("sensors", b'{"time":0}') for _ in range(2000))
        assert lk.dropped == 0
    finally:
        lk.close()
    lk.close()                                  # idempotent
    assert not lk.publish("state", b"{}") and lk.dropped == 1
    with pytest.raises(RtsimError, match="closed"):
        lk.serve(lambda r: r, dict)


def test_blocked_subscriber_does_not_block_publish(link, client):
    gate = threading.Event()
    got = []

    def blocking(msg):
        got.append(msg["i"])
        if msg["i"] >= 0:
            gate.wait(10 * EVENT)               # the subscriber's Zenoh thread hangs here

    client.subscribe("state", blocking)
    wait_for(lambda: (link.publish("state", b'{"i":-1}'), got)[1], what="subscription")
    # stall the subscriber first (its thread now waits on the gate), then flood: under congestion the
    # flood's first message may be dropped too, so it cannot be the one that stalls the subscriber
    wait_for(lambda: (link.publish("state", b'{"i":0}'), max(got) >= 0)[1], what="stalled subscriber")
    pad = "x" * 4000
    n = 5000                                    # 20 MB: more than the TCP buffers and queues hold
    done = []

    def publish_all():
        done.append(sum(link.publish("state", b'{"i":%d,"pad":"%s"}' % (i, pad.encode()))
                        for i in range(n)))

    th = threading.Thread(target=publish_all, daemon=True)
    try:
        th.start()
        th.join(2 * EVENT)                      # deadlock guard: with BLOCK this would hang
        assert not th.is_alive(), "publish blocked behind a stalled subscriber"
        assert not gate.is_set() and max(got) >= 0        # the subscriber was stalled all along
    finally:
        gate.set()
        th.join(EVENT)
    assert done == [n]                          # every put was accepted by Zenoh ...
    marker = n + 1
    wait_for(lambda: (link.publish("state", b'{"i":%d}' % marker), marker in got)[1],
             what="delivery after the subscriber resumed")
    delivered = [i for i in got if 0 <= i < n]
    assert len(delivered) < n                   # ... and the congested ones were dropped
    assert delivered == sorted(delivered)       # what arrived is in order


# ------------------------------------------------------------------------------ queries

def test_parse_request():
    assert parse_request(b'{"op": "step", "n": 3}') == {"op": "step", "n": 3}
    assert parse_request(None, [("op", "step"), ("n", "10"), ("name", "straight_line"),
                                ("dt", "0.5")]) == {"op": "step", "n": 10, "name": "straight_line",
                                                    "dt": 0.5}
    assert parse_request(b'{"n": 2}', [("op", "step"), ("n", "1")]) == {"op": "step", "n": 2}
    for bad, msg in ((b"", "without 'op'"), (b'{"op": "fly"}', "unknown control op 'fly'"),
                     (b"{broken", "not JSON"), (b"[1]", "not an object")):
        with pytest.raises(RtsimError, match=msg):
            parse_request(bad)


def test_control_round_trip_and_errors(link, client):
    seen = []

    def handler(req):
        seen.append(req)
        if req["op"] == "load_scenario" and req.get("name") == "missing":
            raise FileNotFoundError("no scenario 'missing'")
        if req["op"] == "reset":
            return ["not", "a", "dict"]
        return {"sim_time": 1.25, "op": req["op"], "n": req.get("n")}

    link.serve(handler, lambda: {"vehicle_id": VID, "dt": 0.002, "inf": float("inf")})
    assert client.control("step", n=10, timeout=EVENT) == {"ok": True, "sim_time": 1.25, "op": "step",
                                                           "n": 10}
    assert seen[-1] == {"op": "step", "n": 10}
    r = client.control("load_scenario", name="missing", timeout=EVENT)
    assert r == {"ok": False, "error": "FileNotFoundError: no scenario 'missing'"}
    r = client.control("reset", timeout=EVENT)
    assert r["ok"] is False and "returned list" in r["error"]
    r = client.control("explode", timeout=EVENT)
    assert r["ok"] is False and "unknown control op 'explode'" in r["error"]
    n_calls = len(seen)
    # raw queries: selector parameters, malformed payloads, no op
    from bridge.payloads import decode
    s = client._session

    def raw(selector, payload=None):
        replies = list(s.get(selector, payload=payload, timeout=EVENT))
        assert len(replies) == 1 and replies[0].ok is not None
        return decode(replies[0].ok.payload.to_bytes())

    assert raw(f"rtsim/{VID}/control?op=step;n=7") == {"ok": True, "sim_time": 1.25, "op": "step", "n": 7}
    assert seen[-1] == {"op": "step", "n": 7}
    assert raw(f"rtsim/{VID}/control?op=pause") ["ok"] is True
    for payload, msg in ((b"{not json", "not JSON"), (b"[1,2]", "not an object"), (b"\xff", "not JSON"),
                         (None, "without 'op'")):
        r = raw(f"rtsim/{VID}/control", payload)
        assert r["ok"] is False and msg in r["error"]
    assert len(seen) == n_calls + 2             # malformed requests never reached the handler
    assert client.control("resume", timeout=EVENT)["ok"] is True     # still serving
    assert client.config(timeout=EVENT) == {"vehicle_id": VID, "dt": 0.002, "inf": None}
    with pytest.raises(RtsimError, match="twice"):
        link.serve(handler, dict)


def test_control_handler_calls_are_serialised(link, client):
    busy = threading.Lock()
    overlaps = []

    def handler(req):
        if not busy.acquire(blocking=False):
            overlaps.append(req)
            return {}
        try:
            time.sleep(0.02)
            return {"i": req["i"]}
        finally:
            busy.release()

    link.serve(handler, dict)
    clients = [ZenohClient(VID, connect=link.endpoints) for _ in range(3)]
    results = []
    try:
        ths = [threading.Thread(target=lambda c=c, k=k: results.extend(
            c.control("step", timeout=EVENT, i=10 * k + j) for j in range(4))) for k, c in enumerate(clients)]
        for t in ths:
            t.start()
        for t in ths:
            t.join(2 * EVENT)
    finally:
        for c in clients:
            c.close()
    assert overlaps == [] and sorted(r["i"] for r in results) == sorted(10 * k + j for k in range(3)
                                                                        for j in range(4))


def test_config_provider_error_and_no_service(link, client):
    def broken():
        raise RuntimeError("config not loaded")

    link.serve(lambda r: {}, broken)
    assert client.config(timeout=EVENT) == {"ok": False, "error": "RuntimeError: config not loaded"}
    other = ZenohClient("other_car", connect=link.endpoints)
    try:
        with pytest.raises(RtsimError, match="no reply within 0.3 s.*other_car"):
            other.control("pause", timeout=0.3)
    finally:
        other.close()
