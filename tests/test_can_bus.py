"""bridge.can_bus: the bus factory and the python-can-remote loopback hub (127.0.0.1 only).

Every test is bounded: receives use timeouts inside deadline loops (generous bounds on the waits,
never criteria: tests/waits.py), child processes are killed and joined in ``finally``, hubs are closed
by their context manager. python-can and python-can-remote are hard dependencies, and a hub that
cannot start on 127.0.0.1 is a failure, not a skip. Run with ``-s`` to see the measured round trip and
throughput through the hub (printed, never asserted: speed is ``rtsim bench``'s). The ``can_e2e`` test
runs over the ``can_bus_factory`` segment (tests/conftest.py): the hub here, SocketCAN vcan0 when
RTSIM_CAN_INTERFACE/RTSIM_CAN_CHANNEL say so (tests/test_vcan.py does that inside a qemu VM).
"""
from __future__ import annotations

import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import can
import pytest

from bridge.can_bus import LoopbackHub, open_bus
from rtsim.errors import RtsimError
from waits import EVENT, HUB_START, PROCESS

ROOT = Path(__file__).resolve().parent.parent


def _start_hub(**kw) -> LoopbackHub:
    return LoopbackHub(start_timeout=HUB_START, **kw)


def _recv_n(bus, n: int, deadline_s: float) -> list:
    out = []
    deadline = time.monotonic() + deadline_s
    while len(out) < n and time.monotonic() < deadline:
        msg = bus.recv(0.2)
        if msg is not None:
            out.append(msg)
    return out


def _frames(n: int, base_id: int) -> list:
    return [can.Message(arbitration_id=base_id + (i % 64), is_extended_id=False,
                        data=i.to_bytes(4, "little") + bytes((i % 256, 0xA5, (i * 7) % 256, i % 9))[: 1 + i % 4])
            for i in range(n)]


def _same(a, b) -> bool:
    return (a.arbitration_id == b.arbitration_id and bytes(a.data) == bytes(b.data)
            and a.is_extended_id == b.is_extended_id and a.dlc == b.dlc)


# --------------------------------------------------------------------------------------------------
# (a) two buses through one hub, both ways, lossless and in order; timing printed

@pytest.mark.parametrize("mode", ["subprocess", "thread"])
def test_two_buses_through_hub_lossless_both_ways(mode):
    n = 1000
    with _start_hub(mode=mode) as hub:
        a = hub.open_bus()
        b = hub.open_bus()
        try:
            for src, dst, base in ((a, b, 0x100), (b, a, 0x200)):
                sent = _frames(n, base)
                t0 = time.perf_counter()
                for m in sent:
                    src.send(m)
                got = _recv_n(dst, n, EVENT)
                dt = time.perf_counter() - t0
                assert len(got) == n, f"{len(got)} of {n} frames arrived"
                bad = [i for i, (s, r) in enumerate(zip(sent, got)) if not _same(s, r)]
                assert not bad, f"frames out of order or altered from index {bad[0]}"
                assert src.recv(0.05) is None, "the sender must not receive its own frames"
                print(f"\n[hub {mode}] {n} frames one way: {dt * 1e3:.1f} ms, {n / dt:,.0f} frames/s")

            # round trip: a -> hub -> b, b echoes -> hub -> a
            rtt = []
            ping = can.Message(arbitration_id=0x300, data=bytes(8), is_extended_id=False)
            for i in range(300):
                t0 = time.perf_counter()
                a.send(ping)
                m = b.recv(EVENT)
                assert m is not None
                b.send(m)
                assert a.recv(EVENT) is not None
                rtt.append(time.perf_counter() - t0)
            rtt.sort()
            print(f"[hub {mode}] round trip a->b->a: p50 {statistics.median(rtt) * 1e3:.3f} ms, "
                  f"p99 {rtt[int(0.99 * len(rtt))] * 1e3:.3f} ms, max {rtt[-1] * 1e3:.3f} ms")
        finally:
            a.shutdown()
            b.shutdown()


# --------------------------------------------------------------------------------------------------
# (b) end to end across processes: ECU child -> CAN segment (hub or vcan0) -> CommandReceiver here

_CHILD = r"""
import argparse, time, can
from bridge.can_bus import open_bus
from bridge.can_codec import Codec
ap = argparse.ArgumentParser()
ap.add_argument("--can-interface", required=True)
ap.add_argument("--can-channel", required=True)
ap.add_argument("-n", type=int, required=True)
args = ap.parse_args()
n = args.n
codec = Codec()
bus = open_bus(args.can_interface, args.can_channel)
def send(fid, data):
    bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False))
bad_crc = bad_dlc = 0
t_next = time.monotonic()
for i in range(n):
    fid, data = codec.encode_command("THROTTLE_CMD", (i % 140) * 0.01, i % 16)
    send(fid, data)
    if i % 10 == 3:    # corrupted copy: a flipped bit in the value bytes, CRC left as is
        send(fid, bytes((data[0] ^ 0x04,)) + data[1:]); bad_crc += 1
    if i % 25 == 7:    # truncated frame
        send(fid, data[:7]); bad_dlc += 1
    t_next += 0.010
    time.sleep(max(0.0, t_next - time.monotonic()))
send(0x7FF, bytes((bad_crc, bad_dlc)))   # end marker with the number of corrupted frames sent
time.sleep(0.2)
bus.shutdown()
"""


@pytest.mark.can_e2e
def test_end_to_end_child_process_commands_over_can(can_bus_factory):
    """An ECU in a child process sends commands over the test's CAN segment (the loopback hub, or
    SocketCAN vcan0 when RTSIM_CAN_INTERFACE says so, e.g. inside tests/test_vcan.py's VM)."""
    from bridge.can_codec import CommandReceiver

    n = 200
    rx_bus = can_bus_factory()  # connected before the child starts: nothing can be missed
    rx = CommandReceiver()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    child = subprocess.Popen([sys.executable, "-c", _CHILD, *can_bus_factory.child_args(), "-n", str(n)],
                             cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    values = []
    marker = None
    try:
        deadline = time.monotonic() + PROCESS
        while marker is None and time.monotonic() < deadline:
            msg = rx_bus.recv(0.2)
            if msg is None:
                if child.poll() not in (None, 0):
                    break
                continue
            if msg.arbitration_id == 0x7FF:
                marker = bytes(msg.data)
                continue
            # every frame at one time, not its arrival time: a late delivery on a loaded machine must not
            # time the command out and make the receiver re-synchronise (time-outs: tests/test_can_e2e.py)
            if rx.receive(msg.arbitration_id, bytes(msg.data), 0.0):
                values.append(rx.value[rx.names.index("throttle_angle_cmd")])
    finally:
        if child.poll() is None:
            try:
                child.wait(EVENT)
            except subprocess.TimeoutExpired:
                child.kill()
        try:
            out, err = child.communicate(timeout=EVENT)
        except subprocess.TimeoutExpired:
            child.kill()
            out, err = child.communicate(timeout=EVENT)
        rx_bus.shutdown()
    assert marker is not None, f"no end marker from the child (rc {child.returncode}): {err.decode()[-800:]}"
    assert child.returncode == 0, err.decode()[-800:]
    bad_crc, bad_dlc = marker[0], marker[1]
    assert (bad_crc, bad_dlc) == (20, 8)
    assert rx.accepted == n
    assert values == pytest.approx([(i % 140) * 0.01 for i in range(n)], abs=1e-4)
    assert rx.counters["crc"] == bad_crc
    assert rx.counters["dlc"] == bad_dlc
    assert rx.counters["counter"] == 0 and rx.counters["range"] == 0 and rx.counters["unknown_id"] == 0


@pytest.mark.can_e2e
def test_segment_two_buses_classic_and_fd_lossless_both_ways(can_bus_factory):
    """Two buses on the test's CAN segment (hub or vcan0): classic and CAN FD frames (64 bytes, bit
    rate switch, extended ids), sent in bursts of 50, arrive complete, in order and unaltered both ways,
    the sender does not get its own frames back; the round trip a -> b -> a is printed (not asserted)."""
    a = can_bus_factory(fd=True)
    b = can_bus_factory(fd=True)
    n = 200
    for src, dst, base in ((a, b, 0x100), (b, a, 0x1ABC000)):
        sent = _frames(n, base & 0x7FF)
        sent += [can.Message(arbitration_id=base + i, is_extended_id=True, is_fd=True, bitrate_switch=bool(i % 2),
                             data=bytes((i + k) % 256 for k in range(64 if i % 3 else 12))) for i in range(n)]
        got = []
        for k in range(0, len(sent), 50):  # bursts of 50: a SocketCAN receiver that is not reading
            for m in sent[k: k + 50]:       # drops what overflows its socket buffer (~280 frames)
                src.send(m)
            got += _recv_n(dst, min(50, len(sent) - k), EVENT)
        assert len(got) == len(sent), f"{len(got)} of {len(sent)} frames arrived"
        bad = [i for i, (s, r) in enumerate(zip(sent, got))
               if not (_same(s, r) and s.is_fd == r.is_fd and s.bitrate_switch == r.bitrate_switch)]
        assert not bad, f"frames out of order or altered from index {bad[0]}: {sent[bad[0]]} -> {got[bad[0]]}"
        assert src.recv(0.05) is None, "the sender must not receive its own frames"
    rtt = []
    ping = can.Message(arbitration_id=0x300, data=bytes(8), is_extended_id=False)
    for _ in range(100):
        t0 = time.perf_counter()
        a.send(ping)
        m = b.recv(EVENT)
        assert m is not None
        b.send(m)
        assert a.recv(EVENT) is not None
        rtt.append(time.perf_counter() - t0)
    rtt.sort()
    print(f"\n[{can_bus_factory.interface} {can_bus_factory.channel}] round trip a->b->a: "
          f"p50 {statistics.median(rtt) * 1e3:.3f} ms, p99 {rtt[98] * 1e3:.3f} ms, max {rtt[-1] * 1e3:.3f} ms")


# --------------------------------------------------------------------------------------------------
# (c) open_bus: explicit interface, errors

def test_open_bus_explicit_virtual():
    a = open_bus("virtual", "rtsim-test-open-bus")
    b = open_bus(interface="virtual", channel="rtsim-test-open-bus")
    try:
        a.send(can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False))
        m = b.recv(EVENT)
        assert m is not None and m.arbitration_id == 0x123 and bytes(m.data) == b"\x01\x02"
    finally:
        a.shutdown()
        b.shutdown()


def test_open_bus_bad_interface_is_one_line_rtsim_error():
    with pytest.raises(RtsimError) as ei:
        open_bus("no_such_iface", "x")
    msg = str(ei.value)
    assert "\n" not in msg and "no_such_iface" in msg and "expected one of" in msg


def test_open_bus_unreachable_hub_is_one_line_rtsim_error():
    with _start_hub(mode="thread") as hub:
        channel = hub.channel
    # the hub is closed: its port refuses connections now
    with pytest.raises(RtsimError) as ei:
        open_bus("remote", channel)
    msg = str(ei.value)
    assert "\n" not in msg and channel in msg and "not reachable" in msg and "LoopbackHub" in msg


def test_open_bus_socketcan_missing_device_is_rtsim_error():
    with pytest.raises(RtsimError) as ei:
        open_bus("socketcan", "rtsimnodev0")
    assert "\n" not in str(ei.value) and "rtsimnodev0" in str(ei.value)


# --------------------------------------------------------------------------------------------------
# (d) the hub listens on 127.0.0.1 only; close is idempotent and stops it

def _listeners(port: int) -> list[str] | None:
    """Local addresses of the LISTEN sockets on ``port`` in this network namespace (/proc/net/tcp*)."""
    found = []
    any_file = False
    for path, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        try:
            lines = Path(path).read_text().splitlines()[1:]
        except OSError:
            continue
        any_file = True
        for line in lines:
            f = line.split()
            addr_hex, port_hex = f[1].split(":")
            if f[3] != "0A" or int(port_hex, 16) != port:
                continue
            if width == 8:
                found.append(".".join(str(b) for b in reversed(bytes.fromhex(addr_hex))))
            else:
                found.append("v6:" + addr_hex)
    return found if any_file else None


@pytest.mark.parametrize("mode", ["subprocess", "thread"])
def test_hub_listens_on_loopback_only_and_closes(mode):
    hub = _start_hub(mode=mode)
    try:
        assert hub.address[0] == "127.0.0.1" and hub.channel == f"127.0.0.1:{hub.port}"
        listeners = _listeners(hub.port)
        if listeners is None:
            print("no /proc/net/tcp here: only the bound address was checked")
        else:
            assert listeners == ["127.0.0.1"], f"listening sockets on port {hub.port}: {listeners}"
        assert hub.alive()
        pid = hub.pid
    finally:
        hub.close()
    hub.close()  # idempotent
    assert not hub.alive()
    if mode == "subprocess":
        assert not Path(f"/proc/{pid}").exists() or "zombie" in Path(f"/proc/{pid}/status").read_text()
    listeners = _listeners(hub.port)
    assert not listeners, f"port {hub.port} still listening after close: {listeners}"
