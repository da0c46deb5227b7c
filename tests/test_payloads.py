"""JSON payloads and schemas (bridge.payloads): schemas built from the channel dictionary, exact round
trips, NaN/inf as null (always valid JSON), the committed schemas/ files and the MCAP recorder's use of
the same schemas. jsonschema is not installed: payloads are checked by the module's small validator,
which is itself checked against hand-made invalid payloads."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bridge import payloads as P
from bridge.mcap_recorder import Recorder
from rtsim.channels import COMMANDS, SENSOR_NAMES, SENSORS, STATE, STATE_NAMES
from rtsim.errors import RtsimError

ROOT = Path(__file__).resolve().parent.parent

# The status fields as the service brief lists them (an independent copy, not read from the code).
STATUS_FIELDS = ["time", "vehicle_id", "mode", "run_state", "sim_time", "steps", "overruns",
                 "skipped_steps", "catch_up_steps", "stalls", "lateness_p50", "lateness_p99",
                 "lateness_max", "cpu_p50", "cpu_p99", "cpu_max", "steal", "faults", "rejected",
                 "accepted_frames", "bus_errors", "recorder", "zenoh_dropped", "scenario", "message"]
STATUS_OPTIONAL = ["wall_time", "drivers", "user",     # the user command source's (absent from older recordings)
                   "foreign_frames",                   # the second-simulator check's (likewise)
                   "model_fault",                      # the model-fault state's details
                   "injected_faults"]                  # the session's faults (rtsim.faults)


def strict_loads(b: bytes):
    """json.loads that refuses NaN/Infinity (Python's default accepts them; JSON does not)."""
    def bad(c):
        raise ValueError(f"non-JSON constant {c}")
    return json.loads(b, parse_constant=bad)


def status_example(**over):
    s = {"time": 12.5, "vehicle_id": "xbw", "mode": "realtime", "run_state": "running",
         "sim_time": 12.5, "steps": 6250, "overruns": 2, "skipped_steps": 0, "catch_up_steps": 5,
         "stalls": 1, "lateness_p50": 8e-7, "lateness_p99": 3e-4, "lateness_max": 0.021,
         "cpu_p50": 3e-5, "cpu_p99": 6e-5, "cpu_max": 2e-4, "steal": None,
         "faults": {"throttle_timeout": False, "brake_timeout": True, "steer_timeout": False,
                    "bus_error": False},
         "rejected": {"dlc": 0, "crc": 3, "counter": 1, "range": 0, "unknown_id": 7},
         "accepted_frames": 31000, "bus_errors": 0,
         "recorder": {"path": "/tmp/run.mcap", "written": 9000, "dropped": 0, "chunks": 4},
         "zenoh_dropped": 0, "scenario": "straight_line", "message": "running"}
    s.update(over)
    return s


# ----------------------------------------------------------------------------------------- schemas

def test_schema_fields_come_from_the_channel_dictionary():
    assert tuple(P.SCHEMAS) == P.TOPIC_KEYS + P.EVENT_TOPIC_KEYS + P.OFFLINE_TOPIC_KEYS
    for key, channels in (("sensors", SENSORS), ("state", STATE)):
        name, schema = P.SCHEMAS[key]
        assert name == f"rtsim.{key}" and schema["type"] == "object"
        assert list(schema["properties"]) == ["time", *(c.name for c in channels)]
        assert schema["required"] == ["time", *(c.name for c in channels)]
        for c in channels:
            desc = schema["properties"][c.name]["description"]
            assert c.description in desc and f"[{c.unit}]" in desc
    assert len(STATE_NAMES) == 47
    cmd = P.SCHEMAS["commands"][1]
    assert set(cmd["properties"]) == {"time", "source", *(c.name for c in COMMANDS)}
    assert cmd["required"] == ["time", "source"]
    assert cmd["properties"]["source"]["enum"] == ["can", "zenoh", "safe"]
    status = P.SCHEMAS["status"][1]
    assert list(status["properties"]) == STATUS_FIELDS + STATUS_OPTIONAL and status["required"] == STATUS_FIELDS
    assert status["properties"]["mode"]["enum"] == ["realtime", "lockstep", "fast"]
    assert status["properties"]["run_state"]["enum"] == ["running", "paused", "model_fault"]
    for key in P.TOPIC_KEYS:
        assert P.SCHEMAS[key][1]["properties"]["time"]["type"] == "number"


def test_committed_schema_files_match_the_code():
    expected = P.schema_files()
    on_disk = {p.relative_to(ROOT / "schemas").as_posix(): p.read_text()
               for p in (ROOT / "schemas").rglob("*") if p.is_file()}
    assert on_disk == expected, "schemas/ is stale: run `python -m bridge.payloads --write-schemas schemas`"
    for text in expected.values():
        json.loads(text)


def test_write_schemas_command(tmp_path):
    out = subprocess.run([sys.executable, "-m", "bridge.payloads", "--write-schemas", str(tmp_path)],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    written = {p.relative_to(tmp_path).as_posix(): p.read_text()
               for p in tmp_path.rglob("*") if p.is_file()}
    assert written == P.schema_files()
    assert set(written) == {"sensors.json", "state.json", "status.json", "commands.json",
                            "can/rx.json", "can/tx.json", "user.json", "control.json", "faults.json"}


def test_recorder_registers_the_same_schemas(tmp_path):
    from mcap.reader import make_reader
    path = tmp_path / "s.mcap"
    with Recorder(path, "car") as rec:
        for k in P.TOPIC_KEYS:
            rec.record(k, 0, (1, b"\x00") if k.startswith("can") else {"time": 0.0})
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    for ch in summary.channels.values():
        key = ch.topic.split("/", 2)[2]
        schema = summary.schemas[ch.schema_id]
        assert (schema.name, json.loads(schema.data)) == P.SCHEMAS[key]


# ----------------------------------------------------------------------------------------- encoders

def _awkward_values(n, seed):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=n) * 10.0 ** rng.integers(-12, 12, size=n)
    v[:4] = [0.0, -0.0, 1e-300, -1.7976931348623157e308][: min(4, n)]
    return v


@pytest.mark.parametrize("enc,names,key", [(P.encode_sensors, SENSOR_NAMES, "sensors"),
                                           (P.encode_state, STATE_NAMES, "state")])
def test_row_encoders_round_trip_exactly(enc, names, key):
    for seed in range(20):
        v = _awkward_values(len(names), seed)
        t = 0.002 * seed * 1234.5
        msg = strict_loads(enc(t, v))
        assert list(msg) == ["time", *names]
        assert msg["time"] == t and [msg[n] for n in names] == v.tolist()   # bit-exact
        assert P.validation_errors(key, msg) == []
        assert P.decode(enc(t, v)) == msg


@pytest.mark.parametrize("enc,names", [(P.encode_sensors, SENSOR_NAMES), (P.encode_state, STATE_NAMES)])
def test_non_finite_values_become_null(enc, names):
    v = np.linspace(-1.0, 1.0, len(names))
    for i, bad in [(0, np.nan), (len(names) - 1, np.inf), (len(names) // 2, -np.inf)]:
        w = v.copy()
        w[i] = bad
        msg = strict_loads(enc(1.5, w))
        assert msg[names[i]] is None
        assert [msg[n] for j, n in enumerate(names) if j != i] == [x for j, x in enumerate(v.tolist()) if j != i]
    # finite values whose sum overflows take the per-value path and stay exact
    big = np.full(len(names), 1.7e308)
    assert [strict_loads(enc(0.0, big))[n] for n in names] == big.tolist()
    assert strict_loads(enc(float("nan"), v))["time"] is None
    assert strict_loads(enc(0.0, np.full(len(names), np.nan)))[names[0]] is None


def test_row_encoder_inputs_and_precision():
    v = _awkward_values(len(SENSOR_NAMES), 3)
    exact = strict_loads(P.encode_sensors(np.float64(2.0), v))
    assert exact["time"] == 2.0
    assert strict_loads(P.encode_sensors(2.0, list(v))) == exact            # a list works too
    f32 = (np.linspace(-1e4, 1e4, len(SENSOR_NAMES)) / 3).astype(np.float32)
    assert [strict_loads(P.encode_sensors(0.0, f32))[n] for n in SENSOR_NAMES] == f32.astype(float).tolist()
    ints = np.arange(len(SENSOR_NAMES))
    assert [strict_loads(P.encode_sensors(0.0, ints))[n] for n in SENSOR_NAMES] == ints.astype(float).tolist()
    nine = strict_loads(P.encode_state(0.25, np.linspace(-3e5, 7e5, 47) + 1 / 3, digits=9))
    for n, x in zip(STATE_NAMES, np.linspace(-3e5, 7e5, 47) + 1 / 3):
        assert nine[n] == pytest.approx(x, rel=5e-9, abs=0)
    with pytest.raises(ValueError, match="expected 21 values"):
        P.encode_sensors(0.0, np.zeros(20))
    with pytest.raises(ValueError, match="digits"):
        P.encode_state(0.0, np.zeros(47), digits=30)


def test_encode_json_nulls_and_numpy():
    obj = {"time": np.float64(0.5), "a": float("nan"), "b": [1.0, float("inf"), {"c": -float("inf")}],
           "n": np.int64(3), "arr": np.array([1.0, np.nan]), "f32": np.float32(0.25), "s": "x"}
    got = strict_loads(P.encode_json(obj))
    assert got == {"time": 0.5, "a": None, "b": [1.0, None, {"c": None}], "n": 3, "arr": [1.0, None],
                   "f32": 0.25, "s": "x"}
    assert strict_loads(P.encode_json({"x": np.float32("nan")})) == {"x": None}
    with pytest.raises(TypeError):
        P.encode_json({"x": object()})


def test_decode_rejects_non_objects():
    assert P.decode(bytearray(b'{"a": 1}')) == {"a": 1}
    assert P.decode(memoryview(b'{"a": 1}')) == {"a": 1}
    with pytest.raises(RtsimError, match="not JSON"):
        P.decode(b"{nope")
    with pytest.raises(RtsimError, match="not an object"):
        P.decode(b"[1, 2]")
    with pytest.raises(RtsimError, match="not JSON"):
        P.decode(b"\xff\xfe")


# ----------------------------------------------------------------------------------------- validation

def test_status_and_commands_payloads_validate():
    for s in (status_example(), status_example(recorder=None, scenario=None, steal=0.25, mode="lockstep",
                                               run_state="paused", lateness_p99=None)):
        msg = strict_loads(P.encode_json(s))
        assert P.validation_errors("status", msg) == []
    user = {"wall_time": 1.7e9, "drivers": {"throttle_angle_cmd": "user", "brake_pressure_cmd": "ecu",
                                            "steering_wheel_angle_cmd": "safe"},
            "user": {"channels": {"throttle_angle_cmd": 0.3}, "takeover": False, "seq": 4, "requests": 9,
                     "accepted": True}}
    assert P.validation_errors("status", strict_loads(P.encode_json(status_example(**user)))) == []
    assert any("'driver' is not one of" in e for e in
               P.validation_errors("status", status_example(**{**user, "drivers": {"x": "driver"}})))
    nan_stats = strict_loads(P.encode_json(status_example(lateness_p50=float("nan"), cpu_max=float("inf"))))
    assert P.validation_errors("status", nan_stats) == []
    for c in ({"time": 0.1, "source": "safe"},
              {"time": 0.1, "throttle_angle_cmd": 0.05, "brake_pressure_cmd": 300.0,
               "steering_wheel_angle_cmd": -1.0, "source": "can"}):
        assert P.validation_errors("commands", strict_loads(P.encode_json(c))) == []
    frame = {"id": 0x1A0, "dlc": 3, "data": "0102ff", "time": 0.003}
    assert P.validation_errors("can/rx", frame) == [] and P.validation_errors("can/tx", frame) == []


@pytest.mark.parametrize("change,fragment", [
    ({"mode": "turbo"}, "$.mode: 'turbo' is not one of"),
    ({"run_state": None}, "$.run_state: None is not of type string"),
    ({"steps": True}, "$.steps: True is not of type integer"),
    ({"steps": 1.5}, "$.steps: 1.5 is not of type integer"),
    ({"overruns": -1}, "below the minimum 0"),
    ({"sim_time": None}, "$.sim_time: None is not of type number"),
    ({"faults": {"throttle_timeout": 0, "brake_timeout": False, "steer_timeout": False,
                 "bus_error": False}}, "$.faults.throttle_timeout: 0 is not of type boolean"),
    ({"rejected": {"dlc": 0, "crc": 0, "counter": 0, "range": 0}}, "missing required property 'unknown_id'"),
    ({"recorder": {"path": None, "written": 1, "dropped": 0}}, "$.recorder: missing required property 'chunks'"),
    ({"extra": 1}, "$.extra: property not allowed"),
])
def test_validator_catches_bad_status(change, fragment):
    errors = P.validation_errors("status", status_example(**change))
    assert any(fragment in e for e in errors), errors
    with pytest.raises(RtsimError, match="status payload invalid"):
        P.validate("status", status_example(**change))


def test_validator_other_topics():
    assert any("missing required property 'source'" in e
               for e in P.validation_errors("commands", {"time": 0.0}))
    assert any("'cheat' is not one of" in e
               for e in P.validation_errors("commands", {"time": 0.0, "source": "cheat"}))
    sensors = strict_loads(P.encode_sensors(0.0, np.zeros(len(SENSOR_NAMES))))
    del sensors["gyro_z"]
    assert P.validation_errors("sensors", sensors) == ["$: missing required property 'gyro_z'"]
    assert P.validation_errors("can/tx", {"id": 1, "dlc": 1, "data": 5, "time": 0}) == \
        ["$.data: 5 is not of type string"]
    with pytest.raises(RtsimError, match="unknown topic key"):
        P.validate("nope", {})
    assert "not supported" in P.validation_errors({"type": "object", "oneOf": []}, {})[0]
