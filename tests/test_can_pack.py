"""The compiled sensor packer against the reference encoder (Codec.encode_sensors, itself checked
against cantools), and the ECU-side decoder against the values sent."""
from __future__ import annotations

import math
import random

import numpy as np
import pytest

from bridge.can_codec import FAULTS, REJECT_KINDS, STATUS_SOURCES, Codec
from bridge.can_e2e import pack_frames
from bridge.can_pack import SensorDecoder, SensorPacker
from rtsim.channels import SENSOR_NAMES


@pytest.fixture(scope="module")
def codec():
    return Codec()


def _random_values(rng: random.Random) -> list[float]:
    vals = []
    for _ in SENSOR_NAMES:
        kind = rng.random()
        if kind < 0.05:
            vals.append(rng.choice([math.nan, math.inf, -math.inf]))
        elif kind < 0.15:
            vals.append(rng.uniform(-1e5, 1e5))          # out of range: saturates (or wraps)
        elif kind < 0.2:
            vals.append(rng.choice([-1, 1]) * rng.uniform(1e15, 1e20))   # beyond 2**52 raw counts
        else:
            vals.append(rng.uniform(-5.0, 5.0))
    return vals


def test_packer_is_bit_identical_to_reference_encoder(codec):
    packer = SensorPacker(codec)
    rng = random.Random(7)
    for k in range(3000):
        vals = _random_values(rng)
        t = rng.uniform(0, 200.0) if k % 3 else round(rng.uniform(0, 100), 3) + 0.0005  # exact halves
        ref = codec.encode_sensors(vals, t)
        got = packer.pack(np.array(vals), t)
        assert [fid for fid, _ in ref] == list(packer.frame_ids)
        for (fid, data), row in zip(ref, got):
            assert bytes(row) == data, (fid, vals, t)


def test_status_frame_packs_like_encode_status(codec):
    """The compiled step packs SIM_STATUS from STATUS_SOURCES values: bit-identical to encode_status,
    saturating counters and the time included."""
    lay = codec.frame_layout("SIM_STATUS", STATUS_SOURCES)
    rng = np.random.default_rng(3)
    words = np.zeros(1, dtype=np.int64)
    for _ in range(300):
        mode = str(rng.choice(sorted(codec.modes)))
        t = float(rng.choice([rng.uniform(0, 200.0), rng.uniform(0, 3e5), round(rng.uniform(0, 99), 2) + 0.005]))
        overruns = int(rng.integers(0, 400))
        faults = {f: bool(rng.integers(0, 2)) for f in FAULTS}
        rejected = {k: int(rng.integers(0, 100)) for k in REJECT_KINDS}
        _, ref = codec.encode_status(mode, t, overruns, faults, rejected)
        vals = np.array([codec.modes[mode], t, overruns, *(float(faults[f]) for f in FAULTS),
                         *(rejected[k] for k in REJECT_KINDS), 0.0])
        pack_frames(vals, 0.0, lay["time_start"], lay["time_mask"], lay["sig_int"], lay["sig_float"], words)
        assert words.tobytes() == ref, (mode, t, overruns, faults, rejected)


def test_decoder_recovers_values_within_resolution_and_unwraps(codec):
    packer = SensorPacker(codec)
    dec = SensorDecoder(codec)
    res = {s.name: s.factor for f in codec.sensor_frames for s in f.signals}
    iw = SENSOR_NAMES.index("wheel_angle_fl")
    vals = np.zeros(len(SENSOR_NAMES))
    # 70 s at 500 Hz, wheel turning at 40 rad/s: the 16-bit ms stamp wraps at 65.536 s and the 24-bit
    # wheel angle (+-838.86 rad) wraps three times
    for n in range(0, 35000, 7):
        t = n * 0.002
        vals[:] = 0.5 * np.sin(np.arange(len(SENSOR_NAMES)) + t)
        vals[iw] = 40.0 * t
        frames = codec.encode_sensors(vals, t)
        done = [dec.receive(fid, d) for fid, d in frames]
        assert done == [False] * (len(frames) - 1) + [True]
        assert dec.time == pytest.approx(t, abs=1e-9)
        for i, name in enumerate(SENSOR_NAMES):
            if name in ("brake_pressure", "engine_speed", "throttle_angle"):
                expect = min(max(vals[i], 0.0), 1e9)     # unsigned signals saturate at 0
            else:
                expect = vals[i]
            assert dec.values[i] == pytest.approx(expect, abs=0.51 * res[name]), name
    assert dec.values[iw] > 2 * 838.0


def test_decoder_ignores_foreign_frames(codec):
    dec = SensorDecoder(codec)
    assert dec.receive(0x80, bytes(8)) is False
    assert dec.receive(0x100, bytes(3)) is False
    assert dec.samples == 0


def test_step_ack_packs_like_encode_step_ack(codec):
    lay = codec.frame_layout("SIM_STEP_ACK", ("lockstep_sim_time", "lockstep_ack_counter"))
    words = np.zeros(1, dtype=np.int64)
    rng = np.random.default_rng(4)
    for t in [0.0, 0.001, 12.3456785, 1099511.627775, 2e6, *rng.uniform(0, 5000, 100)]:
        counter = int(rng.integers(0, 16))
        _, ref = codec.encode_step_ack(float(t), counter)
        pack_frames(np.array([t, counter, 0.0]), 0.0, lay["time_start"], lay["time_mask"], lay["sig_int"],
                    lay["sig_float"], words)
        assert words.tobytes() == ref, (t, counter)


def test_status_and_diag_frames_pack_like_their_encoders(codec):
    """Codec.status_layout: SIM_STATUS and SIM_DIAG packed from one value array (status_sources, then
    DIAG_SOURCES) are bit-identical to encode_status and encode_diag, counters rolling."""
    from bridge.can_codec import DIAG_SOURCES

    lay = codec.status_layout()
    assert list(lay["frame_id"]) == [codec.status_frame.frame_id, codec.diag_frame.frame_id]
    rng = np.random.default_rng(5)
    words = np.zeros(2, dtype=np.int64)
    for _ in range(300):
        faults = {f: bool(rng.integers(0, 2)) for f in FAULTS}
        rejected = {k: int(rng.integers(0, 100)) for k in REJECT_KINDS}
        reason = int(rng.integers(0, 6))
        diag = {n: int(rng.integers(0, 70000)) for n in DIAG_SOURCES[1:]}
        _, ref_status = codec.encode_status("lockstep", 1.5, 7, faults, rejected)
        _, ref_diag = codec.encode_diag(reason, {n.removeprefix("rejected_"): v for n, v in diag.items()})
        vals = np.array([codec.modes["lockstep"], 1.5, 7, *(float(faults[f]) for f in FAULTS),
                         *(rejected[k] for k in REJECT_KINDS), reason, *diag.values(), 0.0])
        pack_frames(vals, 0.0, lay["time_start"], lay["time_mask"], lay["sig_int"], lay["sig_float"], words)
        assert words[:1].tobytes() == ref_status and words[1:].tobytes() == ref_diag
        assert words[1] & 0xFF == reason and (int(words[1]) >> 48) & 0xFFFF == diag["accepted_frames"] % 65536
