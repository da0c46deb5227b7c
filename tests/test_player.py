"""bridge.player: session playback onto the bus (``rtsim play``).

Timing is checked on FakeClock (deterministic: the expected send times are the recording's times
divided by the rate, anchored at the start), never against the wall clock. Over a real
python-can-remote LoopbackHub (127.0.0.1) with two clients the test asserts content and order only.
"""
from __future__ import annotations

import argparse
import io
import socket
import time

import can
import pytest

from bridge.can_logs import Frame, write_frames
from bridge.player import Player, add_arguments, main, median_interval, parse_ids
from rtsim.errors import RtsimError
from rtsim.realtime.clock import FakeClock
from waits import EVENT, HUB_START


class FakeBus:
    """Records (clock time, id, data) of every send; ``cost`` s of clock time per send; ``fail(k,
    attempt)`` -> True makes attempt ``attempt`` of the ``k``-th frame raise a CanError."""

    def __init__(self, clock, cost=0.0, fail=None, on_send=None):
        self.clock, self.cost, self.fail, self.on_send = clock, cost, fail, on_send
        self.sent = []
        self.attempts = 0
        self._attempt_of = {}

    def send(self, msg, timeout=None):
        self.attempts += 1
        k = len(self.sent)
        a = self._attempt_of.get(k, 0)
        self._attempt_of[k] = a + 1
        if self.fail is not None and self.fail(k, a):
            raise can.CanOperationError(f"bus off (frame {k}, attempt {a})")
        if self.cost:
            self.clock.advance(self.cost)
        now = self.clock.now() if self.clock is not None else time.monotonic()
        self.sent.append((now, msg.arbitration_id, bytes(msg.data)))
        if self.on_send is not None:
            self.on_send(len(self.sent))


def _frames(times, base=0x100):
    return [Frame(t, base + i % 5, bytes((i % 256, (7 * i) % 256)), "tx") for i, t in enumerate(times)]


IRREGULAR = [0.0, 0.0, 0.0013, 0.002, 0.0107, 0.0107, 0.0301, 0.0302, 0.5, 0.75]


# --------------------------------------------------------------------------------------------------
# schedule on FakeClock

@pytest.mark.parametrize("rate", [1.0, 4.0, 0.5])
def test_exact_schedule_and_rate(rate):
    clock = FakeClock(start=100.0)
    bus = FakeBus(clock)
    frames = _frames([t + 3.0 for t in IRREGULAR])            # offsets are what counts, not the origin
    st = Player(frames, bus, rate=rate, clock=clock).run()
    assert [s[0] for s in bus.sent] == pytest.approx([100.0 + t / rate for t in IRREGULAR], abs=1e-12)
    assert [(s[1], s[2]) for s in bus.sent] == [(f.can_id, f.data) for f in frames]
    assert (st.sent, st.loops, st.late, st.send_errors, st.dropped, st.ended) == (len(frames), 1, 0, 0, 0, "done")
    assert st.lateness_max == pytest.approx(0.0, abs=1e-12)
    assert st.elapsed == pytest.approx(0.75 / rate, abs=1e-12)
    # the long gaps were slept in slices of at most max_sleep (stop() is seen that often)
    assert max(clock.sleeps) <= 5e-3 + 1e-15


def test_frames_are_sorted_and_filtered_by_id():
    clock = FakeClock()
    bus = FakeBus(clock)
    frames = _frames(IRREGULAR)
    st = Player(list(reversed(frames)), bus, clock=clock, ids={0x101, 0x103}).run()
    want = [f for f in frames if f.can_id in (0x101, 0x103)]
    first = want[0].time
    assert [(s[1], s[2]) for s in bus.sent] == [(f.can_id, f.data) for f in want]
    assert [s[0] for s in bus.sent] == pytest.approx([f.time - first for f in want], abs=1e-12)
    assert st.sent == len(want)
    with pytest.raises(RtsimError, match="no frames to send with the selected ids"):
        Player(frames, bus, clock=clock, ids={0x7FF})


def test_loop_period_is_span_plus_median_interval():
    # 10 ms bursts of three frames: median positive gap 10 ms, span 30 ms -> period 40 ms
    times = [0.0, 0.0, 0.0, 0.01, 0.01, 0.01, 0.02, 0.02, 0.02, 0.03, 0.03, 0.03]
    assert median_interval(times) == pytest.approx(0.01)
    clock = FakeClock()
    bus = FakeBus(clock)
    p = Player(_frames(times), bus, rate=2.0, loop=True, clock=clock)
    assert p.period == pytest.approx(0.04)
    st = p.run(duration=0.099)                                # 0.198 s of recording at rate 2
    want = [(j * 0.04 + t) / 2.0 for j in range(6) for t in times]
    want = [t for t in want if t < 0.099]
    assert [s[0] for s in bus.sent] == pytest.approx(want, abs=1e-12)
    assert st.sent == len(want) == 60 and st.loops == 5 and st.ended == "duration"
    # the seam: last burst of a pass to the first of the next is one interval, like any other
    assert bus.sent[12][0] - bus.sent[11][0] == pytest.approx(0.01 / 2.0, abs=1e-12)


def test_loop_needs_two_distinct_times():
    with pytest.raises(RtsimError, match="--loop needs frames at two or more distinct times"):
        Player(_frames([1.0, 1.0]), FakeBus(FakeClock()), loop=True, clock=FakeClock())


def test_no_drift_with_send_cost_and_a_stall():
    # 100 Hz for 1 s; every send costs 0.3 ms; the CPU is taken away for 20 ms at t = 0.5005 s
    times = [0.01 * k for k in range(100)]
    clock = FakeClock(stalls=[(0.5005, 0.02)])
    bus = FakeBus(clock, cost=3e-4)
    st = Player(_frames(times), bus, clock=clock).run()
    assert st.sent == 100 and clock.stalled
    sends = [s[0] - 3e-4 for s in bus.sent]                   # when each send started
    late = [s - t for s, t in zip(sends, times)]
    assert min(late) >= -1e-12                                # never early
    hit = [k for k, x in enumerate(late) if x > 1e-9]
    # only frames due during the stall (20 ms plus at most one sleep slice) are late, one after another
    assert hit == list(range(hit[0], hit[-1] + 1))
    assert all(0.5 < times[k] < 0.5005 + 0.02 + 0.005 for k in hit)
    assert all(abs(x) < 1e-12 for k, x in enumerate(late) if k > hit[-1])   # back on schedule exactly
    assert st.late == len(hit)
    assert st.lateness_max == pytest.approx(max(late), abs=1e-12) and st.lateness_max > 0.01
    assert st.lateness_p50 == pytest.approx(0.0, abs=1e-12)


class OvershootClock(FakeClock):
    """Every sleep overshoots by 0.7 ms, as an OS sleep does on a busy machine."""

    def sleep(self, dt):
        super().sleep(dt + 7e-4)


def test_sleep_overshoot_does_not_accumulate():
    times = [0.002 * k for k in range(2000)]                  # 500 Hz for 4 s
    clock = OvershootClock()
    bus = FakeBus(clock)
    st = Player(_frames(times), bus, clock=clock).run()
    late = [s[0] - t for s, t in zip(bus.sent, times)]
    # each frame is at most one overshoot late; 2000 accumulated overshoots would be 1.4 s
    assert st.sent == 2000 and max(late) <= 7e-4 + 1e-12 and min(late) >= -1e-12
    assert late[-1] <= 7e-4 + 1e-12


# --------------------------------------------------------------------------------------------------
# stop and bus errors

def test_stop_from_inside_a_send_ends_the_run():
    clock = FakeClock()
    holder = {}
    bus = FakeBus(clock, on_send=lambda n: n == 3 and holder["p"].stop())
    holder["p"] = p = Player(_frames(IRREGULAR), bus, clock=clock, loop=True)
    st = p.run()
    assert st.sent == 3 and st.ended == "stopped"


def test_stop_from_another_thread_on_the_real_clock():
    frames = _frames([0.0, 3600.0])                           # the second frame is an hour away
    bus = FakeBus(clock=None)
    p = Player(frames, bus)
    p.start()
    deadline = time.monotonic() + EVENT                       # bounds on the waits only
    while not bus.sent and time.monotonic() < deadline:
        time.sleep(0.005)
    p.stop()
    assert p.join(timeout=EVENT), "run() did not return after stop()"
    assert p.stats.sent == 1 and p.stats.ended == "stopped"


def test_bus_errors_are_counted_and_retried():
    clock = FakeClock()
    # every 4th frame fails twice before it goes through
    bus = FakeBus(clock, fail=lambda k, a: k % 4 == 0 and a < 2)
    frames = _frames([0.01 * k for k in range(20)])
    st = Player(frames, bus, clock=clock, retries=3).run()
    assert [(s[1], s[2]) for s in bus.sent] == [(f.can_id, f.data) for f in frames]
    assert (st.sent, st.send_errors, st.dropped, st.ended) == (20, 10, 0, "done")
    assert "CanOperationError" in st.last_error


def test_dead_bus_drops_counts_and_ends_without_raising():
    clock = FakeClock()
    bus = FakeBus(clock, fail=lambda k, a: True)
    st = Player(_frames([0.01 * k for k in range(500)]), bus, clock=clock, retries=2,
                max_consecutive_drops=10, loop=True).run()
    assert (st.sent, st.dropped, st.send_errors, st.ended) == (0, 10, 30, "bus errors")


# --------------------------------------------------------------------------------------------------
# command line pieces

def test_parse_ids_and_arguments():
    assert parse_ids("0x100, 0x101,258") == {0x100, 0x101, 258}
    assert parse_ids(None) is None and parse_ids("") is None
    with pytest.raises(RtsimError, match="'0x10G' is not a CAN id"):
        parse_ids("0x100,0x10G")
    ap = argparse.ArgumentParser()
    add_arguments(ap)
    a = ap.parse_args(["s.mcap", "--rate", "2", "--loop", "--duration", "3", "--direction", "rx",
                       "--ids", "0x100", "--can-interface", "remote", "--can-channel", "127.0.0.1:1"])
    assert (a.file, a.rate, a.loop, a.duration, a.direction, a.ids, a.can_interface, a.can_channel) == (
        "s.mcap", 2.0, True, 3.0, "rx", "0x100", "remote", "127.0.0.1:1")


def _args(file, *extra):
    ap = argparse.ArgumentParser()
    add_arguments(ap)
    return ap.parse_args([str(file), *extra])


def test_main_without_a_hub_says_how_to_start_one(tmp_path, monkeypatch):
    from bridge.can_bus import socketcan_available

    if socketcan_available():
        pytest.skip("this machine has SocketCAN vcan0: open_bus() would use it, not the hub")
    with socket.socket() as s:                                # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv("RTSIM_CAN_HUB_PORT", str(port))
    path = tmp_path / "s.log"
    write_frames(path, _frames(IRREGULAR))
    with pytest.raises(RtsimError, match=rf"hub not reachable.*LoopbackHub\(port={port}\).*python -m can_remote"):
        main(_args(path), out=io.StringIO())
    with pytest.raises(RtsimError, match="--rate must be a positive number"):
        main(_args(path, "--rate", "0"), out=io.StringIO())


# --------------------------------------------------------------------------------------------------
# over a real loopback hub: two clients, every frame arrives in order with its id and bytes

@pytest.fixture
def hub():
    from bridge.can_bus import LoopbackHub

    with LoopbackHub(start_timeout=HUB_START) as h:       # cannot start here: a failure, not a skip
        yield h


def _recv_n(bus, n, deadline_s=EVENT):
    out = []
    deadline = time.monotonic() + deadline_s
    while len(out) < n and time.monotonic() < deadline:
        m = bus.recv(0.2)
        if m is not None:
            out.append(m)
    extra = bus.recv(0.2)                                     # nothing more than what was sent
    if extra is not None:
        out.append(extra)
    return out


def test_player_over_loopback_hub(hub):
    times = [0.002 * k for k in range(300)]                   # 0.6 s at 500 Hz, played at rate 10
    frames = [Frame(t, 0x100 + k % 8, bytes(((k + j) % 256 for j in range(k % 9))), "tx")
              for k, t in enumerate(times)]
    rx = hub.open_bus()
    tx = hub.open_bus()
    try:
        st = Player(frames, tx, rate=10.0).run()
        got = _recv_n(rx, len(frames))
    finally:
        tx.shutdown()
        rx.shutdown()
    assert (st.sent, st.send_errors, st.dropped) == (300, 0, 0)
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(f.can_id, f.data) for f in frames]


def test_rtsim_play_main_sends_the_recorded_sensor_frames(tmp_path, hub):
    from bridge.can_codec import Codec
    from bridge.mcap_recorder import Recorder
    from rtsim.channels import SENSOR_NAMES

    codec = Codec()
    path = tmp_path / "session.mcap"
    sent_tx = []
    with Recorder(path, "car1") as rec:
        for k in range(25):
            t = 0.002 * k
            cmd = codec.encode_command("steering_wheel_angle_cmd", 0.01 * k, k % 16)
            rec.record("can/rx", round(t * 1e9), cmd)
            for fid, data in codec.encode_sensors([0.001 * k] * len(SENSOR_NAMES), t):
                rec.record("can/tx", round(t * 1e9), (fid, data))
                sent_tx.append((fid, data))
    rx = hub.open_bus()
    try:
        out = io.StringIO()
        rc = main(_args(path, "--rate", "5", "--can-interface", "remote", "--can-channel", hub.channel), out=out)
        got = _recv_n(rx, len(sent_tx))
        out2 = io.StringIO()
        # the steering commands at rate 10 for 7.9 ms = 79 ms of recording: one pass of 25 frames
        # (span 48 ms + 2 ms interval = 50 ms), then frames 0..14 of the next (due < 79 ms)
        rc2 = main(_args(path, "--direction", "rx", "--can-interface", "remote", "--can-channel", hub.channel,
                         "--ids", "0x82", "--loop", "--rate", "10", "--duration", "0.0079"), out=out2)
        got2 = _recv_n(rx, 40)
    finally:
        rx.shutdown()
    assert rc == 0 and rc2 == 0
    assert [(m.arbitration_id, bytes(m.data)) for m in got] == sent_tx          # tx only, in order
    text = out.getvalue()
    assert f"sending {len(sent_tx)} tx frames" in text and "sent %d frames" % len(sent_tx) in text
    steer = [codec.encode_command("steering_wheel_angle_cmd", 0.01 * k, k % 16) for k in range(25)]
    assert [(m.arbitration_id, bytes(m.data)) for m in got2] == steer + steer[:15]
    assert "looping every 0.005 s" in out2.getvalue() and "(1 complete passes)" in out2.getvalue()
