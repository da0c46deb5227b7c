"""The channel dictionary as a vehicle's interface: its own checks (unique names, SI units), and a second,
test-only vehicle -- one sensor channel fewer and one renamed, with a DBC written here to match -- whose
codec, JSON schemas, Zenoh/MCAP payloads and recordings are derived from its dictionary; a DBC that does
not carry the dictionary is rejected with an error naming the DBC, the signal and what was expected."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from bridge.can_codec import DEFAULT_DBC, Codec
from bridge.can_pack import SensorDecoder
from bridge.mcap_recorder import Recorder, read_recording
from bridge.payloads import decode, encode_sensors, encode_state, schema_files, schemas_for, validation_errors
from rtsim.channels import CAR, Channel, ChannelDictionary
from rtsim.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]

#: the test vehicle: the car's channels without `pitch`, its inclinometer's `roll` named `lean_angle`
LEAN = Channel("lean_angle", "rad", "inclinometer lean angle, positive right side down")
SMALL = ChannelDictionary(tuple(LEAN if c.name == "roll" else c for c in CAR.sensors if c.name != "pitch"),
                          CAR.commands, CAR.state)


def small_dbc(path: Path, *, roll_unit: str = "rad", steer_cmd_unit: str = "rad") -> Path:
    """The car's DBC edited to carry SMALL: no pitch signal, roll renamed lean_angle."""
    text = DEFAULT_DBC.read_text()
    lines = [ln for ln in text.splitlines() if not re.match(r"\s*SG_ pitch ", ln)
             and not re.search(r"\bSG_ \d+ pitch\b", ln)]
    text = "\n".join(lines) + "\n"
    text = re.sub(r"(SG_ )roll( : [^\"]*)\"rad\"", rf'\1lean_angle\2"{roll_unit}"', text)
    text = re.sub(r"(SG_ \d+ )roll\b", r"\1lean_angle", text)
    text = re.sub(r"(SG_ steering_wheel_angle_cmd : [^\"]*)\"rad\"", rf'\1"{steer_cmd_unit}"', text)
    path.write_text(text)
    return path


# ------------------------------------------------------------------------------ the dictionary itself

def test_names_are_unique_and_units_si():
    acc = CAR.sensors[0]
    with pytest.raises(ValueError, match="repeated: accel_x"):
        ChannelDictionary((acc, acc), CAR.commands, CAR.state)
    with pytest.raises(ValueError, match="repeated: speed"):
        ChannelDictionary(CAR.sensors, CAR.commands, CAR.state + (CAR.state[-1].__class__("speed", "m/s", ""),))
    with pytest.raises(ValueError, match=r"sensors channel accel_x: unit 'g' is not one of"):
        ChannelDictionary((Channel("accel_x", "g", "in g"),), CAR.commands, CAR.state)
    with pytest.raises(ValueError, match="identifier"):
        ChannelDictionary((Channel("accel x", "m/s^2", ""),), CAR.commands, CAR.state)
    # a state channel may share a sensor's name (the actuator's state and its sensor)
    assert "throttle_angle" in CAR.state_names and "throttle_angle" in CAR.sensor_names


def test_index_and_json_round_trip():
    assert CAR.index("state", "yaw_angle") == CAR.state_names.index("yaw_angle")
    assert SMALL.index("sensors", "lean_angle") == 6
    with pytest.raises(KeyError, match="'pitch' is not a sensors channel"):
        SMALL.index("sensors", "pitch")
    with pytest.raises(ValueError, match="kind"):
        SMALL.index("sensor", "lean_angle")
    assert ChannelDictionary.from_json(SMALL.to_json()) == SMALL
    with pytest.raises(ValueError, match="not a channel dictionary"):
        ChannelDictionary.from_json('{"sensors": []}')


# ------------------------------------------------------------------------- a second vehicle's interface

def test_a_second_vehicle_gets_its_codec_from_its_own_dictionary(tmp_path):
    codec = Codec(small_dbc(tmp_path / "small.dbc"), SMALL)
    assert set(codec.sensor_frame_of) == set(SMALL.sensor_names)
    assert codec.sensor_frame_of["lean_angle"] == "SIM_INCLINATION"
    # a sample goes through the frames and back in the dictionary's order, within the DBC's resolution
    values = np.linspace(-0.5, 0.5, len(SMALL.sensors))
    dec = SensorDecoder(codec)
    done = False
    for fid, data in codec.encode_sensors(values, 1.234):
        done = dec.receive(fid, data) or done
    assert done and len(dec.values) == len(SMALL.sensors)
    i = SMALL.index("sensors", "lean_angle")
    assert dec.values[i] == pytest.approx(values[i], abs=1e-4)          # DBC: 0.0001 rad per bit
    j = SMALL.index("sensors", "gyro_z")
    assert dec.values[j] == pytest.approx(values[j], abs=5e-4)          # DBC: 0.0005 rad/s per bit
    by_name = dict(zip(SMALL.sensor_names, values))
    assert codec.encode_sensors(by_name, 1.234) == codec.encode_sensors(values, 1.234)


def test_its_schemas_and_payloads_follow_the_dictionary():
    schemas = schemas_for(SMALL)
    sensors = schemas["sensors"][1]["properties"]
    assert list(sensors) == ["time", *SMALL.sensor_names]
    assert "lean_angle" in sensors and "pitch" not in sensors and "roll" not in sensors
    assert sensors["lean_angle"]["description"].endswith("[rad]")
    files = schema_files(SMALL)
    assert json.loads(files["sensors.json"]) == schemas["sensors"][1]
    msg = decode(encode_sensors(2.0, np.arange(len(SMALL.sensors), dtype=float), names=SMALL.sensor_names))
    assert list(msg) == ["time", *SMALL.sensor_names] and msg["lean_angle"] == 6.0
    assert validation_errors(schemas["sensors"][1], msg) == []
    assert validation_errors(schemas_for(CAR)["sensors"][1], msg) != []      # not the car's sensors message
    state = decode(encode_state(2.0, np.zeros(len(SMALL.state)), names=SMALL.state_names))
    assert validation_errors(schemas["state"][1], state) == []


def test_a_recording_carries_its_dictionary(tmp_path):
    """The recorder writes the vehicle's schemas and its dictionary; a reader gets the dictionary back
    (``RecordingInfo.channels``), the session metadata unchanged beside it."""
    path = tmp_path / "small.mcap"
    rec = Recorder(path, "small", metadata={"rtsim.session": {"mode": "fast"}}, channels=SMALL)
    rec.record("sensors", 0, encode_sensors(0.0, np.zeros(len(SMALL.sensors)), names=SMALL.sensor_names))
    rec.close()
    messages, info = read_recording(path)
    assert info.channels == SMALL and info.metadata == {"rtsim.session": {"mode": "fast"}}
    assert "lean_angle" in messages["rtsim/small/sensors"][0].data
    from mcap.reader import make_reader
    with open(path, "rb") as fh:
        schema = next(s for s in make_reader(fh).get_summary().schemas.values() if s.name.endswith("sensors"))
    assert "lean_angle" in json.loads(schema.data)["properties"]


# ----------------------------------------------------------------------------- mismatches are refused

def test_a_dbc_that_does_not_carry_the_dictionary_is_rejected(tmp_path):
    dbc = small_dbc(tmp_path / "small.dbc")
    with pytest.raises(ConfigError, match=r"small.dbc: SIM_INCLINATION.lean_angle is not a sensor channel "
                                          r"of the vehicle \(its channels: accel_x"):
        Codec(dbc, CAR)
    with pytest.raises(ConfigError, match=r"xbw.dbc: SIM_INCLINATION.roll is not a sensor channel"):
        Codec(DEFAULT_DBC, SMALL)
    extra = ChannelDictionary(SMALL.sensors + (Channel("lean_rate", "rad/s", "lean rate"),), SMALL.commands,
                              SMALL.state)
    with pytest.raises(ConfigError, match=r"small.dbc: sensor channels missing from the sensor frames: lean_rate"):
        Codec(dbc, extra)
    bad_unit = small_dbc(tmp_path / "bad_unit.dbc", roll_unit="deg")
    with pytest.raises(ConfigError, match=r"bad_unit.dbc: SIM_INCLINATION.lean_angle is in 'deg', the "
                                          r"vehicle's channel in 'rad'"):
        Codec(bad_unit, SMALL)
    bad_cmd = small_dbc(tmp_path / "bad_cmd.dbc", steer_cmd_unit="deg")
    with pytest.raises(ConfigError, match=r"bad_cmd.dbc: STEER_CMD.steering_wheel_angle_cmd is in 'deg', "
                                          r"the vehicle's command in 'rad'"):
        Codec(bad_cmd, SMALL)
    fewer_cmds = ChannelDictionary(SMALL.sensors, SMALL.commands[:2], SMALL.state)
    with pytest.raises(ConfigError, match=r"small.dbc: command frame STEER_CMD needs"):
        Codec(dbc, fewer_cmds)


def test_the_service_loop_refuses_a_dictionary_its_kernel_does_not_produce(tmp_path):
    """The car's compiled loop writes the car's sensor channels: a codec for a dictionary of another
    size is refused by name before anything runs."""
    from rtsim.errors import RtsimError
    from rtsim.service.config import DEFAULT_SCENARIO
    from rtsim.service.loop import HilLoop
    from rtsim.service.server import build_sim

    sim, _ = build_sim(DEFAULT_SCENARIO)
    with pytest.raises(RtsimError, match=rf"small.dbc: the vehicle declares 20 sensor and {len(CAR.state)} state "
                                         rf"channels; its loop produces 21 and {len(CAR.state)}"):
        HilLoop(sim, Codec(small_dbc(tmp_path / "small.dbc"), SMALL), mode="fast")


def test_the_front_drive_cars_own_sensor_channels_take_sensor_parameters(tmp_path):
    """[sensors.channels] of the front-drive car configures its wheel_torque_fl (a channel the rear-drive
    car does not have): the bias shows in that channel only."""
    from rtsim.service.server import build_sim
    from rtsim.vehicle.car.step import CMD_THROTTLE

    text = (ROOT / "configs/vehicles/xbw_fwd.toml").read_text().replace('"../', f'"{ROOT.as_posix()}/configs/')
    biased = tmp_path / "fwd_biased.toml"
    biased.write_text(text + "\n[sensors.channels.wheel_torque_fl]\nbias = 3.0\n")
    out = []
    for vehicle in (ROOT / "configs/vehicles/xbw_fwd.toml", biased):
        sim, _ = build_sim(ROOT / "configs/scenarios/hil_flat.toml", vehicle)
        sim.io.commands[CMD_THROTTLE] = 0.3
        sim.step(200)
        out.append(sim.sensors(np.zeros(len(sim.vm.channels.sensors))))
    base, bias = out
    fl = sim.vm.channels.index("sensors", "wheel_torque_fl")
    assert bias[fl] - base[fl] == pytest.approx(3.0, abs=1e-12)
    others = [i for i in range(len(base)) if i != fl]
    assert np.array_equal(bias[others], base[others])
