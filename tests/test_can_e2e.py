"""The command receiver's E2E state machine and watchdog, exactly, in simulated time.

The reference is the rule the DBCs state (AUTOSAR E2E profile 1/2 receiver; bridge.can_codec's module
docstring): a repeated alive counter is never taken; after a time-out or a counter jump the first frame
and the next E2ESyncCounter frames in sequence are not taken; a command without a frame for more than
3 cycle times gets its safe value and its flag from the first step after that. Times are steps of
1 ms (t = k dt, as the service computes them), so each assertion names one step, never a window.

Part 1 drives ``CommandReceiver`` (the Python face of the compiled checks); part 2 the service's own
compiled step in-process (``HilLoop`` in fast mode, frames put in its receive ring as the CAN reader
thread puts them): the status and diagnostics frames it sends, frame formats, a second simulator's
frames. The same over a real bus, with the service in its own process: tests/test_service_e2e.py.
"""
from __future__ import annotations

import random

import cantools
import pytest

from bridge.can_codec import DEFAULT_DBC, SAFE_POLICY, Codec, CommandReceiver
from bridge.can_e2e import FLAG_EXTENDED, FLAG_FD, FLAG_REMOTE, SECOND_SIM_HOLD
from rtsim.channels import car_channels, two_wheeler_channels

DT = 0.001
HOLD = 3000.0       # kPa, the default brake hold pressure
DBCS = {"xbw": car_channels(), "eps_car": car_channels(("fl", "fr"), eps=True),
        "motorcycle": two_wheeler_channels()}


def _codec(name):
    return Codec(DEFAULT_DBC.parent / f"{name}.dbc", DBCS[name])


def _safe(name, last):
    """The safe value the DBC's comments promise for a timed-out command (last: its last value)."""
    policy = SAFE_POLICY.get(name, "zero")
    return {"zero": 0.0, "hold_pressure": HOLD, "hold_last": last}[policy]


# ------------------------------------------------------------------------------ 1. CommandReceiver

@pytest.mark.parametrize("vehicle", sorted(DBCS))
def test_every_command_times_out_exactly_three_periods_after_its_last_frame(vehicle):
    """Each command sent at its DBC period, then never again: at the step 3 periods after its last frame
    the value is still the command's; from the next step (1 ms later) on, the safe value and the flag.
    From many start steps (t = k dt in floating point, as the service counts it)."""
    codec = _codec(vehicle)
    rng = random.Random(29)
    for name in codec.channels.command_names:
        period = round(codec.command_frames[name].period / DT)          # steps
        lo, hi = codec.command_plan(name)[1].minimum, codec.command_plan(name)[1].maximum
        value = lo + 0.37 * (hi - lo)
        for _ in range(25):
            k0 = rng.randrange(0, 200_000)
            rx = CommandReceiver(codec, t0=k0 * DT)
            n = rng.randrange(1, 40)
            for j in range(n):
                assert rx.receive(*codec.encode_command(name, value, j), (k0 + j * period) * DT)
            k_last = k0 + (n - 1) * period
            value_rx = rx.latest[name]                                  # (the value in the DBC's resolution)
            assert value_rx == pytest.approx(value, abs=codec.command_plan(name)[1].factor)
            first_safe = None
            for k in range(k_last, k_last + 3 * period + 5):
                out = rx.check_timeouts(k * DT)[name]
                flag = rx.faults[rx.fault_names[codec.channels.command_names.index(name)]]
                if flag and first_safe is None:
                    first_safe = k
                if k < k_last + 3 * period + 1:
                    assert not flag and out == value_rx, (name, k0, k - k_last)
                else:
                    assert flag and out == _safe(name, value_rx), (name, k0, k - k_last)
            assert first_safe == k_last + 3 * period + 1


def test_a_frozen_sender_gets_nothing_after_its_first_frame():
    """The issue's case: the identical BRAKE_CMD frame (counter 7, 8000 kPa) every 10 ms for 3 s. Its
    first frame is taken; the 299 copies are repeats, never taken whatever the time since; the
    watchdog applies the 3 MPa hold pressure with the flag from 31 ms after the first frame on, at
    every step to the end."""
    codec = Codec()
    rx = CommandReceiver(codec)
    fid, data = codec.encode_command("brake_pressure_cmd", 8000.0, 7)
    taken = []
    for k in range(3000):
        if k % 10 == 0:
            taken.append(rx.receive(fid, data, k * DT))
        out = rx.check_timeouts(k * DT)
        if k <= 30:
            assert out["brake_pressure_cmd"] == 8000.0 and not rx.faults["brake_timeout"], k
        else:
            assert out["brake_pressure_cmd"] == HOLD and rx.faults["brake_timeout"], k
    assert taken == [True] + [False] * 299
    assert rx.accepted == 1 and rx.counters["counter_repeated"] == 299 and rx.counters["counter"] == 299
    assert rx.counters["sync"] == 0


def test_a_sender_frozen_mid_session_and_its_return():
    """A sender in sequence freezes (same frame over and over) for 1 s: nothing taken, safe value from the
    3rd missing period + 1 ms; then it counts again: its first new frame and the next E2ESyncCounter
    ones (2) are checked but not taken, the 4th is, at 10 ms steps: values back exactly 30 ms after the
    sender resumed."""
    codec = Codec()
    assert codec.sync_counter["brake_pressure_cmd"] == 2
    rx = CommandReceiver(codec)
    fid = codec.command_frames["brake_pressure_cmd"].frame_id
    ctr = 0
    log = []
    for k in range(0, 2000, 10):
        if k < 500:
            ctr = (k // 10) & 0xF            # in sequence
        elif k < 1500:
            pass                             # frozen: the frame at k = 490 again
        else:
            ctr = (ctr + 1) & 0xF            # counting again
        v = 1000.0 if k < 1500 else 2000.0
        if 500 <= k < 1500:
            v = 1000.0
        log.append((k, rx.receive(fid, codec.encode_command("brake_pressure_cmd", v, ctr)[1], k * DT)))
    taken = [k for k, ok in log if ok]
    assert [k for k in taken if k >= 490] == [490] + list(range(1530, 2000, 10))
    assert rx.counters["counter_repeated"] == 100 and rx.counters["sync"] == 3
    for k, expect in ((520, 1000.0), (521, HOLD), (1529, HOLD), (1530, 2000.0)):
        rx2 = CommandReceiver(codec)          # replay up to step k, then ask the watchdog
        for kk, _ in log:
            if kk > k:
                break
            rx2.receive(fid, _frame(codec, kk), kk * DT)
        assert rx2.check_timeouts(k * DT)["brake_pressure_cmd"] == expect, k


def _frame(codec, k):
    """The frame test_a_sender_frozen_mid_session_and_its_return sends at step k."""
    if k < 500:
        ctr = (k // 10) & 0xF
    elif k < 1500:
        ctr = (490 // 10) & 0xF
    else:
        ctr = (((490 // 10) & 0xF) + (k - 1490) // 10) & 0xF
    return codec.encode_command("brake_pressure_cmd", 2000.0 if k >= 1500 else 1000.0, ctr)[1]


def test_a_jump_then_a_gap_during_the_resynchronisation():
    """A counter jump starts a re-synchronisation (2 frames in sequence not taken); a silence longer than
    the time-out within it starts it again from the next frame."""
    codec = Codec()
    rx = CommandReceiver(codec)
    fid = codec.command_frames["throttle_angle_cmd"].frame_id

    def rcv(ctr, k):
        return rx.receive(fid, codec.encode_command("throttle_angle_cmd", 0.5, ctr)[1], k * DT)

    assert rcv(0, 0) and rcv(1, 10)
    assert not rcv(5, 20) and rx.counters["counter_jump"] == 1        # jump
    assert not rcv(6, 30)                                             # sync 1
    assert not rcv(7, 80) and rx.counters["sync"] == 2                # 50 ms gap: the sync starts again
    assert not rcv(8, 90) and not rcv(9, 100)                         # sync 1, 2
    assert rcv(10, 110)
    assert rx.counters["sync"] == 4 and rx.accepted == 3


@pytest.mark.parametrize("kw", [{"is_extended_id": True}, {"is_remote_frame": True}, {"is_fd": True},
                                {"is_extended_id": True, "is_fd": True}])
def test_frames_of_the_wrong_format_are_never_applied(kw):
    """50 frames with a command's id that are extended-id, remote or CAN FD frames (authentic payloads,
    counters in sequence): none taken, all counted as format errors; the classic frame after them is."""
    codec = Codec()
    rx = CommandReceiver(codec)
    for c in range(50):
        fid, data = codec.encode_command("brake_pressure_cmd", 8000.0, c)
        assert not rx.receive(fid, b"" if kw.get("is_remote_frame") else data, c * 0.01, **kw)
    assert rx.accepted == 0 and rx.counters["format"] == 50 and rx.latest["brake_pressure_cmd"] is None
    assert rx.receive(*codec.encode_command("brake_pressure_cmd", 100.0, 0), 0.5)


# ------------------------------------------------------------------- 2. the service's compiled step

@pytest.fixture(scope="module")
def car():
    """The default scenario's car, a fresh one per call (the built model cached)."""
    from rtsim.service.server import build_sim

    models: dict = {}
    return lambda: build_sim(None, None, models=models)


def _loop(car):
    from rtsim.service.loop import HilLoop

    sim, sc = car()
    return HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="fast", driver=sc.driver())


class _Sent:
    """The status and diagnostics frames the loop sent (its log ring), decoded with cantools."""

    def __init__(self, loop):
        from rtsim.service.rings import H_LOG, LOG_TX

        self.db = cantools.database.load_file(str(loop.codec.path))
        self.loop, self.H_LOG, self.LOG_TX = loop, H_LOG, LOG_TX
        self.n = 0
        self.status: list[tuple[int, dict]] = []
        self.diag: list[tuple[int, dict]] = []

    def take(self):
        rg = self.loop.rings
        cap = rg.log_t.shape[0]
        head = int(rg.heads[self.H_LOG])
        assert head - self.n <= cap
        for n in range(self.n, head):
            j = n % cap
            fid, dlc, direction = (int(v) for v in rg.log_meta[j, :3])
            if direction != self.LOG_TX or fid not in (272, 274):
                continue
            d = self.db.decode_message(fid, bytes(rg.log_data[j, :8]), decode_choices=False)
            (self.status if fid == 272 else self.diag).append((int(round(rg.log_t[j] / DT)), d))
        self.n = head


def _ecu_period(loop, k, cmds, flags=0):
    """Put one period's command frames (name -> (value, counter)) in the receive ring, take them at step
    k (the loop is there), run 10 steps."""
    assert loop.k == k
    for name, (v, c) in cmds.items():
        loop.rx_writer.put(*loop.codec.encode_command(name, v, c), flags)
    loop.take_frames()
    loop.advance(10)


def test_the_loop_applies_safe_values_and_flags_at_the_exact_step(car):
    """The compiled step: commands every 10 ms until step 300, then none. The watchdog's change (the
    commands topic's event) is at step 331 exactly, with the safe values; SIM_STATUS at T reports the
    step that started at T - 1 ms, so its flags are set in every status frame from T = 332 ms on and in
    none before."""
    from rtsim.service.rings import CMD_MASK, H_CMD

    loop = _loop(car)
    sent = _Sent(loop)
    names = loop.codec.channels.command_names
    values = {"throttle_angle_cmd": 0.1, "brake_pressure_cmd": 500.0, "steering_wheel_angle_cmd": 0.4}
    for p in range(31):                               # frames at k = 0, 10, ..., 300
        _ecu_period(loop, 10 * p, {n: (values[n], p & 0xF) for n in names})
    loop.advance(1000 - loop.k)
    sent.take()
    rg = loop.rings
    events = [(int(round(rg.cmd_t[j] / DT)), int(rg.cmd_meta[j, 1]), rg.cmd_v[j].copy())
              for j in range(int(rg.heads[H_CMD])) if rg.cmd_meta[j, 0] == CMD_MASK]
    assert [(k, m) for k, m, _ in events] == [(0, 0), (331, 0b111)], events
    assert list(events[-1][2]) == [0.0, HOLD, 0.4]                    # throttle closed, hold, steering held
    assert len(sent.status) == 10 and len(sent.diag) == 10            # every 100 ms, each with its diag
    flags = ("fault_throttle_timeout", "fault_brake_timeout", "fault_steer_timeout")
    for t_ms, st in sent.status:
        expect = t_ms >= 332
        assert all(st[f] == expect for f in flags), (t_ms, st)
        assert st["fault_second_sim"] == 0 and st["fault_model"] == 0
    assert [d["accepted_frames"] for _, d in sent.diag][-1] == 93


def test_the_loop_never_applies_a_frozen_frame_or_a_frame_of_the_wrong_format(car):
    """The issue's frozen BRAKE_CMD (counter 7, 8000 kPa every 10 ms for 3 s) and 50 extended-id, remote,
    CAN FD frames with command ids and SIM_STEP_REQ's: the first frozen frame is taken, nothing else;
    the hold pressure acts from step 31 on and every SIM_STATUS frame after it carries the flag;
    SIM_DIAG counts the repeats and the format errors."""
    from rtsim.service.rings import CMD_ACCEPTED, CMD_MASK, H_CMD

    loop = _loop(car)
    sent = _Sent(loop)
    codec = loop.codec
    fid, data = codec.encode_command("brake_pressure_cmd", 8000.0, 7)
    step_req = codec.encode_step_request(5, 3)
    for p in range(300):
        loop.rx_writer.put(fid, data)
        if p < 50:
            flags = (FLAG_EXTENDED, FLAG_REMOTE, FLAG_FD)[p % 3]
            loop.rx_writer.put(*codec.encode_command("throttle_angle_cmd", 1.0, p & 0xF), flags)
            loop.rx_writer.put(*step_req, flags)
        loop.take_frames()
        loop.advance(10)
    sent.take()
    rg = loop.rings
    ev = [(int(round(rg.cmd_t[j] / DT)), int(rg.cmd_meta[j, 0]), int(rg.cmd_meta[j, 1]))
          for j in range(int(rg.heads[H_CMD]))]
    accepted = [e for e in ev if e[1] == CMD_ACCEPTED]
    assert accepted == [(0, CMD_ACCEPTED, 1)]                        # the first brake frame only
    brake_to = [(k, m & 0b10) for k, kind, m in ev if kind == CMD_MASK]
    assert brake_to[-1] == (31, 0b10) and all(m for k, m in brake_to if k >= 31)
    c = loop.rx.counters
    assert c["counter_repeated"] == 299 and c["format"] == 100 and loop.rx.accepted == 1
    assert loop.lockstep_rejected == 0 and loop.lockstep_ignored == 0
    assert len(sent.status) == 30
    assert all(st["fault_brake_timeout"] for _, st in sent.status)   # every one (the first is at 100 ms)
    last = sent.diag[-1][1]
    assert (last["rejected_repeated"], last["rejected_format"], last["accepted_frames"]) == (299 % 256, 100, 1)
    ib = codec.channels.sensor_names.index("brake_pressure")
    assert abs(loop.ls.values[ib] - HOLD) < 50.0                     # the hold pressure, not 8 MPa


def test_a_second_simulator_on_the_bus_is_counted_and_flagged(car):
    """Frames with the simulator's own ids (a sensor frame, SIM_STATUS) that it did not send: counted as
    foreign, SIM_STATUS.fault_second_sim set while they arrive and for SECOND_SIM_HOLD s after the last,
    the Zenoh status says so; extended-id or remote frames with those ids are someone else's ids."""
    loop = _loop(car)
    sent = _Sent(loop)
    codec = loop.codec
    sensor_id = codec.sensor_frames[0].frame_id
    loop.advance(150)
    assert not loop.faults()["second_sim"]
    for p in range(50):                                               # 0.5 s of another simulator
        loop.rx_writer.put(sensor_id, bytes(8))
        if p % 10 == 0:
            loop.rx_writer.put(codec.status_frame.frame_id, bytes(8))
        loop.rx_writer.put(sensor_id, bytes(8), FLAG_EXTENDED)
        loop.rx_writer.put(sensor_id, b"", FLAG_REMOTE)
        loop.take_frames()
        loop.advance(10)
    k_last = 150 + 49 * 10
    st = loop.status()
    assert st["faults"]["second_sim"] and st["foreign_frames"] == 55
    assert st["rejected"]["unknown_id"] == 100 and loop.rx.counters["foreign_frames"] == 55
    hold = round(SECOND_SIM_HOLD / DT)
    loop.advance(k_last + hold + 300 - loop.k)
    assert not loop.faults()["second_sim"]
    sent.take()
    for t_ms, s in sent.status:
        expect = 150 <= t_ms and t_ms - k_last <= hold
        assert s["fault_second_sim"] == expect, (t_ms, s)
    assert sent.diag[-1][1]["foreign_frames"] == 55
    from bridge.payloads import validate

    validate("status", st)


def test_the_recording_keeps_a_received_frame_s_format():
    """A received extended-id, remote or CAN FD frame is recorded with its format (``can/rx``), which
    the schema allows and the log reader and re-simulation read back; a classic frame's record is as
    before (no extra keys)."""
    from bridge.can_logs import _mcap_frame
    from bridge.mcap_recorder import _can_frame
    from bridge.payloads import validation_errors

    classic = _can_frame((0x81, bytes(8)), 0.01)
    assert classic == {"id": 0x81, "dlc": 8, "data": "00" * 8, "time": 0.01}
    ext = _can_frame((0x81, bytes(8), 8, FLAG_EXTENDED), 0.02)
    remote = _can_frame((0x81, b"", 0, FLAG_REMOTE), 0.03)
    fd = _can_frame((0x81, bytes(12), 12, FLAG_FD | FLAG_EXTENDED), 0.04)
    assert ext["extended"] and remote["remote"] and fd["fd"] and fd["extended"] and "fd" not in ext
    for f in (classic, ext, remote, fd):
        assert validation_errors("can/rx", f) == []

    class M:
        def __init__(self, data):
            self.data, self.log_time_ns = data, 0

    assert _mcap_frame(None, "t", 0, M(ext), "rx").is_extended
    assert _mcap_frame(None, "t", 0, M(fd), "rx").is_fd and not _mcap_frame(None, "t", 0, M(classic), "rx").is_extended
    from rtsim.service.resim import _flags

    assert [_flags(f) for f in (classic, ext, remote, fd)] == [0, FLAG_EXTENDED, FLAG_REMOTE, FLAG_FD | FLAG_EXTENDED]


def _acks(loop) -> list[tuple[float, int]]:
    """(sim_time s, counter) of every SIM_STEP_ACK the loop sent (its log ring)."""
    from rtsim.service.rings import H_LOG, LOG_TX

    rg, codec = loop.rings, loop.codec
    cap = rg.log_t.shape[0]
    out = []
    for n in range(int(rg.heads[H_LOG])):
        j = n % cap
        fid, dlc, direction = (int(v) for v in rg.log_meta[j, :3])
        if direction == LOG_TX and fid == codec.step_ack.frame_id:
            out.append(codec.decode_step_ack(bytes(rg.log_data[j, :dlc])))
    return out


def test_a_retransmitted_step_request_is_acknowledged_again_and_never_run_twice(car):
    """Lockstep: SIM_STEP_REQ (5 steps, counter 3) runs 5 steps and is acknowledged at 5 ms; the same
    frame again (a retransmission) is acknowledged again at 5 ms, counted as repeated, not rejected, and
    time stays; counter 4 then runs its 5 steps. Outside lockstep a repeated counter is still rejected."""
    from rtsim.service.loop import HilLoop

    sim, sc = car()
    loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="lockstep", driver=sc.driver())
    codec = loop.codec
    for counter in (3, 3, 3, 4):
        loop.rx_writer.put(*codec.encode_step_request(5, counter))
        loop.take_frames()
    assert loop.k == 10
    acks = [(round(t / DT), c) for t, c in _acks(loop)]
    assert acks == [(5, 3), (5, 3), (5, 3), (10, 4)]
    assert (loop.lockstep_repeated, loop.lockstep_rejected, loop.lockstep_ignored) == (2, 0, 0)
    assert loop.rx.counters["counter_repeated"] == 0            # not a command frame's rejection

    fast = _loop(car)
    for counter in (3, 3):
        fast.rx_writer.put(*codec.encode_step_request(5, counter))
        fast.take_frames()
    assert (fast.lockstep_ignored, fast.lockstep_rejected, fast.lockstep_repeated) == (1, 1, 0)
    assert fast.k == 0 and _acks(fast) == []


def test_the_demo_controller_sends_an_unanswered_step_request_again(car):
    """drivers.bus_controller in lockstep: the first SIM_STEP_REQ is lost (the service not yet on the
    bus); the controller sends the same frame again (same counter) and, once it is acknowledged, asks
    for the next step. Waits, without asserting how long, for the resend."""
    import time

    from drivers.bus_controller import run

    sim, _ = car()
    codec = Codec(sim.vm.dbc, sim.vm.channels)

    class Ctl:
        t, done = 0.0, False
        decoder = type("D", (), {"receive": staticmethod(lambda fid, data: False)})()

        def __init__(self):
            self.codec = codec

        def summary(self):
            return {}

    ctl = Ctl()

    class LossyBus:
        def __init__(self):
            self.requests, self.replies = [], []

        def send(self, msg):
            steps, counter = codec.decode_step_request(bytes(msg.data))
            self.requests.append((steps, counter))
            if len(self.requests) == 1:
                return                                  # lost: nobody else on the bus yet
            if counter == 2:
                ctl.done = True
                return
            self.replies.append(codec.encode_step_ack(0.001, counter))

        def recv(self, timeout):
            if self.replies:
                import can

                fid, data = self.replies.pop(0)
                return can.Message(arbitration_id=fid, data=data, is_extended_id=False)
            time.sleep(0.01)
            return None

    bus = LossyBus()
    out = run(bus, ctl, lockstep=True, first_frame_timeout=120.0)
    assert bus.requests == [(1, 1), (1, 1), (1, 2)]
    assert out["step_requests_resent"] == 1
