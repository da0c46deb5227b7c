"""The EPS car in the loop (issue 12, item 6): the controller under test commands the motor current over
CAN from the car's own DBC (configs/can/eps_car.dbc), the driver is the scenario's inside the service.

In-process tests run the service's loop (``HilLoop``, the same compiled step as ``rtsim serve``) in fast
mode and play the demo EPS controller (``drivers.eps_demo.EpsController``) on the frames the step queued
for sending: each step's sensor frames are decoded, the controller's command frame is put in the receive
ring and taken before the next step, as the CAN reader thread would. Everything is simulated time, so
the assertions hold on a loaded machine. References: the vehicle's path in angle mode does not depend on
the assistance (the offline run of the same scenario with the built-in law), the current loop's
steady state (current = command), the watchdog's time-out (3 DBC periods), the frames' DBC periods.

The last test runs ``rtsim demo --vehicle eps_car`` (the service and the demo controller as separate
processes over the loopback CAN hub, lockstep) and checks the recording: a command every 1 ms, the car
turning, the safe state within 3 periods of the controller going silent, the fault flagged.
"""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from bridge.can_codec import Codec
from bridge.mcap_recorder import read_recording
from drivers.scenario import load_scenario
from drivers.eps_demo import EPS_FRAMES, EpsController
from rtsim.service.loop import HilLoop
from rtsim.service.rings import H_TX, RingReader
from rtsim.service.server import build_sim
from rtsim.vehicle.offline import prepare, run
from service_harness import ROOT, free_port

VEHICLE = ROOT / "configs" / "vehicles" / "eps_car.toml"
LS1 = ROOT / "configs" / "scenarios" / "step_steer_80kph.toml"
SILENT_AT = 3.0          # s: the controller stops commanding


class Bench:
    """The loop plus the demo controller, frame by frame (see the module docstring)."""

    def __init__(self, scenario=LS1):
        self.sim, self.sc = build_sim(scenario, VEHICLE)
        self.codec = Codec(self.sim.vm.dbc, self.sim.vm.channels)
        self.loop = HilLoop(self.sim, self.codec, mode="fast", driver=self.sc.driver())
        self.ctl = EpsController(self.codec)
        self.tx = RingReader(self.loop.rings.heads, H_TX, self.loop.rings.tx_id.shape[0])
        self.sent_ids: list[tuple[float, int]] = []          # (sim time, frame id) of every frame sent
        self.rows: list[tuple] = []

    def step(self, command: bool = True) -> None:
        r = self.loop.rings
        cap = r.tx_id.shape[0]
        sample = False
        for n in self.tx.take():
            fid, word, t = int(r.tx_id[n % cap]), int(r.tx_word[n % cap]), float(r.tx_t[n % cap])
            self.sent_ids.append((t, fid))
            if self.ctl.decoder.receive(fid, word.to_bytes(8, "little", signed=True)):
                self.ctl.on_sample(self.ctl.decoder.time, self.ctl.decoder.values)
                sample = True
        if sample and command:
            self.loop.rx_writer.put(*self.ctl.command_frames()[0])
        self.loop.take_frames()
        self.loop.advance(1)
        v = self.loop.ls.values
        names = self.codec.channels.sensor_names
        self.rows.append((self.loop.sim_time, *(v[names.index(n)] for n in (
            "accel_y", "gyro_z", "steering_torque", "eps_motor_current", "eps_power_stage")),
            self.ctl.command))

    def run_until(self, t_end: float, command=lambda t: True) -> None:
        while self.loop.sim_time < t_end - 1e-9:
            self.step(command(self.loop.sim_time))

    @property
    def table(self) -> np.ndarray:
        return np.array(self.rows)     # time, ay, yaw rate, torsion-bar torque, current, stage, command


@pytest.fixture(scope="module")
def bench():
    b = Bench()
    b.run_until(SILENT_AT)
    b.accepted_before_silence = b.loop.rx.accepted
    b.run_until(SILENT_AT + 0.05, command=lambda t: False)
    return b


@pytest.fixture(scope="module")
def offline_ls1():
    sim, sc = prepare(VEHICLE, load_scenario(LS1, check_files=True))
    res = run(sim, sc)
    return res


def test_commands_every_period_and_the_car_turns_as_offline(bench, offline_ls1):
    """One accepted command per 1 ms step while the controller runs; the EPS frames go out every step,
    the car frames every 10 (their DBC periods). In angle mode the car's path does not depend on the
    assistance: the lateral acceleration reached equals the offline run's (built-in assistance law)."""
    steps = int(round(SILENT_AT / 1e-3))
    # the first command answers the first sample (after step 1): every later step had a fresh one
    assert bench.accepted_before_silence == steps - 1
    assert bench.loop.rx.counters["crc"] == bench.loop.rx.counters["counter"] == 0
    sent = {}
    for t, fid in bench.sent_ids:
        sent.setdefault(fid, []).append(t)
    for f in bench.codec.sensor_frames:
        gaps = np.diff(sent[f.frame_id])
        assert np.allclose(gaps, f.period, atol=1e-9), f.name
    assert {f.name for f in bench.codec.sensor_frames if f.period == 1e-3} == set(EPS_FRAMES)
    tab = bench.table
    steady = (tab[:, 0] > 2.5) & (tab[:, 0] <= SILENT_AT)
    ay_loop = tab[steady, 1].mean()
    cols = offline_ls1.columns
    t_off = offline_ls1.data[:, cols.index("time")]
    ay_off = offline_ls1.data[(t_off > 2.5) & (t_off <= SILENT_AT), cols.index("accel_y")].mean()
    assert ay_loop > 0.3 * 9.81 and tab[steady, 2].mean() > 0.1      # turning left
    assert ay_loop == pytest.approx(ay_off, rel=0.01)


def test_the_drive_follows_the_controllers_current(bench):
    """With the stage on, the motor current follows the controller's command (the drive's current
    loop: feed-forward of R i and the back-emf plus proportional feedback; 2 ms time constant): in the
    steady turn the measured current equals the command of the previous sample within 2 % + 0.1 A."""
    tab = bench.table
    steady = np.flatnonzero((tab[:, 0] > 2.5) & (tab[:, 0] <= SILENT_AT))
    cmd_prev = tab[steady - 1, 6]
    assert np.all(tab[steady, 5] == 1.0)
    assert np.abs(cmd_prev).mean() > 2.0                                   # it does assist
    assert np.all(np.abs(tab[steady, 4] - cmd_prev) <= 0.02 * np.abs(cmd_prev) + 0.1)


def test_silent_controller_safe_state_within_three_periods(bench):
    """The controller stops at SILENT_AT: the watchdog (3 DBC periods) switches the power stage off
    within 3 periods of the first missing command, the current drops to zero, the status flags the
    time-out, and the safe state is latched (``eps_safe_state``)."""
    tab = bench.table
    first_missing = SILENT_AT          # the last command answered the sample at SILENT_AT - 1 ms
    off = tab[(tab[:, 5] == 0.0) & (tab[:, 0] > 1.0), 0]
    # exactly: no command taken for more than 3 ms after the last (at SILENT_AT - 1 ms) first holds in the
    # step starting 3 ms after the first missing one; the sample after that step shows the stage off
    assert off.size and off[0] == pytest.approx(first_missing + 3e-3 + 1e-3, abs=1e-9)
    assert np.all(tab[tab[:, 0] >= off[0], 4] == 0.0)                      # no current: assist off
    faults = bench.loop.faults()
    assert faults["eps_timeout"] and faults["eps_safe_state"]
    assert bench.loop.rx.accepted == bench.accepted_before_silence


def test_safe_state_is_latched_until_reset():
    """Commands that resume after the time-out do not switch the stage back on (a latched fault, as an
    EPS ECU's safe state); a new session (reset) starts with the stage off until the first command."""
    b = Bench()
    b.run_until(0.2)
    b.run_until(0.21, command=lambda t: False)
    b.run_until(0.3)
    tab = b.table
    assert tab[(tab[:, 0] > 0.01) & (tab[:, 0] <= 0.2), 5].min() == 1.0
    assert np.all(tab[tab[:, 0] > 0.21, 5] == 0.0)
    assert b.loop.faults()["eps_safe_state"] and not b.loop.faults()["eps_timeout"]
    sim, sc = build_sim(LS1, VEHICLE)
    b.loop._control("reset", {"_sim": sim, "_name": sc.name, "_driver": sc.driver()})
    assert not b.loop.faults()["eps_safe_state"] and not sim.eps_stage_on


def test_live_driver_input_overrides_the_scenario():
    """The ``driver`` control (live inputs: a person at a wheel through Zenoh) replaces the scenario's
    steering-wheel angle until released; only channels the in-loop driver drives, within their limits."""
    b = Bench()
    ok = b.loop._control("driver", {"steering_wheel_angle_cmd": -0.3})
    assert ok["ok"] and ok["live"] == {"steering_wheel_angle_cmd": -0.3}
    b.run_until(1.5)                               # past the scenario's step (+35 deg at 1 s)
    assert b.sim.io.commands[2] == -0.3
    assert b.table[-1, 2] < -0.05                  # turning right, as the live wheel says
    assert not b.loop._control("driver", {"motor_current_cmd": 1.0})["ok"]
    assert not b.loop._control("driver", {"steering_wheel_angle_cmd": 100.0})["ok"]
    assert b.loop._control("driver", {"steering_wheel_angle_cmd": None})["live"] == {}
    b.run_until(1.6)
    assert b.sim.io.commands[2] == pytest.approx(0.6108652382)


def test_demo_over_can_end_to_end(tmp_path):
    """`rtsim demo --vehicle eps_car` (lockstep): the demo controller's commands arrive every 1 ms of
    simulated time (the recorded receive stamps), the car turns, and after the controller goes silent the
    recorded EPS frames show the stage off within 3 periods, with the time-out flagged in the status."""
    rec = tmp_path / "eps.mcap"
    out = subprocess.run([sys.executable, "-m", "rtsim.cli", "demo", "--vehicle", "eps_car", "--no-zenoh",
                          "--record", str(rec), "--duration", "2.5", "--silent-after", "2.0"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=1200,
                         env={**os.environ, "RTSIM_CAN_HUB_PORT": str(free_port())})
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    messages, _ = read_recording(rec)
    codec = Codec(ROOT / "configs" / "can" / "eps_car.dbc", build_sim(LS1, VEHICLE)[0].vm.channels)
    cmd_id = codec.command_frames["motor_current_cmd"].frame_id
    rx_t = np.array([m.data["time"] for m in messages["rtsim/eps_car/can/rx"] if m.data["id"] == cmd_id])
    assert rx_t.size > 1900 and np.allclose(np.diff(rx_t), 1e-3, atol=1e-9)
    sens = messages["rtsim/eps_car/sensors"]
    t = np.array([m.data["time"] for m in sens])
    stage = np.array([m.data["eps_power_stage"] for m in sens])
    gz = np.array([m.data["gyro_z"] for m in sens])
    assert gz[(t > 1.8) & (t < 2.0)].mean() > 0.1
    off = t[(stage == 0.0) & (t > rx_t[0] + 0.01)]
    assert off.size and off[0] == pytest.approx(rx_t[-1] + 1e-3 + 3e-3 + 1e-3, abs=1e-9)   # (as above)
    status_id = codec.status_frame.frame_id
    db = codec.db
    flags = [(m.data["time"], db.decode_message(status_id, bytes.fromhex(m.data["data"]))["fault_eps_timeout"])
             for m in messages["rtsim/eps_car/can/tx"] if m.data["id"] == status_id]
    assert all(f == 0 for ts, f in flags if rx_t[0] + 0.01 < ts <= rx_t[-1])
    assert any(f == 1 for ts, f in flags if ts > off[0])
    assert "power stage off" in out.stdout
