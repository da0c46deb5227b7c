"""The two-wheeler in the loop (issue 13, item 6): the sport motorcycle served by the HIL service's compiled
step with its own DBC (configs/can/motorcycle.dbc), the rider inside the step, a rider-assist ECU's
commands on the bus.

In-process tests run the service's loop (``HilLoop``, the same compiled step as ``rtsim serve``) in fast
mode and put command frames in its receive ring as the CAN reader thread would. References: the
offline ride (rtsim.vehicle.motorcycle.ride: the same rider and model, stepped from Python) for the
rider in the loop; the steady turn's kinematics for the sensors (specific force sqrt(g^2 + (u r)^2),
the IMU's rates against the state's); the watchdog's time-out (3 DBC periods) and the fallback to the
rider's own demand; a fall ending the session with a status, never a NaN."""
from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest

from bridge.can_codec import Codec
from drivers.scenario import load_scenario
from drivers.rider import RiderPar, RO_THROTTLE
from rtsim.service.loop import HilLoop
from rtsim.service.server import build_sim
from rtsim.vehicle.motorcycle.plant import IN_ASSIST, IN_RIDER_TORQUE, IN_THROTTLE
from rtsim.service.rings import H_TX, RingReader
from rtsim.vehicle.motorcycle.geometry import frame_rotation
from rtsim.vehicle.motorcycle.ride import Ride, tyre_lean_ratio
from rtsim.vehicle.motorcycle.sim import TwoWheelerSim
from service_harness import ROOT, free_port

VEHICLE = ROOT / "configs" / "vehicles" / "motorcycle.toml"
MODELS: dict = {}


def _loop(rider: bool = True, scenario=None):
    sim, sc = build_sim(scenario, VEHICLE, models=MODELS, rider=rider)
    return sim, sc, HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="fast", driver=sc.driver())


def _value(loop, kind, name):
    ch = loop.sim.vm.channels
    return float((loop.ls.values if kind == "sensors" else loop.ls.state)[ch.index(kind, name)])


@pytest.fixture(scope="module")
def riding():
    """The rider on the default HIL scenario's figure-eight: 9 s (the first circle's steady part)."""
    sim, sc, loop = _loop()
    loop.advance(9000)
    return sim, sc, loop


def test_the_rider_in_the_loop_rides_as_offline(riding):
    """The compiled rider view and inputs (rtsim.vehicle.motorcycle.plant) reproduce the offline ride
    (Python view, same rider, same model and start): the same trajectory to round-off (its differences, 1e-9 after 9 s, grow from the last digits)."""
    sim, sc, loop = riding
    mm, _dbc, q = MODELS[(VEHICLE.resolve(), "two_wheeler")]
    r = sc.rider()
    r.par[RiderPar.TYRE_LEAN] = tyre_lean_ratio(mm)
    off = TwoWheelerSim(mm, dt=sim.dt, speed=sc.spec.initial.speed, q=q)
    Ride(off, r).run(loop.sim_time)
    assert loop.run_state == "running" and loop.sim_time == pytest.approx(9.0)
    assert np.max(np.abs(sim.data.q - off.data.q)) < 1e-6          # m, rad: 60 m from the start after 9 s
    assert _value(loop, "state", "roll_angle") == pytest.approx(off.roll, abs=1e-8)


def frame_roll(mm, q) -> tuple[float, float, float]:
    """Yaw, roll and pitch of the rear frame from its three unit vectors in the multibody state q, without
    the model's own roll function: the rotation R that takes the design axes (e1, v, h) to the current
    ones, read as yaw about z, then roll about the new x, then pitch about the new y (R = Rz Rx Ry, the
    definition of rtsim.vehicle.motorcycle.geometry.frame_rotation), its second column R e_y =
    (-sin yaw cos roll, cos yaw cos roll, sin roll)."""
    axes = [mm.group(q, n) for n in ("E1", "V", "H_AX")]
    des = mm.design
    rot = np.column_stack(axes) @ np.linalg.inv(np.column_stack([des.e1, des.v, des.h]))
    yaw = math.atan2(-rot[0, 1], rot[1, 1])
    roll = math.atan2(rot[2, 1], math.hypot(rot[0, 1], rot[1, 1]))
    pitch = math.atan2(-rot[2, 0], rot[2, 2])
    assert np.allclose(frame_rotation(yaw, roll, pitch), rot, atol=1e-9)     # it is that rotation
    return yaw, roll, pitch


def test_sensors_in_the_steady_turn(riding):
    """In the circle the IMU's specific force has the magnitude sqrt(g^2 + (u r)^2), its rates the
    magnitude of the frame's angular velocity (the yaw rate, nearly vertical); the roll sensor reads the
    rear frame's roll taken from its orientation in the multibody state (frame_roll), and the steady
    turn's lean: tan(phi_k) = u r / g for the line from the contacts to the mass centre, the frame leaning
    (1 + k) times further on tyres of crown radius rho (k = rho / (h - rho), tyre_lean_ratio), to within
    the gyroscopic and rider terms (5 %); the wheel speeds are the speed over the rolling radii (within the
    tyres' slip and crown)."""
    sim, _sc, loop = riding
    mm = MODELS[(VEHICLE.resolve(), "two_wheeler")][0]
    u, r = _value(loop, "state", "speed"), _value(loop, "state", "yaw_rate")
    f = [_value(loop, "sensors", f"accel_{a}") for a in "xyz"]
    w = [_value(loop, "sensors", f"gyro_{a}") for a in "xyz"]
    assert abs(r) > 0.3                                    # in a circle, not on a straight
    assert np.linalg.norm(f) == pytest.approx(math.hypot(9.81, u * r), rel=0.02)
    assert np.linalg.norm(w) == pytest.approx(abs(r), rel=0.05)
    roll = _value(loop, "sensors", "roll")
    assert roll == pytest.approx(frame_roll(mm, sim.data.q)[1], abs=1e-9)
    # ISO 8855: leaning into a left turn (r > 0) is a negative roll
    assert roll == pytest.approx(-math.atan(u * r / 9.81) * (1.0 + tyre_lean_ratio(mm)), rel=0.05)
    assert _value(loop, "sensors", "wheel_speed_rear") * 0.30 == pytest.approx(u, rel=0.05)
    assert _value(loop, "sensors", "fork_travel") > 0.0 and _value(loop, "sensors", "shock_travel") > 0.0


def test_ecu_commands_replace_the_riders_demand_and_time_out_to_it():
    """A valid throttle command replaces the rider's demand, the assist torque adds to the rider's, and
    while they arrive their time-out flags stay clear, in the receiver and in every SIM_STATUS frame sent
    (as the ECU decodes them with the DBC); when the ECU goes silent the time-out flags rise within 3 DBC
    periods (10 ms frame: 30 ms; 2 ms frame: 6 ms) and the rider's own demand acts again."""
    sim, _sc, loop = _loop()
    codec = loop.codec
    inp = sim.state.inp
    rings = loop.rings
    tx = RingReader(rings.heads, H_TX, rings.tx_id.shape[0])
    status_id = codec.status_frame.frame_id
    status = []                                            # (sim time, decoded SIM_STATUS) sent while commanded
    for k in range(100):                                   # 0.2 s of commands: throttle every 10 ms, assist every 2 ms
        if k % 5 == 0:
            loop.rx_writer.put(*codec.encode_command("throttle_cmd", 0.5, k // 5))
        loop.rx_writer.put(*codec.encode_command("assist_torque_cmd", 2.0, k))
        loop.take_frames()
        loop.advance(2)
        assert inp[IN_THROTTLE] == pytest.approx(0.5, abs=1e-4)
        assert sim.parts.u[0] == pytest.approx(inp[IN_RIDER_TORQUE] + 2.0, abs=1e-3)
        assert not loop.rx.faults["throttle_timeout"] and not loop.rx.faults["assist_timeout"], loop.rx.faults
        cap = rings.tx_id.shape[0]
        for n in tx.take():
            if int(rings.tx_id[n % cap]) == status_id and float(rings.tx_t[n % cap]) > 0.0:
                data = int(rings.tx_word[n % cap]).to_bytes(8, "little", signed=True)
                status.append((float(rings.tx_t[n % cap]), codec.db.decode_message(status_id, data)))
    assert loop.rx.accepted == 120
    assert [t for t, _ in status] == pytest.approx([0.1, 0.2])     # SIM_STATUS every 100 ms of the 0.2 s
    for t, frame in status:
        assert frame["fault_throttle_timeout"] == 0 and frame["fault_assist_timeout"] == 0, (t, frame)
    t_silent = loop.sim_time
    faults_at = {}
    while loop.sim_time < t_silent + 0.05:
        loop.advance(1)
        for name in ("throttle_timeout", "assist_timeout"):
            if loop.rx.faults[name] and name not in faults_at:
                faults_at[name] = loop.sim_time - t_silent
    assert faults_at["assist_timeout"] <= 0.006 + 1e-9 and faults_at["throttle_timeout"] <= 0.030 + 1e-9
    assert inp[IN_ASSIST] == 0.0
    assert inp[IN_THROTTLE] == pytest.approx(sim.state.rider_out[RO_THROTTLE]) and _value(loop, "sensors", "throttle") == \
        pytest.approx(_value(loop, "sensors", "rider_throttle"))


def test_without_a_rider_it_falls_and_the_session_stops_with_a_status(tmp_path):
    """`--rider off` at 4 m/s (below the weave speed: a riderless motorcycle is unstable there; at the
    scenario's 12 m/s it rights itself), a controller on the bus that pushes the handlebars (2 N m for
    0.2 s) and goes silent: the motorcycle falls; the loop enters the model-fault state with the fall's
    reason (a message, no NaN, the state of the last good step), as a model failure does."""
    text = (ROOT / "configs" / "scenarios" / "motorcycle_hil.toml").read_text()
    path = ROOT / "configs" / "scenarios" / "motorcycle_hil.toml"
    slow = tmp_path / "slow.toml"
    slow.write_text(text.replace("speed = 12.0           # m/s, rolling", "speed = 4.0  # m/s, rolling").replace(
        '"../', f'"{path.parent}/../'))
    sim, _sc, loop = _loop(rider=False, scenario=slow)
    for k in range(100):
        loop.rx_writer.put(*loop.codec.encode_command("assist_torque_cmd", 2.0, k))
        loop.take_frames()
        loop.advance(2)
    loop.advance(20000)
    assert loop.run_state == "model_fault" and "fell" in loop.message
    assert loop.model_fault.reason == "fell" and loop.model_fault.reason_code == 64
    assert loop.model_fault.sim_time < 20.0 and np.all(np.isfinite(sim.data.q))
    assert abs(_value(loop, "state", "roll_angle")) > 1.0


def test_demo_over_can_end_to_end(tmp_path):
    """`rtsim demo --vehicle motorcycle` (lockstep): the service with the rider inside and the demo
    rider-assist ECU in its own process over the CAN bus (E2E-protected commands from the motorcycle's
    DBC). The recording shows every sensor frame at its DBC period and the assist commands every 2 ms of
    simulated time, all accepted; after the ECU goes silent the assist's time-out is flagged within
    3 periods and the recorded assist torque drops to zero, the rider rides on (no fall); the session
    re-simulates bit for bit from its recording."""
    from bridge.mcap_recorder import read_recording
    from rtsim.service.resim import resim

    rec = tmp_path / "moto.mcap"
    out = subprocess.run([sys.executable, "-m", "rtsim.cli", "demo", "--vehicle", "motorcycle", "--no-zenoh",
                          "--record", str(rec), "--silent-after", "1.5"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=1200,
                         env={**os.environ, "RTSIM_CAN_HUB_PORT": str(free_port())})
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    messages, _ = read_recording(rec)
    codec = Codec(ROOT / "configs" / "can" / "motorcycle.dbc", build_sim(None, VEHICLE, models=MODELS)[0].vm.channels)
    rx = messages["rtsim/motorcycle/can/rx"]
    assist_id = codec.command_frames["assist_torque_cmd"].frame_id
    rx_t = np.array([m.data["time"] for m in rx if m.data["id"] == assist_id])
    assert rx_t.size > 700 and np.allclose(np.diff(rx_t), 2e-3, atol=1e-9)
    tx = messages["rtsim/motorcycle/can/tx"]
    for f in codec.sensor_frames:
        ts = np.array([m.data["time"] for m in tx if m.data["id"] == f.frame_id])
        assert ts.size > 100 and np.allclose(np.diff(ts), f.period, atol=1e-9), f.name
    assert "0 dropped" in out.stdout and "'crc': 0" in out.stdout
    status_id = codec.status_frame.frame_id
    flags = [(m.data["time"], codec.db.decode_message(status_id, bytes.fromhex(m.data["data"]))["fault_assist_timeout"])
             for m in tx if m.data["id"] == status_id]
    assert all(f == 0 for ts, f in flags if rx_t[0] + 0.01 < ts <= rx_t[-1])
    assert any(f == 1 for ts, f in flags if ts > rx_t[-1])
    st = messages["rtsim/motorcycle/state"]
    t = np.array([m.data["time"] for m in st])
    assist = np.array([m.data["assist_torque"] for m in st])
    assert np.any(assist[t <= rx_t[-1]] != 0.0) and np.all(assist[t > rx_t[-1] + 0.006 + 1e-9] == 0.0)
    assert t[-1] > rx_t[-1] + 0.2 and np.max(np.abs([m.data["roll_angle"] for m in st])) < 1.0
    report = resim(rec)
    assert report["identical"], report


def test_identified_effects_stop_the_service_and_the_offline_ride(tmp_path):
    """A two-wheeler file with [effects] as `rtsim validate` writes them: the service and the offline ride
    apply none of them (the validation replay does), so both stop with an error naming them rather than run
    the nominal model under a file that says otherwise."""
    from rtsim.errors import ConfigError
    from rtsim.validate.configwrite import _rebase
    from rtsim.vehicle.motorcycle.offline import prepare

    out = tmp_path / "motorcycle_validated.toml"
    out.write_text(_rebase(VEHICLE.read_text(), VEHICLE.parent, tmp_path) + "\n[effects.brake_friction]\nscale = 0.9\n")
    with pytest.raises(ConfigError, match=r"\[effects\] \(brake_friction\).*not yet by the service"):
        build_sim(ROOT / "configs" / "scenarios" / "motorcycle_hil.toml", out, models={})
    with pytest.raises(ConfigError, match=r"\[effects\] \(brake_friction\).*not yet by the offline ride"):
        prepare(out, load_scenario(ROOT / "configs" / "scenarios" / "motorcycle_steady_turn.toml", check_files=True))
