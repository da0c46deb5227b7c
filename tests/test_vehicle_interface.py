"""Each vehicle declares its interface: a channel dictionary and a DBC that carries it. The front-wheel-drive
variant's drive-torque sensors sit on its front wheels; its codec, schemas and the service's frames follow
its own dictionary and DBC, and a DBC that does not carry the dictionary is rejected by name."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bridge.can_codec import Codec
from bridge.can_pack import SensorDecoder
from bridge.payloads import schemas_for
from drivers.scenario import load_scenario
from rtsim.channels import CAR, car_channels
from rtsim.errors import ConfigError
from rtsim.vehicle.car.build import build_vehicle
from rtsim.vehicle.car.config import load_vehicle

ROOT = Path(__file__).resolve().parents[1]
FWD = ROOT / "configs" / "vehicles" / "xbw_fwd.toml"


@pytest.fixture(scope="module")
def fwd_model():
    return build_vehicle(*load_vehicle(FWD))


def test_the_vehicle_declares_its_channels_and_dbc(fwd_model):
    ch = fwd_model.channels
    assert ch.sensor_names[-2:] == ("wheel_torque_fl", "wheel_torque_fr")
    assert ch.sensor_names[:-2] == CAR.sensor_names[:-2] and ch.state == CAR.state
    assert fwd_model.dbc == (ROOT / "configs" / "can" / "xbw_fwd.dbc").resolve()
    codec = Codec(fwd_model.dbc, ch)
    assert set(codec.sensor_frame_of) == set(ch.sensor_names)
    props = schemas_for(ch)["sensors"][1]["properties"]
    assert "wheel_torque_fl" in props and "wheel_torque_rl" not in props


def test_a_dbc_that_does_not_carry_the_dictionary_is_rejected():
    with pytest.raises(ConfigError, match=r"xbw.dbc: .*wheel_torque_rl is not a sensor channel of the vehicle"):
        Codec(ROOT / "configs" / "can" / "xbw.dbc", car_channels(("fl", "fr")))
    with pytest.raises(ConfigError, match=r"xbw_fwd.dbc: .*wheel_torque_fl is not a sensor channel"):
        Codec(ROOT / "configs" / "can" / "xbw_fwd.dbc", CAR)


def test_the_service_loop_sends_the_vehicles_own_frames():
    """The front-wheel-drive car accelerating under the service's compiled loop: its frames, decoded with
    its own DBC, carry the front drive torques as wheel_torque_fl/fr (positive, equal: open
    differential) and the samples match the values the loop packed."""
    from rtsim.service.loop import HilLoop
    from rtsim.service.resim import Collector
    from rtsim.service.server import build_sim
    from rtsim.vehicle.car.step import CMD_THROTTLE

    sim, _ = build_sim(ROOT / "configs" / "scenarios" / "hil_flat.toml", FWD)
    codec = Codec(sim.vm.dbc, sim.vm.channels)
    loop = HilLoop(sim, codec, mode="fast")
    col = Collector(loop)
    sim.io.commands[CMD_THROTTLE] = 0.3
    loop.advance(400)
    names = sim.vm.channels.sensor_names
    fl, fr = names.index("wheel_torque_fl"), names.index("wheel_torque_fr")
    last = col.sensors[-1][1]
    assert last[fl] > 10.0 and last[fl] == pytest.approx(last[fr], rel=1e-9)
    dec = SensorDecoder(codec)
    done = False
    for fid, data in codec.encode_sensors(last, col.sensors[-1][0]):
        done = dec.receive(fid, data) or done
    assert done
    assert dec.values[fl] == pytest.approx(last[fl], abs=0.2)      # the DBC's resolution: 0.2 N*m
    assert np.isfinite(dec.values).all()


def test_the_validation_workflow_reads_a_vehicles_own_channels(tmp_path, fwd_model):
    """A front-drive run (CSV and MCAP written by the offline runner) loads with its drive-torque channels
    when read with the vehicle's dictionary; with the rear-drive one they are not read, and the note
    says columns were ignored."""
    from bridge.mcap_log import write_run
    from rtsim.vehicle.offline import prepare, run, write_csv
    from bridge.mcap_recorder import read_recording
    from rtsim.validate.data import load_run

    sim, sc = prepare(FWD, load_scenario(ROOT / "configs" / "scenarios" / "step_steer_80kph.toml", check_files=True))
    res = run(sim, sc)
    csv_path, mcap_path = tmp_path / "run.csv", tmp_path / "run.mcap"
    write_csv(res, csv_path)
    write_run(mcap_path, res.columns, res.data, "xbw_fwd", sim.vm.channels)
    names = fwd_model.channels.sensor_names
    for path in (csv_path, mcap_path):
        r = load_run(path, names, read_recording)
        assert set(r.channels) == set(names)
        assert np.allclose(r.channels["wheel_torque_fl"], res.column("wheel_torque_fl"), rtol=1e-8, atol=1e-9)   # CSV: 9 digits
    rear = load_run(csv_path)
    assert "wheel_torque_fl" not in rear.channels and any(n.startswith("ignored ") for n in rear.notes)
