"""bridge.can_logs: CAN frame logs (rtsim MCAP recordings, python-can's ASC/BLF/candump/CSV) read into
one time-sorted frame list, written back with python-can's writers, and the ECU command inputs
decoded through the service's CommandReceiver (E2E checks; rejections counted, never used).

References are independent of the module under test: frames are written by python-can's own writers
(or bridge.mcap_recorder.Recorder) from known lists; command frames are built with
Codec.encode_command and the expected values follow from the sequence the test builds.
"""
from __future__ import annotations

import gzip
import math
import shutil

import can
import pytest

from bridge.can_codec import Codec
from bridge.can_logs import Frame, command_inputs, read_frames, write_frames
from bridge.mcap_recorder import Recorder
from rtsim.channels import COMMAND_NAMES, SENSOR_NAMES
from rtsim.errors import RtsimError

FORMAT_RESOLUTION = 1e-6   # s: ASC and candump write microseconds; frames below are on a 1 us grid


@pytest.fixture(scope="module")
def codec():
    return Codec()


def _frames(with_fd: bool = True) -> list[Frame]:
    out = []
    t = 0.0
    for i in range(120):
        t += (137 + 53 * (i % 5)) * 1e-6                     # irregular steps on a 1 us grid
        n = i % 9                                            # 0..8 data bytes
        data = bytes((i * 31 + 7 * j) % 256 for j in range(n))
        ext = i % 11 == 3
        cid = (0x1ABC000 + i) if ext else (0x100 + i % 40)
        out.append(Frame(round(t, 6), cid, data, "tx" if i % 3 else "rx", ext, False))
    if with_fd:
        out.append(Frame(round(t + 0.001, 6), 0x321, bytes(range(64)), "rx", False, True))
        out.append(Frame(round(t + 0.002, 6), 0x322, bytes(range(12)), "tx", False, True))
    t0 = out[0].time
    return [f._replace(time=round(f.time - t0, 6)) for f in out]


def _assert_same(got, want, directions=True):
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert (g.can_id, g.data, g.is_extended, g.is_fd) == (w.can_id, w.data, w.is_extended, w.is_fd)
        assert g.time == pytest.approx(w.time, abs=FORMAT_RESOLUTION / 2)
        if directions:
            assert g.direction == w.direction


# --------------------------------------------------------------------------------------------------
# round trips through python-can's writers and readers

@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log"])
def test_round_trip_python_can_formats(tmp_path, suffix):
    frames = _frames()
    path = tmp_path / f"session{suffix}"
    assert write_frames(path, frames) == len(frames)
    got = read_frames(path)
    assert got.format == suffix and got.total == len(frames)
    _assert_same(got, frames)
    # also readable by python-can itself, frame for frame (the file is a genuine log of its format)
    with can.LogReader(str(path)) as reader:
        msgs = list(reader)
    assert [(m.arbitration_id, bytes(m.data)) for m in msgs] == [(f.can_id, f.data) for f in frames]


def test_round_trip_csv_has_no_direction(tmp_path):
    frames = _frames(with_fd=False)
    path = tmp_path / "session.csv"
    write_frames(path, frames)
    got = read_frames(path)
    _assert_same(got, frames, directions=False)
    assert {f.direction for f in got} == {None}


def test_absolute_start_time_and_gzip(tmp_path):
    frames = _frames(with_fd=False)
    path = tmp_path / "session.log"
    write_frames(path, frames, start=1_700_000_000.0)         # epoch time stamps as candump writes
    gz = tmp_path / "session.log.gz"
    with open(path, "rb") as a, gzip.open(gz, "wb") as b:
        shutil.copyfileobj(a, b)
    for p in (path, gz):
        _assert_same(read_frames(p), frames)


def test_frames_are_sorted_by_time_and_filtered_by_direction(tmp_path):
    frames = _frames(with_fd=False)
    # python-can's ASC/BLF/candump writers clamp time stamps that go backwards, so the out-of-order
    # file is written by hand in candump -L syntax
    shuffled = frames[1::2] + frames[0::2]
    path = tmp_path / "shuffled.log"
    path.write_text("".join(
        f"({5.0 + f.time:.6f}) can0 {f.can_id:0{8 if f.is_extended else 3}X}#{f.data.hex()} "
        f"{'R' if f.direction == 'rx' else 'T'}\n" for f in shuffled))
    _assert_same(read_frames(path), frames)
    ordered = tmp_path / "ordered.asc"
    write_frames(ordered, frames)
    rx = read_frames(ordered, "rx")
    # times stay relative to the file's first frame, whatever its direction
    _assert_same(rx, [f for f in frames if f.direction == "rx"])
    assert rx.total == len(frames)
    tx = read_frames(ordered, direction="tx")
    assert len(rx) + len(tx) == len(frames) and {f.direction for f in tx} == {"tx"}
    with pytest.raises(RtsimError, match="direction 'up'"):
        read_frames(ordered, "up")


def test_candump_lines_without_direction_are_unknown(tmp_path):
    path = tmp_path / "plain.log"
    path.write_text("(1000.000100) vcan0 100#0102\n(1000.000300) vcan0 101#\n(1000.000200) vcan0 1ABCDEF0#FF T\n")
    got = read_frames(path)
    assert [(f.time, f.can_id, f.data, f.direction, f.is_extended) for f in got] == [
        (0.0, 0x100, b"\x01\x02", None, False),
        (pytest.approx(1e-4, abs=1e-9), 0x1ABCDEF0, b"\xff", "tx", True),
        (pytest.approx(2e-4, abs=1e-9), 0x101, b"", None, False),
    ]
    assert read_frames(path, "rx") == []


def test_error_and_remote_frames_are_skipped_and_counted(tmp_path):
    path = tmp_path / "mixed.log"
    with can.CanutilsLogWriter(str(path)) as w:
        w.on_message_received(can.Message(timestamp=10.0, is_error_frame=True))
        w.on_message_received(can.Message(timestamp=10.5, arbitration_id=0x55, is_remote_frame=True, dlc=2))
        w.on_message_received(can.Message(timestamp=11.0, arbitration_id=0x56, data=b"\x01"))
        w.on_message_received(can.Message(timestamp=11.5, is_error_frame=True))
        w.on_message_received(can.Message(timestamp=12.0, arbitration_id=0x57, data=b"\x02"))
    got = read_frames(path)
    assert [(f.time, f.can_id) for f in got] == [(0.0, 0x56), (1.0, 0x57)]
    assert got.skipped == {"error_frames": 2, "remote_frames": 1}


# --------------------------------------------------------------------------------------------------
# MCAP recordings of the service

def _record_session(path, codec, vid="car1"):
    """A 0.2 s session at 100 Hz: ECU commands on can/rx, sensor frames on can/tx, plus a sensors
    topic; returns the (direction, time, id, data) of every CAN frame recorded."""
    frames = []
    with Recorder(path, vid) as rec:
        for k in range(20):
            t = 0.5 + 0.01 * k                                # the session did not start at 0
            t_ns = round(t * 1e9)
            fid, data = codec.encode_command("throttle_angle_cmd", 0.01 * k, k % 16)
            rec.record("can/rx", t_ns, (fid, data))
            frames.append(("rx", t, fid, data))
            values = [0.001 * k * (i + 1) for i in range(len(SENSOR_NAMES))]
            for j, (sid, sdata) in enumerate(codec.encode_sensors(values, t)):
                ts = t + 0.002 + 1e-5 * j
                rec.record("can/tx", round(ts * 1e9), {"id": sid, "data": sdata, "time": ts})
                frames.append(("tx", ts, sid, sdata))
            rec.record("sensors", t_ns, dict(zip(SENSOR_NAMES, values)))
    return frames


def test_mcap_recording_frames(tmp_path, codec):
    path = tmp_path / "session.mcap"
    rec = _record_session(path, codec)
    got = read_frames(path)
    assert got.topics == ("rtsim/car1/can/rx", "rtsim/car1/can/tx")
    want = sorted(rec, key=lambda r: r[1])
    t0 = want[0][1]
    assert [(f.direction, f.can_id, f.data) for f in got] == [(d, i, b) for d, _, i, b in want]
    assert [f.time for f in got] == pytest.approx([t - t0 for _, t, _, _ in want], abs=1e-9)
    tx = read_frames(path, "tx")
    assert len(tx) == sum(1 for r in rec if r[0] == "tx") and tx[0].time == pytest.approx(0.002, abs=1e-9)
    assert {f.can_id for f in tx} == {f.frame_id for f in codec.sensor_frames}
    with pytest.raises(RtsimError, match="no CAN topics of vehicle 'other'"):
        read_frames(path, vehicle="other")


def test_mcap_cut_short_is_recovered_with_a_note(tmp_path, codec):
    full = tmp_path / "full.mcap"
    with Recorder(full, "car1", chunk_size=2048) as rec:     # many small chunks
        for k in range(400):
            rec.record("can/tx", k * 2_000_000, (0x100 + k % 8, k.to_bytes(8, "little")))
    raw = full.read_bytes()
    cut = tmp_path / "cut.mcap"                               # as if the recorder had been killed
    cut.write_bytes(raw[: len(raw) // 2])
    want = read_frames(full)
    got = read_frames(cut)
    assert 0 < len(got) < len(want) and got == want[: len(got)]
    assert got.note and not want.note


def test_mcap_without_can_topics(tmp_path):
    path = tmp_path / "offline.mcap"
    with Recorder(path, "car1") as rec:
        rec.record("sensors", 0, {"accel_x": 1.0})
    with pytest.raises(RtsimError, match=r"no CAN topics .*rtsim/car1/sensors"):
        read_frames(path)


def test_mcap_bad_can_message_names_topic_and_index(tmp_path):
    path = tmp_path / "bad.mcap"
    with Recorder(path, "car1") as rec:
        rec.record("can/tx", 0, (0x100, b"\x01\x02"))
        rec.record("can/tx", 1000, b'{"id": 257, "dlc": 2, "data": "zz", "time": 0.001}')
    with pytest.raises(RtsimError, match=r"bad\.mcap: rtsim/car1/can/tx message 1: not a CAN frame"):
        read_frames(path)


# --------------------------------------------------------------------------------------------------
# bad files give one-line RtsimErrors naming the file and the place

def test_bad_files(tmp_path):
    def err(path, match):
        with pytest.raises(RtsimError, match=match) as ei:
            read_frames(path)
        assert "\n" not in str(ei.value) and str(path) in str(ei.value)

    (tmp_path / "x.txt").write_text("hello")
    err(tmp_path / "x.txt", r"unknown CAN log format '\.txt'; expected one of \.mcap, \.asc")
    err(tmp_path / "missing.asc", "no such file")
    (tmp_path / "empty.blf").write_bytes(b"")
    err(tmp_path / "empty.blf", "empty file")
    (tmp_path / "junk.blf").write_bytes(b"\x00not a blf" * 40)
    err(tmp_path / "junk.blf", r"not a \.blf file")
    (tmp_path / "junk.asc").write_bytes(bytes(range(256)) * 4)
    err(tmp_path / "junk.asc", "no CAN data frames .* none is a CAN data frame")
    (tmp_path / "junk.mcap").write_text("not mcap")
    err(tmp_path / "junk.mcap", "not an MCAP file")
    errors_only = tmp_path / "errors.log"
    errors_only.write_text("(1.0) vcan0 20000080#0000000000000000\n(1.1) vcan0 20000080#0000000000000000\n")
    err(errors_only, r"no CAN data frames in the file \(2 error frames skipped\)")

    good = _frames(with_fd=False)
    for suffix, lineno in ((".log", 7), (".asc", 12)):
        path = tmp_path / f"bad{suffix}"
        write_frames(path, good)
        lines = path.read_text().splitlines()
        lines[lineno - 1] = (" ".join(lines[lineno - 1].split()[:-1] + ["ZZ"]) if suffix == ".asc"
                             else "(0.1) vcan0 10Q#00 R")
        path.write_text("\n".join(lines) + "\n")
        err(path, rf"line {lineno}: .*cannot parse \(ValueError")

    blf = tmp_path / "damaged.blf"
    write_frames(blf, good)
    raw = bytearray(blf.read_bytes())
    raw[200:216] = b"\xa5" * 16                              # inside the compressed container
    blf.write_bytes(raw)
    err(blf, r"record after frame \d+: cannot parse")


def test_truncated_blf_keeps_frames_and_says_so(tmp_path):
    frames = _frames(with_fd=False)
    path = tmp_path / "cut.blf"
    write_frames(path, frames)
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - 64])
    got = read_frames(path)
    assert 0 < len(got) < len(frames)
    _assert_same(got, frames[: len(got)])
    assert "BLF header announces" in got.note


def test_write_frames_unknown_suffix(tmp_path):
    with pytest.raises(RtsimError, match=r"cannot write '\.mcap'"):
        write_frames(tmp_path / "x.mcap", _frames())


# --------------------------------------------------------------------------------------------------
# command inputs through the service's CommandReceiver

def _command_log(codec):
    """ECU frames at 100 Hz with known corruptions; returns (frames, expected accepted (t, name, value),
    expected rejection kinds, first brake time)."""
    frames, accepted, kinds = [], [], []
    thr_id = codec.command_frames["throttle_angle_cmd"].frame_id
    for i in range(60):
        t = 0.01 * i
        v = 0.0125 * i                                        # multiples of the 1e-4 rad resolution
        fid, data = codec.encode_command("throttle_angle_cmd", v, i % 16)
        if i == 10:                                           # one bit flipped: CRC fails
            data = bytes((data[0] ^ 0x04,)) + data[1:]
            kinds.append("crc")
        elif i == 20:                                         # authentic but 1.5 rad > DBC max 1.4
            fid, data = codec.encode_command("throttle_angle_cmd", 1.5, i % 16)
            kinds.append("range")
        elif i == 40:                                         # truncated frame
            data = data[:7]
            kinds.append("dlc")
        else:
            accepted.append((t, "throttle_angle_cmd", v))
        frames.append(Frame(t, fid, data, "rx"))
        if i == 30:                                           # replayed copy 1 ms later: same counter
            frames.append(Frame(t + 0.001, fid, codec.encode_command("throttle_angle_cmd", 0.9, i % 16)[1], "rx"))
            kinds.append("counter")
        if i >= 25:                                           # the brake starts late
            tb = t + 0.0005
            p = 100.0 * (i - 25)                              # multiples of 0.5 kPa
            frames.append(Frame(tb, *codec.encode_command("brake_pressure_cmd", p, i % 16), "rx"))
            accepted.append((tb, "brake_pressure_cmd", p))
        frames.append(Frame(t + 0.0002, 0x100, bytes(8), "tx"))   # a sensor frame: not a command
    assert thr_id == frames[0].can_id
    return frames, accepted, kinds, 0.25 + 0.0005


def _expected(accepted, name, t):
    vals = [v for ta, n, v in accepted if n == name and ta <= t]
    return vals[-1] if vals else math.nan


def test_command_inputs_accept_reject_and_hold(codec):
    frames, accepted, kinds, t_brake = _command_log(codec)
    ci = command_inputs(frames, codec)
    assert set(ci.values) == set(COMMAND_NAMES)
    assert ci.accepted == len(accepted)
    assert sorted(r.kind for r in ci.rejected) == sorted(kinds)
    assert {k: ci.counters[k] for k in ("crc", "range", "dlc", "counter")} == {
        "crc": 1, "range": 1, "dlc": 1, "counter": 1}
    assert ci.other_frames == 60
    assert len(ci.times) == len(frames) - 60
    # rejected values never reach the series: throttle never 1.5 (range) nor 0.9 (replay)
    thr = ci.values["throttle_angle_cmd"]
    assert thr.max() <= 0.0125 * 59 + 1e-9
    for k, t in enumerate(ci.times):
        for name in ("throttle_angle_cmd", "brake_pressure_cmd"):
            want = _expected(accepted, name, t)
            got = ci.values[name][k]
            if math.isnan(want):
                assert math.isnan(got)
            else:
                assert got == pytest.approx(want, abs=1e-9)
    assert math.isnan(ci.value_at("brake_pressure_cmd", t_brake - 1e-4))
    assert ci.value_at("brake_pressure_cmd", t_brake) == pytest.approx(0.0)
    assert ci.value_at("throttle_angle_cmd", 0.105) == pytest.approx(0.0125 * 9)     # crc-rejected 10 held 9
    assert ci.value_at("throttle_angle_cmd", 0.115) == pytest.approx(0.0125 * 11)
    assert all(math.isnan(v) for v in ci.values["steering_wheel_angle_cmd"])
    assert math.isnan(ci.value_at("throttle_angle_cmd", -1.0))
    assert "4 rejected" in ci.summary()


def test_command_inputs_from_files(tmp_path, codec):
    frames, accepted, kinds, _ = _command_log(codec)
    # via a candump log (python-can writer) ...
    path = tmp_path / "ecu.log"
    write_frames(path, frames)
    ci = command_inputs(read_frames(path, "rx"))
    assert ci.accepted == len(accepted) and len(ci.rejected) == len(kinds)
    # ... and via an MCAP recording: the commands the simulator received are on can/rx
    mpath = tmp_path / "ecu.mcap"
    with Recorder(mpath, "car1") as rec:
        for f in frames:
            rec.record("can/rx" if f.direction == "rx" else "can/tx", round(f.time * 1e9), (f.can_id, f.data))
    ci2 = command_inputs(read_frames(mpath, "rx"), codec)
    assert ci2.accepted == ci.accepted and ci2.counters == ci.counters
    assert ci2.other_frames == 0
