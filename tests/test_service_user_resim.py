"""A session someone drove from `rtsim view`, or stepped and steered through control requests, re-simulates
bit for bit: the service records every change of the user command source (the ``drive`` op: values,
takeover, release, lapse) on the ``user`` topic with the step it applied it at, and `rtsim resim` applies
them at the same steps.

A lockstep service in this process (CAN on a loopback hub started here, Zenoh off, recording on); the test
is the lockstep ECU on the bus (commands, then SIM_STEP_REQ, then the acknowledgement) and the user (the
``drive`` op through the service's control path, as the view server sends it): the user drives a car no ECU
drives, an ECU's commands keep priority over the user's throttle, the user takes over, hands the steering
back (null), the page goes away (the commands lapse), the user drives again and releases."""
from __future__ import annotations

import math
import threading
import time

import pytest

from bridge import payloads
from bridge.can_bus import LoopbackHub
from bridge.mcap_recorder import read_recording
from rtsim.service.resim import resim
from rtsim.service.server import ServeOptions, Service
from service_harness import send_lockstep_cycle
from waits import EVENT, HUB_START


class _Ecu:
    """The test as a lockstep ECU: optional commands, then SIM_STEP_REQ, then wait for its SIM_STEP_ACK."""

    def __init__(self, bus, codec):
        self.bus, self.codec = bus, codec
        self.ctr = [0, 0, 0, 0]

    def cycle(self, cmd=None, steps=10) -> float:
        send_lockstep_cycle(self.bus, self.codec, self.ctr, cmd, steps)
        deadline = time.monotonic() + EVENT
        while time.monotonic() < deadline:
            msg = self.bus.recv(1.0)
            if msg is not None and msg.arbitration_id == self.codec.step_ack.frame_id:
                t, c = self.codec.decode_step_ack(msg.data)
                if c == self.ctr[3]:
                    return t
        raise AssertionError(f"no SIM_STEP_ACK within {EVENT:g} s")


def test_a_session_driven_by_the_user_resimulates_bit_for_bit(tmp_path):
    rec = tmp_path / "driven.mcap"
    hub = LoopbackHub(0, start_timeout=HUB_START)
    # user_hold: the user's commands never lapse on their own, however slow the machine
    svc = Service(ServeOptions(mode="lockstep", can_interface="remote", can_channel=hub.channel, start_hub=False,
                               zenoh=False, record=rec, user_hold=3600.0), out=lambda *a: None)
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    ecu_cmd = (0.05, 0.0, -0.4)                              # a light throttle, steering right
    try:
        bus = hub.open_bus()
        ecu = _Ecu(bus, svc.codec)

        def drive(**kw):
            r = svc.control({"op": "drive", **kw})
            assert r["ok"], r
            return r

        for k in range(60):                                  # the user alone: throttle, steering left
            if k % 10 == 0:
                drive(throttle_angle_cmd=0.6, brake_pressure_cmd=0.0, steering_wheel_angle_cmd=1.0, seq=k)
            ecu.cycle()
        assert set(svc.loop.drivers().values()) == {"user"}
        for k in range(40):                                  # an ECU on the bus keeps priority
            if k % 10 == 0:
                drive(throttle_angle_cmd=0.3, seq=100 + k)
            ecu.cycle(ecu_cmd)
        assert set(svc.loop.drivers().values()) == {"ecu"}
        r = drive(throttle_angle_cmd=0.8, takeover=True, seq=200)   # the user takes the throttle and brake over
        for _ in range(30):
            ecu.cycle(ecu_cmd)
        r = drive(steering_wheel_angle_cmd=None, seq=201)    # hands the steering back (the ECU's anyway)
        assert r["drivers"]["throttle_angle_cmd"] == "user" and r["drivers"]["steering_wheel_angle_cmd"] == "ecu"
        svc.loop.user_clock = lambda: math.inf                 # the page goes away: its hold runs out
        for _ in range(30):
            ecu.cycle(ecu_cmd)
        assert svc.loop.user_status()["channels"] == {} and set(svc.loop.drivers().values()) == {"ecu"}
        assert svc.loop.user_status()["lapses"] == 1           # counted once, however many steps pass after
        for _ in range(20):                                  # the ECU stops: its commands time out
            ecu.cycle()
        drive(brake_pressure_cmd=500.0, steering_wheel_angle_cmd=-2.0, seq=300)
        for _ in range(20):
            ecu.cycle()
        r = drive(release=True, seq=301)
        assert r["user"]["lapses"] == 1                        # a release is no lapse
        for _ in range(10):
            ecu.cycle()
        bus.shutdown()
    finally:
        svc.stop()
        th.join(EVENT)
        hub.close()
    assert not th.is_alive()

    msgs, info = read_recording(rec)
    changes = [m.data for m in msgs[f"rtsim/{svc.vehicle_id}/user"]]
    for c in changes:
        assert payloads.validation_errors("user", c) == [], c
        assert c["time"] == pytest.approx(c["step"] * 0.001, abs=1e-12)
    assert [c["cause"] for c in changes] == ["drive", "drive", "drive", "drive", "lapse", "drive", "release"]
    assert changes[0]["channels"] == {"throttle_angle_cmd": 0.6, "brake_pressure_cmd": 0.0,
                                      "steering_wheel_angle_cmd": 1.0} and changes[0]["step"] == 0
    assert changes[2]["takeover"] and changes[3]["channels"]["steering_wheel_angle_cmd"] is None
    assert changes[4]["channels"] == dict.fromkeys(changes[0]["channels"]) and not changes[4]["takeover"]
    assert [c["seq"] for c in changes] == [0, 100, 200, 201, 201, 300, 301]
    status = [m.data for m in msgs[f"rtsim/{svc.vehicle_id}/status"]]
    assert any(s["drivers"]["throttle_angle_cmd"] == "user" for s in status)      # the replay's "who drives"

    rep = resim(rec)
    assert rep["user_changes"] == rep["user_changes_applied"] == len(changes)
    assert rep["sensors"]["matched"] > 500 and rep["state"]["matched"] > 100
    assert rep["identical"], (rep["sensors"]["max_abs_diff"], rep["state"]["max_abs_diff"])
    without = resim(rec, user=False)                         # the user's commands made the session
    assert not without["identical"] and without["state"]["max_abs_diff"].get("speed", 0.0) > 0.5


def _serve(tmp_path, hub, name, **kw):
    rec = tmp_path / f"{name}.mcap"
    svc = Service(ServeOptions(mode="lockstep", can_interface="remote", can_channel=hub.channel, start_hub=False,
                               zenoh=False, record=rec, **kw), out=lambda *a: None)
    th = threading.Thread(target=svc.run, daemon=True)
    th.start()
    return svc, th, rec


def _ok(svc, op, **kw):
    r = svc.control({"op": op, **kw})
    assert r["ok"], r
    return r


def test_control_requests_are_recorded_and_resimulated(tmp_path):
    """The control requests that change a run are recorded (``control`` topic, with the step they acted at and
    the order among the user's changes) and `rtsim resim` repeats them: a lockstep session stepped both by the
    ECU's SIM_STEP_REQ frames and by Zenoh ``step`` requests, paused and resumed, the user driving between
    them, re-runs bit for bit, up to the reset that restarts simulation time (the frames and samples after it
    are a new session); the EPS car whose in-loop driver was given a live steering-wheel angle (the ``driver``
    op: turning right while the scenario's driver holds the wheel straight) re-runs bit for bit."""
    hub = LoopbackHub(0, start_timeout=HUB_START)
    try:
        svc, th, rec = _serve(tmp_path, hub, "stepped")
        try:
            bus = hub.open_bus()
            ecu = _Ecu(bus, svc.codec)
            ecu_cmd = (0.2, 0.0, 0.3)
            for k in range(8):
                ecu.cycle(ecu_cmd)
                _ok(svc, "step", n=7 + k)                    # Zenoh steps between the ECU's
            _ok(svc, "pause")
            _ok(svc, "resume")
            _ok(svc, "drive", throttle_angle_cmd=0.7, takeover=True, seq=1)
            _ok(svc, "step", n=40)
            ecu.cycle(ecu_cmd, steps=25)
            _ok(svc, "drive", release=True, seq=2)
            _ok(svc, "step", n=30)
            stepped = svc.loop.k
            _ok(svc, "reset")
            for _ in range(3):                               # a new session after the reset
                ecu.cycle(ecu_cmd)
            bus.shutdown()
        finally:
            svc.stop()
            th.join(EVENT)
        assert not th.is_alive()
        msgs, _ = read_recording(rec)
        control = [m.data for m in msgs[f"rtsim/{svc.vehicle_id}/control"]]
        for c in control:
            assert payloads.validation_errors("control", c) == [], c
        assert [c["op"] for c in control] == ["step"] * 8 + ["pause", "resume", "step", "step", "reset"]
        assert control[0]["args"] == {"n": 7} and control[0]["step"] == 10     # after the ECU's first 10 steps
        user = [m.data for m in msgs[f"rtsim/{svc.vehicle_id}/user"]]
        assert control[9]["order"] < user[0]["order"] < control[10]["order"]
        assert control[-1]["args"] == {"scenario": svc.loop.scenario_name} and control[-1]["step"] == stepped
        rep = resim(rec)
        assert rep["control_ops"] == rep["control_ops_applied"] == 12 and rep["user_changes_applied"] == 2
        assert rep["ended_by"].startswith("reset") and rep["sim_time"] == pytest.approx(stepped * 1e-3)
        assert rep["sensors"]["matched"] > 100 and rep["sensors"]["missing"] == 0
        assert rep["identical"], (rep["sensors"]["max_abs_diff"], rep["state"]["max_abs_diff"])

        from pathlib import Path
        root = Path(__file__).resolve().parents[1]
        svc, th, rec = _serve(tmp_path, hub, "driver", vehicle=root / "configs" / "vehicles" / "eps_car.toml",
                              scenario=root / "configs" / "scenarios" / "step_steer_80kph.toml")
        try:
            _ok(svc, "step", n=200)
            _ok(svc, "driver", steering_wheel_angle_cmd=-0.3)
            _ok(svc, "step", n=300)
            _ok(svc, "driver", steering_wheel_angle_cmd=None)
            _ok(svc, "step", n=100)
        finally:
            svc.stop()
            th.join(EVENT)
        rep = resim(rec)
        assert rep["control_ops"] == rep["control_ops_applied"] == 5 and rep["sim_time"] == pytest.approx(0.6)
        assert rep["identical"], (rep["sensors"]["max_abs_diff"], rep["state"]["max_abs_diff"])
        msgs, _ = read_recording(rec)
        control = [m.data for m in msgs[f"rtsim/{svc.vehicle_id}/control"]]
        assert control[1] == {"time": 0.2, "step": 200, "op": "driver", "args": {"steering_wheel_angle_cmd": -0.3},
                              "order": 1}
        yaw = [m.data["yaw_rate"] for m in msgs[f"rtsim/{svc.vehicle_id}/state"]]
        assert min(yaw) < -0.02          # the live wheel turned the car right: the op made this session
    finally:
        hub.close()


def test_a_malformed_event_in_a_recording_is_a_clear_error():
    """A control or user event that does not match its schema (a hand-edited or foreign recording) stops the
    re-simulation with a message naming the topic, the event and what is wrong, never a traceback."""
    from types import SimpleNamespace

    from rtsim.errors import ConfigError
    from rtsim.service.resim import SessionEvents
    ok = SimpleNamespace(data={"time": 0.0, "step": 0, "op": "pause", "args": {}, "order": 0})
    warp = SimpleNamespace(data={"time": 0.0, "step": 0, "op": "warp", "args": {}, "order": 1})
    assert len(SessionEvents(None, (), [ok]).events) == 1
    with pytest.raises(ConfigError, match=r"control event 1 of the recording is malformed: .*'warp' is not one of"):
        SessionEvents(None, (), [ok, warp])
    with pytest.raises(ConfigError, match=r"user event 0 of the recording is malformed: .*missing required"):
        SessionEvents(None, [SimpleNamespace(data={"time": 0.0})], ())
