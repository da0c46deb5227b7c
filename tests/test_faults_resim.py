"""A session with faults of every family (sensor, random and patterned bus faults in both directions, an
actuator fault, time, condition and follower triggers), served by `rtsim serve` in lockstep with the demo
ECU over CAN and recorded: the recording carries each onset and end at its configured step on the
``faults`` topic, and `rtsim resim` re-arms the faults and reproduces the run bit for bit."""
from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from bridge.can_bus import open_bus
from bridge.can_codec import Codec
from bridge.mcap_recorder import read_recording
from service_harness import ROOT, Listener, ServiceProcess, can_segment
from waits import EVENT, PROCESS

FAULTS = """
[[faults]]
id = "noise"
kind = "noise_burst"
target = "accel_y"
amplitude = 0.5
seed = 3
at = 0.3
duration = 0.4

[[faults]]
id = "gyro_frames"
kind = "loss"
target = "SIM_IMU_GYRO"
n = 1
m = 3
at = 0.2
duration = 0.5

[[faults]]
id = "brake_frames"
kind = "loss"
target = "BRAKE_CMD"
probability = 0.3
seed = 9
at = 0.4
duration = 0.6

[[faults]]
id = "steer_counter"
kind = "corrupt_counter"
target = "STEER_CMD"
at = 0.25
duration = 0.05

[[faults]]
id = "moving"
kind = "drift"
target = "pitch"
rate = 0.01
when = "brake_pressure > 1500"
duration = 0.3

[[faults]]
id = "wheel"
kind = "brake_loss"
target = "brake_fr"
after = "moving"
after_delay = 0.1
duration = 0.2
"""


@pytest.mark.can_e2e
def test_a_recorded_session_with_faults_resimulates_bit_identically(tmp_path):
    from rtsim.service.resim import resim

    faults = tmp_path / "faults.toml"
    faults.write_text(FAULTS)
    rec = tmp_path / "faults.mcap"
    duration = 1.5
    with can_segment() as (iface, chan):
        svc = ServiceProcess(iface, chan, "--no-zenoh", "--mode", "lockstep", "--record", str(rec),
                             "--faults", str(faults))
        gyro = Codec().frames["SIM_IMU_GYRO"].frame_id
        bus = open_bus(iface, chan)
        listener = Listener(bus, sensor_ids=(gyro,))
        try:
            ecu = subprocess.run([sys.executable, "-m", "drivers.ecu_demo", "--can-interface", iface,
                                  "--can-channel", chan, "--lockstep", "--duration", str(duration), "--manoeuvre",
                                  "straight_line", "--timeout", str(EVENT)],
                                 cwd=ROOT, capture_output=True, text=True, timeout=PROCESS)
            seen_all = listener.wait_sim_ms(int(duration * 1000))
            rc, _ = svc.stop(signal.SIGTERM)
        finally:
            svc.close()
            listener.close()
            bus.shutdown()
    assert seen_all
    # on the bus: SIM_IMU_GYRO (every 2 ms) lost 1 of every 3 from 0.2 s to 0.7 s, every one outside
    stamps = [int.from_bytes(d[0:2], "little") for _, i, d in listener.frames if i == gyro]
    assert stamps[-1] >= duration * 1000
    assert stamps == [ms for ms in range(2, stamps[-1] + 1, 2) if not (200 <= ms < 700 and ((ms - 200) // 2) % 3 == 0)]
    assert ecu.returncode == 0, ecu.stderr
    assert rc == 0, svc.output
    messages, info = read_recording(rec)
    ev = [(m.data["id"], m.data["event"], m.data["step"]) for m in messages["rtsim/xbw/faults"]]
    timed = [e for e in ev if e[0] != "moving" and e[0] != "wheel"]
    assert sorted(timed, key=lambda e: (e[2], e[0])) == sorted([
        ("gyro_frames", "onset", 200), ("steer_counter", "onset", 250), ("steer_counter", "end", 300),
        ("noise", "onset", 300), ("brake_frames", "onset", 400), ("gyro_frames", "end", 700),
        ("noise", "end", 700), ("brake_frames", "end", 1000)], key=lambda e: (e[2], e[0]))
    moving = [e for e in ev if e[0] == "moving"]
    wheel = [e for e in ev if e[0] == "wheel"]
    assert moving and moving[0][1] == "onset" and wheel[0] == ("wheel", "onset", moving[0][2] + 100)
    # the brake pressure (the ECU's 2.5 MPa hold) crossed 1.5 MPa at the sensor sample the fault started at
    sensors = messages["rtsim/xbw/sensors"]
    first = next(m.data["time"] for m in sensors if m.data["brake_pressure"] > 1500)
    assert moving[0][2] == round(first * 1000) > 0
    rep = resim(rec)
    print(f"\nresim with faults: {rep['sensors']['matched']} sensor samples, faults {rep['faults']}")
    assert rep["faults"]["identical"] and rep["faults"]["recorded"] == len(ev) >= 12
    assert rep["sensors"]["missing"] == 0 and rep["sensors"]["matched"] >= 490 * duration
    assert rep["identical"], (rep["sensors"], rep["state"])
