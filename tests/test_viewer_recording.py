"""A recording as the page's source (rtsim.viewer.recording) reads only the topics the page needs, fast
(bridge.mcap_recorder.read_topics), and gives exactly what the MCAP library's reader gives
(bridge.mcap_recorder.read_recording): every message of those topics with its log time, the same metadata
and counts, and for a file cut off by a kill the same complete chunks."""
from __future__ import annotations

import json
import random
from pathlib import Path

from bridge.mcap_recorder import Recorder, read_recording, read_topics
from bridge.payloads import encode_json, encode_sensors, encode_state
from rtsim.channels import SENSOR_NAMES, STATE_NAMES
from rtsim.viewer.recording import Recording

VID = "car9"
VEHICLE = Path(__file__).resolve().parent.parent / "configs" / "vehicles" / "xbw.toml"


def _record(path, seconds=6.0):
    """A session's topics at the service's rates (sensors 500 Hz, state 100 Hz, status 10 Hz, four CAN
    frames per sensor sample), small chunks so that a cut falls inside the file's chunks."""
    rnd = random.Random(3)
    meta = {"rtsim.session": {"vehicle_id": VID, "dt": "0.001"},
            "rtsim.vehicle": {"path": str(VEHICLE), "toml": VEHICLE.read_text()}}
    with Recorder(path, VID, chunk_size=32 * 1024, metadata=meta) as rec:
        for k in range(1, int(seconds * 1000) + 1):
            t = k * 1e-3
            ns = k * 1_000_000
            if k % 2 == 0:
                rec.record("sensors", ns, encode_sensors(t, [rnd.uniform(-5, 5) for _ in SENSOR_NAMES]))
                for f in range(4):
                    rec.record("can/tx", ns, (0x100 + f, bytes(rnd.randrange(256) for _ in range(8))))
            if k % 10 == 0:
                rec.record("state", ns, encode_state(t, [rnd.uniform(-5, 5) for _ in STATE_NAMES]))
            if k % 100 == 0:
                rec.record("status", ns, encode_json({"time": t, "mode": "realtime", "steps": k}))
    return rec.chunks


def test_read_topics_equals_the_mcap_reader_whole_and_cut(tmp_path):
    path = tmp_path / "s.mcap"
    chunks = _record(path)
    assert chunks > 10
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[:len(data) * 3 // 5])                  # a kill in the middle of the recording
    for f in (path, cut):
        want = [f"rtsim/{VID}/{k}" for k in ("state", "sensors", "status")]
        got, info = read_topics(f, want)
        ref, rinfo = read_recording(f)
        for topic in want:
            assert [json.loads(m) for m in got[topic].data] == [m.data for m in ref[topic]], topic
            assert got[topic].log_time_ns.tolist() == [m.log_time_ns for m in ref[topic]]
        assert (info.complete, info.chunks, info.messages, info.topics, info.metadata, info.truncated_bytes) == \
            (rinfo.complete, rinfo.chunks, rinfo.messages, rinfo.topics, rinfo.metadata, rinfo.truncated_bytes)
        assert info.complete == (f == path) and 0 < len(got[want[0]].data)


def test_the_pages_recording_holds_every_state_sample_and_the_sensors_at_its_times(tmp_path):
    path = tmp_path / "s.mcap"
    _record(path, 2.0)
    ref, _ = read_recording(path)
    rec = Recording(path)
    page = json.loads(rec.payload(0))
    state = [m.data for m in ref[f"rtsim/{VID}/state"]]
    sensors = [m.data for m in ref[f"rtsim/{VID}/sensors"]]
    assert rec.vehicle_id == VID and rec.config["vehicle"]["id"] == "xbw" and abs(rec.duration - 1.99) < 1e-9
    assert page["state"] == state and page["status"] == [m.data for m in ref[f"rtsim/{VID}/status"]]
    # state every 10 ms, sensors every 2 ms: the sensor sample of the same time
    assert page["sensors"] == [next(s for s in sensors if abs(s["time"] - x["time"]) < 1e-9) for x in state]
