"""The CAN interface: configs/can/xbw.dbc and bridge/can_codec.py.

cantools' own decoder is the independent reference for the codec's precomputed fast path; the CRC is
checked against the published check values of CRC-8 SAE J1850 (AUTOSAR CRC library test vectors) and
a bitwise implementation written here.
"""
from __future__ import annotations

import random
import shutil

import cantools
import pytest

from bridge.can_codec import DEFAULT_DBC, FAULTS, Codec, CommandReceiver, crc8_j1850
from rtsim.channels import BY_NAME, COMMAND_NAMES, COMMANDS, SENSOR_NAMES, SENSORS
from rtsim.errors import ConfigError

CMD_FRAMES = {"THROTTLE_CMD": "throttle_angle_cmd", "BRAKE_CMD": "brake_pressure_cmd",
              "STEER_CMD": "steering_wheel_angle_cmd"}
CMD_RANGE = {"throttle_angle_cmd": (0.0, 1.4), "brake_pressure_cmd": (0.0, 12000.0),
             "steering_wheel_angle_cmd": (-11.0, 11.0)}


@pytest.fixture(scope="module")
def db():
    return cantools.database.load_file(str(DEFAULT_DBC), strict=True)


@pytest.fixture(scope="module")
def codec():
    return Codec(DEFAULT_DBC)


def sensor_messages(db):
    return [m for m in db.messages if m.senders == ["SIM"] and m.name not in ("SIM_STATUS", "SIM_DIAG", "SIM_STEP_ACK")]


def crc8_bitwise(data: bytes) -> int:
    """Reference CRC-8 SAE J1850: poly 0x1D, init 0xFF, MSB first, final xor 0xFF."""
    crc = 0xFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ 0xFF


# ---------------------------------------------------------------------------------------------- DBC

def test_dbc_loads_and_is_classic_intel_8_byte(db):
    assert {n.name for n in db.nodes} == {"ECU", "SIM"}
    assert len(db.messages) == 3 + 8 + 2 + 2   # commands, sensor frames, status and diagnostics, lockstep req/ack
    for m in db.messages:
        assert m.length == 8 and not m.is_extended_frame, m.name
        for s in m.signals:
            assert s.byte_order == "little_endian", (m.name, s.name)
            assert s.minimum is not None and s.maximum is not None, (m.name, s.name)


def test_every_sensor_channel_in_exactly_one_frame_with_its_unit(db):
    where: dict[str, list[str]] = {}
    for m in sensor_messages(db):
        assert "sim_time_ms" in [s.name for s in m.signals], m.name
        for s in m.signals:
            if s.name == "sim_time_ms":
                continue
            assert s.name in BY_NAME, s.name
            assert s.unit == BY_NAME[s.name].unit, (s.name, s.unit)
            where.setdefault(s.name, []).append(m.name)
    assert sorted(where) == sorted(SENSOR_NAMES)
    assert all(len(v) == 1 for v in where.values()), where
    for c in SENSORS:  # at least 16 bits, and at least 10 000 steps of resolution over the range
        m = db.get_message_by_name(where[c.name][0])
        s = m.get_signal_by_name(c.name)
        assert s.length >= 16 and (s.maximum - s.minimum) / s.scale >= 10000, c.name


def test_sensor_ranges(db):
    def sig(name):
        for m in sensor_messages(db):
            for s in m.signals:
                if s.name == name:
                    return s
    for a in "xyz":
        assert (sig(f"accel_{a}").minimum, sig(f"accel_{a}").maximum) == (-50, 50)
        assert (sig(f"gyro_{a}").minimum, sig(f"gyro_{a}").maximum) == (-10, 10)


def test_command_frames(db):
    for frame, name in CMD_FRAMES.items():
        m = db.get_message_by_name(frame)
        assert m.senders == ["ECU"]
        names = [s.name for s in m.signals]
        prefix = frame.split("_")[0].lower()
        assert names == [name, f"{prefix}_counter", f"{prefix}_crc"]
        s = m.get_signal_by_name(name)
        assert s.unit == BY_NAME[name].unit
        assert (s.minimum, s.maximum) == CMD_RANGE[name]
        crc = m.get_signal_by_name(f"{prefix}_crc")
        assert (crc.start, crc.length) == (56, 8)  # the last byte
        assert m.get_signal_by_name(f"{prefix}_counter").length == 4
    assert {s.name for f in CMD_FRAMES for s in db.get_message_by_name(f).signals} >= {c.name for c in COMMANDS}
    assert db.get_message_by_name("STEER_CMD").get_signal_by_name("steering_wheel_angle_cmd").is_signed


def test_cycle_times(db):
    for m in db.messages:
        if m.name in CMD_FRAMES:
            assert m.cycle_time == 10, m.name
        elif m.name in ("SIM_STATUS", "SIM_DIAG"):
            assert m.cycle_time == 100
        elif m.name in ("SIM_STEP_REQ", "SIM_STEP_ACK"):
            assert m.cycle_time is None, m.name   # event frames
        else:
            assert m.cycle_time == 2, m.name


def test_status_frame(db):
    m = db.get_message_by_name("SIM_STATUS")
    names = {s.name for s in m.signals}
    assert {f"fault_{f}" for f in FAULTS} <= names
    assert {"rejected_dlc", "rejected_crc", "rejected_counter", "rejected_range", "loop_overruns",
            "sim_time", "mode"} <= names
    assert {str(v) for v in m.get_signal_by_name("mode").choices.values()} == {"realtime", "lockstep", "fast"}
    # the simulator's own flags in byte 0, bits 6 and 7
    assert [(m.get_signal_by_name(n).start, m.get_signal_by_name(n).length)
            for n in ("fault_model", "fault_second_sim")] == [(6, 1), (7, 1)]


def test_diag_frame_reasons_are_the_model_status_codes(db):
    """SIM_DIAG: byte 0 the model's failure status, one VAL_ entry per status code of rtsim.mbs.model
    (1:1), then the rolling E2E outcome counters."""
    from rtsim.mbs import model

    m = db.get_message_by_name("SIM_DIAG")
    assert (m.frame_id, m.length, m.cycle_time) == (274, 8, 100)
    reason = m.get_signal_by_name("model_fault_reason")
    assert (reason.start, reason.length, reason.is_signed) == (0, 8, False)
    codes = {getattr(model, n): n for n in dir(model) if n == "OK" or n.startswith("ERR_")}
    assert set(reason.choices) == set(codes)
    names = {0: "none", model.ERR_NEWTON: "newton_not_converged", model.ERR_NONFINITE_FORCE: "nonfinite_force",
             model.ERR_NONFINITE_STATE: "nonfinite_state", model.ERR_FACTOR: "tangent_not_positive_definite",
             model.ERR_PROJECTION: "projection_not_converged"}
    assert {k: str(v) for k, v in reason.choices.items()} == names
    wrap = {s.name for s in m.signals if s.dbc is not None and s.dbc.attributes.get("SigWrap")
            and s.dbc.attributes["SigWrap"].value}
    assert wrap == {s.name for s in m.signals} - {"model_fault_reason"}      # every counter rolls


@pytest.mark.parametrize("name", ["xbw", "xbw_fwd", "eps_car", "motorcycle"])
def test_every_dbc_has_the_simulator_flags_and_diag(name):
    """The four DBCs declare the same SIM_DIAG frame and the model and second-simulator flags; the codec
    derives the status layout (both frames from one value array) from each."""
    path = DEFAULT_DBC.parent / f"{name}.dbc"
    db = cantools.database.load_file(str(path), strict=True)
    ref = cantools.database.load_file(str(DEFAULT_DBC), strict=True).get_message_by_name("SIM_DIAG")
    diag = db.get_message_by_name("SIM_DIAG")
    assert [(s.name, s.start, s.length) for s in diag.signals] == [(s.name, s.start, s.length) for s in ref.signals]
    status = db.get_message_by_name("SIM_STATUS")
    used = set()
    for s in status.signals:                                  # no two signals share a bit
        bits = set(range(s.start, s.start + s.length))
        assert not bits & used, s.name
        used |= bits
    assert {"fault_model", "fault_second_sim"} <= {s.name for s in status.signals}
    from rtsim.channels import car_channels, two_wheeler_channels

    channels = {"xbw": car_channels(), "xbw_fwd": car_channels(("fl", "fr")), "eps_car": car_channels(("fl", "fr"), eps=True),
                "motorcycle": two_wheeler_channels()}[name]
    codec = Codec(path, channels)
    assert codec.faults[-3:] == ("bus_error", "model", "second_sim")
    lay = codec.status_layout()
    assert list(lay["frame_id"]) == [272, 274]
    assert set(codec.own_frame_ids) == ({f.frame_id for f in codec.sensor_frames} | {272, 273, 274})


def test_broken_dbc_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError):
        Codec(tmp_path / "missing.dbc")
    p = tmp_path / "x.dbc"
    shutil.copy(DEFAULT_DBC, p)
    p.write_text(p.read_text().replace(" SG_ gyro_z ", " SG_ gyro_q "))
    with pytest.raises(ConfigError, match="gyro_q"):
        Codec(p)


# -------------------------------------------------------------------------------------- encoding

def test_sensor_round_trip_against_cantools(codec, db):
    rng = random.Random(7)
    msgs = {m.frame_id: m for m in db.messages}
    sigs = {s.name: s for m in sensor_messages(db) for s in m.signals}
    for k in range(300):
        vals = {n: rng.uniform(sigs[n].minimum, sigs[n].maximum) for n in SENSOR_NAMES}
        t = rng.uniform(0, 200)
        frames = codec.encode_sensors(vals if k % 2 else [vals[n] for n in SENSOR_NAMES], t)
        assert sorted(fid for fid, _ in frames) == sorted(m.frame_id for m in sensor_messages(db))
        for fid, data in frames:
            assert isinstance(data, bytes) and len(data) == 8
            dec = msgs[fid].decode(data, decode_choices=False)
            assert dec["sim_time_ms"] == round(t * 1000) % 65536
            for n, v in dec.items():
                if n != "sim_time_ms":
                    assert abs(v - vals[n]) <= sigs[n].scale / 2 + 1e-9, (n, v, vals[n])


def test_sensor_saturation_and_wrap(codec, db):
    vals = dict.fromkeys(SENSOR_NAMES, 0.0)
    vals.update(accel_x=80.0, accel_y=-1e9, gyro_z=float("nan"), engine_speed=-5.0,
                wheel_angle_fl=1000.0, wheel_angle_rr=-900.0, brake_pressure=float("inf"))
    dec = {}
    for fid, data in codec.encode_sensors(vals, 70.0):
        dec.update(db.get_message_by_frame_id(fid).decode(data))
    assert dec["accel_x"] == 50 and dec["accel_y"] == -50 and dec["gyro_z"] == 0 and dec["engine_speed"] == 0
    assert dec["brake_pressure"] == 16000
    assert dec["sim_time_ms"] == 70000 - 65536
    assert dec["wheel_angle_fl"] == pytest.approx(1000.0 - 1677.7216, abs=1e-4)
    assert dec["wheel_angle_rr"] == pytest.approx(-900.0 + 1677.7216, abs=1e-4)


def test_status_round_trip(codec, db):
    fid, data = codec.encode_status("lockstep", 1234.567, loop_overruns=300,
                                    faults={"brake_timeout", "bus_error"},
                                    rejected={"dlc": 3, "crc": 64 + 5, "counter": 1, "range": 63})
    dec = db.get_message_by_frame_id(fid).decode(data, decode_choices=False)
    assert dec["mode"] == 1
    assert dec["sim_time"] == pytest.approx(1234.57, abs=0.005)
    assert dec["loop_overruns"] == 300 % 256
    assert (dec["fault_throttle_timeout"], dec["fault_brake_timeout"], dec["fault_steer_timeout"],
            dec["fault_bus_error"]) == (0, 1, 0, 1)
    assert (dec["rejected_dlc"], dec["rejected_crc"], dec["rejected_counter"], dec["rejected_range"]) == (3, 5, 1, 63)
    with pytest.raises(ValueError):
        codec.encode_status("warp", 0.0)


def test_encode_command_against_cantools(codec, db):
    rng = random.Random(3)
    for frame, name in CMD_FRAMES.items():
        m = db.get_message_by_name(frame)
        s = m.get_signal_by_name(name)
        for counter in range(40):
            v = rng.uniform(s.minimum, s.maximum)
            fid, data = codec.encode_command(name if counter % 2 else frame, v, counter)
            assert fid == m.frame_id and len(data) == 8
            dec = m.decode(data)
            assert abs(dec[name] - v) <= s.scale / 2 + 1e-9
            prefix = frame.split("_")[0].lower()
            assert dec[f"{prefix}_counter"] == counter % 16
            # the documented CRC: data ID (low byte of the frame id) then bytes 0-6
            assert data[7] == crc8_bitwise(bytes((m.frame_id & 0xFF,)) + data[:7])


# ------------------------------------------------------------------------------------------- CRC

@pytest.mark.parametrize("data,crc", [
    (b"123456789", 0x4B),  # the catalogue check value of CRC-8/SAE-J1850
    (bytes.fromhex("00000000"), 0x59),  # AUTOSAR SWS CRC library test vectors
    (bytes.fromhex("F20183"), 0x37),
    (bytes.fromhex("0FAA0055"), 0x79),
    (bytes.fromhex("00FF5511"), 0xB8),
    (bytes.fromhex("332255AABBCCDDEEFF"), 0xCB),
    (bytes.fromhex("926B55"), 0x8C),
    (bytes.fromhex("FFFFFFFF"), 0x74),
])
def test_crc8_j1850_check_values(data, crc):
    assert crc8_j1850(data) == crc
    assert crc8_bitwise(data) == crc


def test_crc8_matches_bitwise_on_random_data():
    rng = random.Random(1)
    for _ in range(500):
        d = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 12)))
        assert crc8_j1850(d) == crc8_bitwise(d)


# ------------------------------------------------------------------------------------ E2E checks

def feed(rx, codec, name, value, counter, t):
    fid, data = codec.encode_command(name, value, counter)
    return rx.receive(fid, data, t)


def test_counter_sequence_wraps_and_rejects_repeats_and_jumps(codec):
    rx = CommandReceiver(codec)
    n, t = "throttle_angle_cmd", 0.0
    for c in list(range(16)) + [0, 1, 2]:  # wrap-around 15 -> 0 accepted
        t += 0.01
        assert feed(rx, codec, n, 0.1, c, t)
    t += 0.01
    assert not feed(rx, codec, n, 0.2, 2, t)  # repeated
    assert rx.counters["counter"] == 1 and rx.counters["counter_repeated"] == 1
    assert feed(rx, codec, n, 0.3, 4, t + 0.01)  # one frame lost: accepted
    assert not feed(rx, codec, n, 0.4, 7, t + 0.02)  # two frames lost: jump rejected
    assert rx.counters["counter"] == 2 and rx.counters["counter_jump"] == 1
    assert rx.latest[n] == pytest.approx(0.3)
    # re-synchronising on 7 (E2ESyncCounter = 2 in the DBC): 8 and 9 in sequence are checked, not taken
    assert not feed(rx, codec, n, 0.5, 8, t + 0.03) and not feed(rx, codec, n, 0.5, 9, t + 0.04)
    assert rx.counters["sync"] == 2 and rx.latest[n] == pytest.approx(0.3)
    assert feed(rx, codec, n, 0.5, 10, t + 0.05)                      # ... 10 is taken
    assert not feed(rx, codec, n, 0.5, 13, t + 0.06)  # a step of 3: jump
    assert rx.counters["counter"] == 3 and rx.counters["counter_jump"] == 2
    # 14 and 15 follow 13 (sync), 0 is taken; a repeat among them restarts the count
    assert not feed(rx, codec, n, 0.6, 14, t + 0.07) and not feed(rx, codec, n, 0.6, 14, t + 0.08)
    assert not feed(rx, codec, n, 0.6, 15, t + 0.09) and not feed(rx, codec, n, 0.6, 0, t + 0.10)
    assert feed(rx, codec, n, 0.6, 1, t + 0.11) and rx.latest[n] == pytest.approx(0.6)
    assert rx.counters["sync"] == 5 and rx.counters["counter_repeated"] == 2
    # counters are per command
    assert feed(rx, codec, "brake_pressure_cmd", 100.0, 9, t)
    assert feed(rx, codec, "brake_pressure_cmd", 100.0, 10, t + 0.01)
    assert rx.counters["dlc"] == rx.counters["crc"] == rx.counters["range"] == 0


def test_wrong_dlc_rejected(codec):
    rx = CommandReceiver(codec)
    fid, data = codec.encode_command("brake_pressure_cmd", 500.0, 1)
    for bad in (b"", data[:7], data + b"\x00", data[:1]):
        assert not rx.receive(fid, bad, 0.0)
    assert rx.counters["dlc"] == 4 and rx.accepted == 0
    assert rx.receive(fid, data, 0.0)


def test_bad_crc_and_foreign_data_id_rejected(codec):
    rx = CommandReceiver(codec)
    fid, data = codec.encode_command("steering_wheel_angle_cmd", -2.0, 5)
    for byte in range(8):
        for bit in range(8):
            d = bytearray(data)
            d[byte] ^= 1 << bit
            assert not rx.receive(fid, bytes(d), 0.0)
    assert rx.counters["crc"] == 64
    other = codec.command_plan("throttle_angle_cmd")[0].frame_id
    assert not rx.receive(other, data, 0.0)  # steer payload on the throttle id: data ID mismatch
    assert rx.counters["crc"] == 65 and rx.accepted == 0


def test_unknown_ids_ignored_and_counted_separately(codec):
    rx = CommandReceiver(codec)
    for fid in (0x000, 0x100, 0x110, 0x7FF, 0x1FFFFFFF):
        assert not rx.receive(fid, bytes(8), 0.0)
    assert rx.counters["unknown_id"] == 5
    assert all(rx.counters[k] == 0 for k in ("dlc", "crc", "counter", "range"))


def test_out_of_range_rejected_unless_clamped(codec):
    rx = CommandReceiver(codec)
    assert feed(rx, codec, "throttle_angle_cmd", 1.4, 0, 0.0)  # the limits themselves are valid
    assert feed(rx, codec, "throttle_angle_cmd", 0.0, 1, 0.01)
    assert not feed(rx, codec, "throttle_angle_cmd", 1.5, 2, 0.02)
    assert not feed(rx, codec, "steering_wheel_angle_cmd", -11.5, 0, 0.02)
    assert not feed(rx, codec, "brake_pressure_cmd", 12000.5, 0, 0.02)
    assert rx.counters["range"] == 3
    assert rx.latest["throttle_angle_cmd"] == 0.0 and rx.latest["steering_wheel_angle_cmd"] is None
    assert feed(rx, codec, "steering_wheel_angle_cmd", 11.0, 1, 0.03)
    assert feed(rx, codec, "brake_pressure_cmd", 12000.0, 1, 0.03)

    rx = CommandReceiver(codec, clamp={"throttle_angle_cmd"})
    assert feed(rx, codec, "throttle_angle_cmd", 3.0, 0, 0.0)
    assert rx.latest["throttle_angle_cmd"] == 1.4 and rx.counters["clamped"] == 1
    assert not feed(rx, codec, "brake_pressure_cmd", 20000.0, 0, 0.0)
    with pytest.raises(ValueError):
        CommandReceiver(codec, clamp={"nonsense"})


def test_receive_never_raises_on_odd_inputs(codec):
    rx = CommandReceiver(codec)
    fid, data = codec.encode_command("throttle_angle_cmd", 0.5, 0)
    assert rx.receive(fid, bytearray(data), 0.0)
    assert rx.receive(fid, memoryview(codec.encode_command("throttle_angle_cmd", 0.5, 1)[1]), 0.01)
    for bad in (None, 12345, "abcdefgh", [1, 2, 3]):
        assert not rx.receive(fid, bad, 0.02)


def test_fuzz_random_frames(codec, db):
    """100 000 random frames with valid ones interleaved: no exception; every frame is counted once;
    acceptances agree with an independent model (cantools decode, bitwise CRC, the counter rule)."""
    rng = random.Random(12345)
    rx = CommandReceiver(codec)
    cmd_msgs = {db.get_message_by_name(f).frame_id: db.get_message_by_name(f) for f in CMD_FRAMES}
    ids = list(cmd_msgs)
    # oracle state (AUTOSAR E2E profile 1/2 receiver, as the DBC's comments state it), per frame id
    state = {fid: {"ctr": None, "taken_t": None, "seq_t": None, "sync": 0} for fid in ids}
    nsync = {fid: codec.sync_counter[CMD_FRAMES[m.name]] for fid, m in cmd_msgs.items()}
    expect = {"unknown_id": 0, "dlc": 0, "crc": 0, "counter": 0, "range": 0, "sync": 0}
    expect_accepted = 0
    latest = {}
    sender_ctr = dict.fromkeys(ids, 0)
    constructed = constructed_ok = 0
    t = 0.0
    n = 100_000
    for k in range(n):
        t += 1e-4 if k % 5000 else 0.05  # occasional gaps longer than the 30 ms timeout
        r = rng.random()
        if r < 0.1:  # a constructed frame from the "ECU", sometimes out of range
            fid = rng.choice(ids)
            name = CMD_FRAMES[cmd_msgs[fid].name]
            lo, hi = CMD_RANGE[name]
            v = rng.uniform(lo, hi) if rng.random() < 0.9 else hi + (hi - lo) * 0.1
            sender_ctr[fid] = (sender_ctr[fid] + 1) % 16
            _, data = codec.encode_command(name, v, sender_ctr[fid])
            constructed += 1
        else:
            fid = rng.choice(ids) if r < 0.7 else rng.randrange(0x800)
            dlc = 8 if rng.random() < 0.5 else rng.randrange(9)
            data = bytes(rng.randrange(256) for _ in range(dlc))
        got = rx.receive(fid, data, t)
        # the oracle
        ok = False
        m = cmd_msgs.get(fid)
        if m is None:
            expect["unknown_id"] += 1
        elif len(data) != 8:
            expect["dlc"] += 1
        elif crc8_bitwise(bytes((fid & 0xFF,)) + data[:7]) != data[7]:
            expect["crc"] += 1
        else:
            dec = m.decode(data, decode_choices=False)
            name = CMD_FRAMES[m.name]
            ctr = dec[[s.name for s in m.signals][1]]
            st = state[fid]
            d = (ctr - st["ctr"]) % 16 if st["ctr"] is not None else 1
            take = False
            if d == 0:                                       # repeated: never
                expect["counter"] += 1
                if st["sync"]:
                    st["sync"] = nsync[fid] + 1              # the sync count starts again
            elif st["taken_t"] is None:                      # before the first value: any other counter
                take = True
            else:
                # re-synchronising (sync > 0): sync - 1 frames in sequence still to pass, then one is taken
                ref = st["seq_t"] if st["sync"] else st["taken_t"]
                timed_out = t - ref > 0.03 + 1e-9            # after a time-out (or a gap in the sync)
                if timed_out or d > 2:
                    st["ctr"], st["seq_t"], st["sync"] = ctr, t, nsync[fid] + 1
                    expect["sync" if timed_out else "counter"] += 1
                elif st["sync"] > 1:
                    st["ctr"], st["seq_t"] = ctr, t
                    st["sync"] -= 1
                    expect["sync"] += 1
                else:
                    st["sync"] = 0
                    take = True
            if take:
                st["ctr"], st["seq_t"] = ctr, t
                s = m.get_signal_by_name(name)
                if s.minimum - s.scale * 1e-3 <= dec[name] <= s.maximum + s.scale * 1e-3:
                    ok = True
                    st["taken_t"] = t
                    latest[name] = dec[name]
                else:
                    expect["range"] += 1
        expect_accepted += ok
        assert got == ok, (k, hex(fid), data.hex())
        if r < 0.1 and ok:
            constructed_ok += 1
    assert rx.accepted == expect_accepted
    assert {k: rx.counters[k] for k in expect} == expect
    assert rx.accepted + sum(expect.values()) == n  # every frame counted exactly once
    assert rx.counters["counter"] == rx.counters["counter_repeated"] + rx.counters["counter_jump"]
    assert constructed_ok > 0.7 * constructed  # the valid frames are honoured despite the noise
    assert min(expect.values()) > 0 and expect["crc"] > 0.25 * n
    for name, v in latest.items():
        assert rx.latest[name] == pytest.approx(v, abs=1e-9)


# -------------------------------------------------------------------------------------- watchdog

def test_watchdog_timeouts_safe_values_and_recovery(codec):
    rx = CommandReceiver(codec, hold_pressure=2500.0)
    assert rx.timeout == {n: pytest.approx(0.03) for n in CMD_RANGE}  # 3 x 10 ms from the DBC
    # before any frame: safe values, flagged only after the timeout counted from t0 = 0
    assert rx.check_timeouts(0.02) == {"throttle_angle_cmd": 0.0, "brake_pressure_cmd": 2500.0,
                                       "steering_wheel_angle_cmd": 0.0}
    assert not any(rx.faults.values())
    rx.check_timeouts(0.031)
    assert rx.faults == {"throttle_timeout": True, "brake_timeout": True, "steer_timeout": True}
    # regular traffic
    t = 0.0
    for c in range(10):
        t = 0.04 + 0.01 * c
        assert feed(rx, codec, "throttle_angle_cmd", 0.3, c, t)
        assert feed(rx, codec, "brake_pressure_cmd", 800.0, c, t)
        assert feed(rx, codec, "steering_wheel_angle_cmd", 1.25, c, t)
    out = rx.check_timeouts(t + 0.005)
    assert out == pytest.approx({"throttle_angle_cmd": 0.3, "brake_pressure_cmd": 800.0,
                                 "steering_wheel_angle_cmd": 1.25})
    assert not any(rx.faults.values())
    rx.check_timeouts(t + 0.029)
    assert not any(rx.faults.values())
    out = rx.check_timeouts(t + 0.031)  # silence for more than 3 periods
    assert all(rx.faults.values())
    assert out == pytest.approx({"throttle_angle_cmd": 0.0, "brake_pressure_cmd": 2500.0,
                                 "steering_wheel_angle_cmd": 1.25})
    # after a timeout the sender's first frame (any counter) and the next E2ESyncCounter (2) frames in
    # sequence are checked but not taken; the one after them clears the flag at once
    t2 = t + 0.2
    for j, c in enumerate((13, 14, 15)):
        assert not feed(rx, codec, "throttle_angle_cmd", 0.2, c, t2 + 0.01 * j)
        assert rx.check_timeouts(t2 + 0.01 * j)["throttle_angle_cmd"] == 0.0 and rx.faults["throttle_timeout"]
    assert rx.counters["sync"] == 3
    t3 = t2 + 0.03
    assert feed(rx, codec, "throttle_angle_cmd", 0.2, 0, t3)
    assert rx.faults == {"throttle_timeout": False, "brake_timeout": True, "steer_timeout": True}
    out = rx.check_timeouts(t3 + 0.001)
    assert out["throttle_angle_cmd"] == pytest.approx(0.2) and out["brake_pressure_cmd"] == 2500.0
    for j, c in enumerate((3, 4, 5, 6)):
        ok = j == 3
        assert feed(rx, codec, "brake_pressure_cmd", 900.0, c, t3 - 0.03 + 0.01 * j) == ok
        assert feed(rx, codec, "steering_wheel_angle_cmd", -0.5, c, t3 - 0.03 + 0.01 * j) == ok
    out = rx.check_timeouts(t3 + 0.001)
    assert not any(rx.faults.values())
    assert out == pytest.approx({"throttle_angle_cmd": 0.2, "brake_pressure_cmd": 900.0,
                                 "steering_wheel_angle_cmd": -0.5})
    t2 = t3
    # the flags go straight into the status frame
    fid, data = codec.encode_status("realtime", t2, faults=rx.faults, rejected=rx.counters)
    assert data[0] >> 2 & 0xF == 0


def test_watchdog_custom_timeout(codec):
    rx = CommandReceiver(codec, timeouts={"brake_pressure_cmd": 0.1})
    assert feed(rx, codec, "brake_pressure_cmd", 100.0, 0, 0.0)
    rx.check_timeouts(0.05)
    assert not rx.faults["brake_timeout"] and rx.faults["throttle_timeout"]
    rx.check_timeouts(0.11)
    assert rx.faults["brake_timeout"]


# ---------------------------------------------------------------------------------------- lockstep

def test_step_request_round_trip_against_cantools(db, codec):
    m = db.get_message_by_name("SIM_STEP_REQ")
    for steps, ctr in ((1, 0), (10, 7), (65535, 15)):
        fid, data = codec.encode_step_request(steps, ctr)
        assert fid == m.frame_id == 0xC0
        dec = m.decode(data)
        assert dec["lockstep_steps"] == steps and dec["lockstep_counter"] == ctr
        assert dec["lockstep_crc"] == crc8_bitwise(bytes((0xC0,)) + data[:7])
        assert codec.decode_step_request(data) == (steps, ctr)
    fid, data = codec.encode_step_request(5, 3)
    bad = bytearray(data)
    bad[0] ^= 1
    assert codec.decode_step_request(bytes(bad)) is None           # CRC
    assert codec.decode_step_request(data[:7]) is None             # DLC
    assert codec.decode_step_request(object()) is None              # not bytes: no exception
    with pytest.raises(ValueError):
        codec.encode_step_request(0, 0)


def test_step_ack_round_trip_against_cantools(db, codec):
    m = db.get_message_by_name("SIM_STEP_ACK")
    fid, data = codec.encode_step_ack(12.345678, 9)
    assert fid == m.frame_id
    dec = m.decode(data)
    assert dec["lockstep_sim_time"] == pytest.approx(12.345678, abs=1e-6)
    assert dec["lockstep_ack_counter"] == 9
    t, c = codec.decode_step_ack(data)
    assert t == pytest.approx(12.345678, abs=1e-6) and c == 9


def test_apply_timeouts_matches_check_timeouts(codec):
    import numpy as np

    a = CommandReceiver(codec, hold_pressure=1234.0)
    b = CommandReceiver(codec, hold_pressure=1234.0)
    out = np.zeros(3)
    frames = [(0.001, codec.encode_command("throttle_angle_cmd", 0.3, 1)),
              (0.002, codec.encode_command("steering_wheel_angle_cmd", -0.5, 1)),
              (0.003, codec.encode_command("brake_pressure_cmd", 800.0, 1))]
    for t, (fid, data) in frames:
        a.receive(fid, data, t)
        b.receive(fid, data, t)
    for t in (0.0, 0.01, 0.031, 0.0325, 0.5):
        ref = a.check_timeouts(t)
        mask = b.apply_timeouts(t, out)
        assert list(out) == [ref[n] for n in COMMAND_NAMES]
        assert mask == sum(1 << i for i, n in enumerate(COMMAND_NAMES) if b.timed_out[i])
    assert list(out) == [0.0, 1234.0, -0.5]     # throttle closed, brake hold, steering held
