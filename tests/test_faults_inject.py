"""Every fault kind of rtsim.faults acts exactly at its configured step, in the service's own compiled step
(HilLoop in lockstep mode, in process, no bus): the sensor samples and frames are read from the loop's rings
and compared, step by step, with an unfaulted run of the same session (the service is deterministic). Onsets
at 0.1 s (step 100: a sensor sample), ends after 0.05 s (step 150)."""
from __future__ import annotations

import math

import cantools
import numpy as np
import pytest

from bridge.can_codec import Codec
from bridge.can_e2e import C_ACCEPTED, C_CRC, C_JUMP
from rtsim.configfile import validate
from rtsim.errors import ConfigError
from rtsim.faults.spec import FaultSpec
from rtsim.service.loop import HilLoop
from rtsim.service.rings import H_CMD, H_SENSOR, H_STATE, H_TX
from rtsim.service.server import build_sim

ON, OFF = 100, 150           # steps: onset 0.1 s, end 0.15 s (dt 1 ms)
STEPS = 220
AT = dict(at=0.1, duration=0.05)
MOVING = "step_steer_80kph"  # a car at 80 km/h, coasting with the watchdog's brake hold (no ECU)


class Run:
    """A lockstep session of ``steps`` steps: per step, ``feed(loop, k)`` may put frames (taken at k)."""

    def __init__(self, models, faults=(), steps=STEPS, scenario=None, feed=None):
        from rtsim.vehicle.registry import resolve_scenario
        sim, sc = build_sim(resolve_scenario(scenario) if scenario else None, None, models=models)
        self.sim = sim
        specs = [validate(FaultSpec, f, "test") for f in faults]
        self.loop = loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="lockstep", driver=sc.driver(),
                                   faults=specs)
        self.codec = loop.codec
        self.names = sim.vm.channels.sensor_names
        self.snap = {}               # step -> what probe(sim) returned after it
        self.probe = None
        if feed is None:
            loop.advance(steps)
        else:
            for k in range(steps):
                feed(loop, k)
                loop.take_frames()
                loop.advance(1)
        r = loop.rings
        dt = sim.dt
        n = int(r.heads[H_SENSOR])
        self.sensors = {int(round(r.sensor_t[j] / dt)): r.sensor_v[j].copy() for j in range(n)}
        n = int(r.heads[H_STATE])
        self.state = {int(round(r.state_t[j] / dt)): r.state_v[j].copy() for j in range(n)}
        n = int(r.heads[H_TX])
        self.tx = [(int(round(r.tx_t[j] / dt)), int(r.tx_id[j]), int(r.tx_word[j])) for j in range(n)]
        n = int(r.heads[H_CMD])
        self.cmd = [(int(round(r.cmd_t[j] / dt)), int(r.cmd_meta[j, 0]), int(r.cmd_meta[j, 1])) for j in range(n)]
        self.events = [(e["id"], e["event"], e["step"]) for topic, e in loop.event_log if topic == "faults"]

    def value(self, k, name):
        return self.sensors[k][self.names.index(name)]

    def state_value(self, k, name):
        return self.state[k][self.sim.vm.channels.state_names.index(name)]

    def sent(self, frame_id):
        """Steps at which frame ``frame_id`` was sent, and their payloads."""
        return [(k, w) for k, f, w in self.tx if f == frame_id]

    def frame_id(self, channel):
        return self.codec.frames[self.codec.sensor_frame_of[channel]].frame_id


@pytest.fixture(scope="module")
def models():
    return {}


_REF: dict = {}


def ref(models, scenario=None) -> Run:
    if scenario not in _REF:
        _REF[scenario] = Run(models, scenario=scenario)
    return _REF[scenario]


def samples(run):
    return sorted(run.sensors)


# ---- sensor faults ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind, params, expect", [
    ("stuck_value", {"value": 3.25}, lambda r, k, x: 3.25),
    ("offset", {"offset": 0.5}, lambda r, k, x: x + 0.5),
    ("drift", {"rate": 2.0}, lambda r, k, x: x + 2.0 * ((k - ON) * 0.001)),
    ("gain", {"gain": -1.5}, lambda r, k, x: x * -1.5),
    ("stuck_last", {}, lambda r, k, x: r.value(ON - 2, "accel_z")),
    ("delay", {"delay": 0.01}, lambda r, k, x: r.value(k - 10, "accel_z")),
    ("out_of_range", {"value": 80.0}, lambda r, k, x: 80.0),
])
def test_sensor_fault_acts_from_its_onset_sample_to_its_end(models, kind, params, expect):
    base = ref(models)
    run = Run(models, [dict(id="f", kind=kind, target="accel_z", **params, **AT)])
    for k in samples(base):
        x = base.value(k, "accel_z")
        want = expect(base, k, x) if ON <= k < OFF else x
        assert run.value(k, "accel_z") == want, (k, run.value(k, "accel_z"), want)
        others = [n for n in run.names if n != "accel_z"]
        assert all(run.value(k, n) == base.value(k, n) for n in others)
    assert run.events == [("f", "onset", ON), ("f", "end", OFF)]


def test_out_of_range_value_reaches_the_frame_saturated(models):
    run = Run(models, [dict(id="f", kind="out_of_range", target="accel_z", value=80.0, **AT)])
    db = cantools.database.load_file(str(run.codec.path))
    fid = run.frame_id("accel_z")
    got = {k: db.decode_message(fid, w.to_bytes(8, "little", signed=True))["accel_z"] for k, w in run.sent(fid)}
    assert got[ON - 2] < 20 and got[ON] == pytest.approx(50.0, abs=0.002) and got[OFF] < 20


def test_out_of_range_refuses_a_value_inside_the_range(models):
    with pytest.raises(ConfigError, match=r"faults: faults\[0\].value = 3.0: inside the DBC's range of accel_z"):
        Run(models, [dict(id="f", kind="out_of_range", target="accel_z", value=3.0, **AT)], steps=1)


def test_noise_burst_is_bounded_seeded_and_only_in_its_window(models):
    base = ref(models)
    spec = [dict(id="n", kind="noise_burst", target="gyro_z", amplitude=0.2, seed=5, **AT)]
    a, b = Run(models, spec), Run(models, spec)
    other = Run(models, [dict(spec[0], seed=6)])
    diffs = []
    for k in samples(base):
        x = base.value(k, "gyro_z")
        assert a.value(k, "gyro_z") == b.value(k, "gyro_z")
        if ON <= k < OFF:
            d = a.value(k, "gyro_z") - x
            assert abs(d) <= 0.2
            diffs.append(d)
        else:
            assert a.value(k, "gyro_z") == x
    assert len(set(diffs)) == len(diffs) == (OFF - ON) // 2 and np.std(diffs) > 0.05
    assert any(other.value(k, "gyro_z") != a.value(k, "gyro_z") for k in range(ON, OFF, 2))


def test_dropout_stops_the_channels_frame_only(models):
    base = ref(models)
    run = Run(models, [dict(id="d", kind="dropout", target="gyro_z", **AT)])
    fid = run.frame_id("gyro_z")
    steps = [k for k, _ in run.sent(fid)]
    assert steps == [k for k, _ in base.sent(fid) if not ON <= k < OFF]
    other = run.frame_id("accel_x")
    assert run.sent(other) == base.sent(other)
    assert all(run.value(k, "gyro_z") == base.value(k, "gyro_z") for k in samples(base))


# ---- bus faults on the frames the simulator sends ----------------------------------------------------------
def test_loss_pattern_loses_n_of_every_m_from_the_onset(models):
    base = ref(models)
    fid = base.frame_id("accel_x")
    run = Run(models, [dict(id="l", kind="loss", target="SIM_IMU_ACCEL", n=2, m=3, **AT)])
    want = [(k, w) for i, (k, w) in enumerate(base.sent(fid))
            if not (ON <= k < OFF and ((k - ON) // 2) % 3 < 2)]
    assert run.sent(fid) == want


def test_loss_probability_is_seeded_and_only_in_its_window(models):
    base = ref(models)
    fid = base.frame_id("accel_x")
    spec = [dict(id="l", kind="loss", target=fid, probability=0.5, seed=11, **AT)]
    a, b = Run(models, spec), Run(models, spec)
    assert a.sent(fid) == b.sent(fid)
    lost = sorted(set(base.sent(fid)) - set(a.sent(fid)))
    assert lost and all(ON <= k < OFF for k, _ in lost)
    assert 5 <= len(lost) <= 20            # 25 frames at p = 0.5: outside 5..20 has probability < 1e-3
    assert a.loop.faults_status()["lost_out"] == len(lost)


def test_frame_delay_sends_each_frame_late_with_its_payload(models):
    base = ref(models)
    fid = base.frame_id("accel_x")
    run = Run(models, [dict(id="d", kind="frame_delay", target="SIM_IMU_ACCEL", delay=0.005, **AT)])
    want = sorted([(k + 5, w) if ON <= k < OFF else (k, w) for k, w in base.sent(fid)])
    assert sorted(run.sent(fid)) == want


def test_status_frame_loss_and_babbling_id(models):
    base = ref(models)
    st = base.codec.status_frame.frame_id
    run = Run(models, [dict(id="s", kind="loss", target="SIM_STATUS", at=0.1),
                       dict(id="b", kind="babble", target=0x7A0, period=0.02, payload=0x0807060504030201, **AT)])
    assert [k for k, _ in run.sent(st)] == [k for k, _ in base.sent(st) if k < ON]
    assert run.sent(0x7A0) == [(k, 0x0807060504030201) for k in range(ON, OFF, 20)]


def test_bus_off_silences_every_frame_in_and_out(models):
    codec_ctr = {"n": 0}

    def feed(loop, k):
        if k % 10 == 0:
            fid, data = loop.codec.encode_command("brake_pressure_cmd", 2000.0, codec_ctr["n"] % 16)
            codec_ctr["n"] += 1
            loop.rx_writer.put(fid, data)
    base = Run(models, feed=feed)
    codec_ctr["n"] = 0
    run = Run(models, [dict(id="off", kind="bus_off", target="bus", **AT)], feed=feed)
    assert [x for x in run.tx if ON <= x[0] < OFF] == []
    # (after it the payloads differ: the commands timed out meanwhile; the frames and their steps do not)
    assert [x[:2] for x in run.tx if not ON <= x[0] < OFF] == [x[:2] for x in base.tx if not ON <= x[0] < OFF]
    assert [x for x in run.tx if x[0] < ON] == [x for x in base.tx if x[0] < ON]
    # commands: none taken while the bus is off (5 frames), then the receiver resynchronises
    acc = [k for k, kind, i in run.cmd if kind == 0]
    assert not [k for k in acc if ON <= k < OFF] and [k for k in acc if k < ON] == [k for k, kind, _ in base.cmd
                                                                                 if kind == 0 and k < ON]
    assert run.loop.faults_status()["lost_in"] == 5


# ---- bus faults on the frames the simulator takes ----------------------------------------------------------
def _brake_feed():
    ctr = {"n": 0}

    def feed(loop, k):
        if k % 10 == 0:
            fid, data = loop.codec.encode_command("brake_pressure_cmd", 1000.0 + k, ctr["n"] % 16)
            ctr["n"] += 1
            loop.rx_writer.put(fid, data)
    return feed


def test_received_frame_loss_pattern(models):
    run = Run(models, [dict(id="l", kind="loss", target="BRAKE_CMD", n=1, m=1, **AT)], feed=_brake_feed())
    acc = [k for k, kind, _ in run.cmd if kind == 0]
    assert [k for k in acc if k < ON] == list(range(0, ON, 10))
    assert not [k for k in acc if ON <= k < OFF]
    assert run.loop.faults_status()["lost_in"] == 5


def test_received_frame_delay_takes_each_frame_late(models):
    run = Run(models, [dict(id="d", kind="frame_delay", target="BRAKE_CMD", delay=0.004, **AT)],
              feed=_brake_feed())
    acc = [k for k, kind, _ in run.cmd if kind == 0]
    assert acc == [k + 4 if ON <= k < OFF else k for k in range(0, STEPS, 10)]
    v = run.loop.rx.state.fv
    assert v is not None


def test_corrupt_crc_is_rejected_by_the_e2e_check(models):
    run = Run(models, [dict(id="c", kind="corrupt_crc", target="BRAKE_CMD", **AT)], feed=_brake_feed())
    counts = run.loop.rx.state.counts
    assert counts[C_CRC] == 5
    assert not [k for k, kind, _ in run.cmd if kind == 0 and ON <= k < OFF]


def test_corrupt_counter_is_seen_as_a_jump(models):
    run = Run(models, [dict(id="c", kind="corrupt_counter", target="BRAKE_CMD", add=8, at=0.1, duration=0.001)],
              feed=_brake_feed())
    counts = run.loop.rx.state.counts
    assert counts[C_CRC] == 0 and counts[C_JUMP] >= 1
    assert ON not in [k for k, kind, _ in run.cmd if kind == 0]
    assert counts[C_ACCEPTED] < STEPS // 10


def test_corrupt_faults_refuse_a_frame_the_simulator_sends(models):
    with pytest.raises(ConfigError, match=r"target = 'SIM_IMU_ACCEL': SIM_IMU_ACCEL is sent by the simulator"):
        Run(models, [dict(id="c", kind="corrupt_crc", target="SIM_IMU_ACCEL", **AT)], steps=1)
    with pytest.raises(ConfigError, match="not a frame the simulator sends or takes"):
        Run(models, [dict(id="c", kind="loss", target="NOPE", **AT)], steps=1)


# ---- actuator faults -------------------------------------------------------------------------------------
class Stepper:
    """A session stepped one step at a time, ``probe(sim)`` read after each step."""

    def __init__(self, models, faults, probe, steps=STEPS, scenario=MOVING, feed=None):
        from rtsim.vehicle.registry import resolve_scenario
        sim, sc = build_sim(resolve_scenario(scenario) if scenario else None, None, models=models)
        specs = [validate(FaultSpec, f, "test") for f in faults]
        loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="lockstep", driver=sc.driver(), faults=specs)
        self.at = {}
        for k in range(steps):
            if feed is not None:
                feed(loop, k)
                loop.take_frames()
            loop.advance(1)
            self.at[loop.k] = probe(sim)
        self.loop = loop


def test_brake_loss_removes_one_wheels_torque_from_the_step(models):
    from rtsim.vehicle.kit.brake import BS_TAU_SLIDE

    def probe(sim):
        return sim.states.brake[BS_TAU_SLIDE:BS_TAU_SLIDE + 4].copy()
    base = Stepper(models, [], probe)
    run = Stepper(models, [dict(id="b", kind="brake_loss", target="brake_fl", **AT)], probe)
    for k in base.at:
        want = base.at[k].copy()
        if ON < k <= OFF:
            want[0] = 0.0
        if k <= ON:
            assert np.array_equal(run.at[k], base.at[k]), k
        elif k <= OFF:
            assert run.at[k][0] == 0.0 and base.at[k][0] > 100.0, k
    assert run.at[OFF + 1][0] > 100.0          # restored: the step from the end on brakes again


def test_caliper_stuck_holds_one_wheels_torque_while_the_pressure_changes(models):
    from rtsim.vehicle.kit.brake import BS_TAU_SLIDE

    def probe(sim):
        return sim.states.brake[BS_TAU_SLIDE:BS_TAU_SLIDE + 4].copy()

    def feed(loop, k):      # 6 MPa until 0.12 s, then released
        if k % 10 == 0:
            fid, data = loop.codec.encode_command("brake_pressure_cmd", 6000.0 if k < 120 else 0.0, (k // 10) % 16)
            loop.rx_writer.put(fid, data)
    end = 200
    run = Stepper(models, [dict(id="c", kind="caliper_stuck", target="brake_rl", at=0.1, duration=0.1)], probe,
                  feed=feed)
    held = run.at[ON][2]
    assert held > 100.0 and run.at[ON + 1][2] == held
    assert run.at[119][3] > held                # the pressure still rose: the other rear wheel followed it
    for k in range(ON + 1, end + 1):
        assert run.at[k][2] == held, k
    assert run.at[end][3] < 0.5 * held          # the other rear wheel followed the release
    assert run.at[end + 1][2] == run.at[end + 1][3] < 0.5 * held    # ended: it follows the pressure again


def test_stuck_throttle_from_the_step(models):
    from rtsim.vehicle.car.step import CMD_THROTTLE

    def probe(sim):
        return (sim.io.commands[CMD_THROTTLE], sim.io.signals.copy())
    run = Stepper(models, [dict(id="t", kind="stuck_throttle", target="throttle", value=0.6, **AT)], probe,
                  scenario=None)
    base = Stepper(models, [], probe, scenario=None)
    for k in base.at:
        cmd, sig = run.at[k]
        if k <= ON:
            assert cmd == base.at[k][0] == 0.0 and np.array_equal(sig, base.at[k][1]), k
        elif k <= OFF:
            assert cmd == 0.6, k
    assert run.at[ON + 1][1].tolist() != base.at[ON + 1][1].tolist()


def test_steering_motor_failure_gives_no_motor_torque(models):
    from rtsim.vehicle.car.step import CMD_STEER
    from rtsim.vehicle.kit.steering import SO_MOTOR_TORQUE

    def probe(sim):
        return sim.io.st_out[SO_MOTOR_TORQUE]

    def feed(loop, k):
        if k % 10 == 0:
            fid, data = loop.codec.encode_command("steering_wheel_angle_cmd", 1.0, (k // 10) % 16)
            loop.rx_writer.put(fid, data)
    base = Stepper(models, [], probe, feed=feed)
    run = Stepper(models, [dict(id="s", kind="steering_motor_failure", target="steering_motor", **AT)], probe,
                  feed=feed)
    for k in base.at:
        if k <= ON:
            assert run.at[k] == base.at[k], k
        elif k <= OFF:
            assert run.at[k] == 0.0 and abs(base.at[k]) > 0.0, k
    assert abs(run.at[OFF + 1]) > 0.0          # ended: the motor's torque builds up again
    assert CMD_STEER >= 0


def test_a_fault_on_an_actuator_the_vehicle_lacks_is_one_line(models):
    with pytest.raises(ConfigError) as e:
        Run(models, [dict(id="p", kind="power_stage_off", target="eps_power_stage", **AT)], steps=1)
    assert "no such actuator" in str(e.value) and "no power_stage actuator" in str(e.value)
    assert "\n" not in str(e.value)


# ---- triggers ----------------------------------------------------------------------------------------------
def test_condition_on_a_state_channel_starts_at_the_first_sample_that_holds(models):
    base = ref(models, MOVING)
    v0 = base.state_value(10, "speed")
    limit = v0 - 0.3
    first = next(k for k in sorted(base.state) if base.state_value(k, "speed") < limit)
    run = Run(models, [dict(id="w", kind="offset", target="accel_x", offset=1.0, when=f"speed < {float(limit)!r}",
                            duration=0.02)], scenario=MOVING)
    assert run.events[0] == ("w", "onset", first)
    for k in samples(base):
        want = base.value(k, "accel_x") + (1.0 if first <= k < first + 20 else 0.0)
        assert run.value(k, "accel_x") == want, k


def test_condition_on_a_sensor_magnitude_and_a_follower(models):
    base = ref(models, MOVING)
    ks = samples(base)
    mags = [abs(base.value(k, "accel_x")) for k in ks]
    limit = 0.5 * (max(mags[5:]) + min(mags[5:]))
    first = next(k for k, m in zip(ks, mags) if k > 0 and m > limit)
    run = Run(models, [dict(id="w", kind="dropout", target="gyro_x", when=f"abs(accel_x) > {float(limit)!r}",
                            duration=0.01),
                       dict(id="f", kind="stuck_value", target="roll", value=0.1, after="w", after_delay=0.004,
                            duration=0.002)], scenario=MOVING)
    assert run.events[:3] == [("w", "onset", first), ("f", "onset", first + 4), ("f", "end", first + 6)]
    assert run.value(first + 4, "roll") == 0.1 and run.value(first + 2, "roll") == base.value(first + 2, "roll")


def test_live_injection_and_clear_act_from_the_next_step(models):
    base = ref(models)
    sim, sc = build_sim(None, None, models=models)
    loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="lockstep", driver=sc.driver())
    loop.advance(ON - 1)
    bad = loop.apply_control("inject_fault", {"id": "x", "kind": "gain", "target": "accel_q", "gain": 2.0})
    assert not bad["ok"] and "accel_q" in bad["error"] and "not a sensor channel" in bad["error"]
    r = loop.apply_control("inject_fault", {"id": "x", "kind": "gain", "target": "accel_z", "gain": 2.0})
    assert r["ok"] and r["fault"]["state"] == "armed"
    loop.advance(31)
    assert loop.apply_control("clear_fault", {"id": "x"})["fault"]["state"] == "ended"
    loop.advance(40)
    r = loop.rings
    iz = sim.vm.channels.sensor_names.index("accel_z")
    got = {int(round(r.sensor_t[j] / sim.dt)): r.sensor_v[j, iz] for j in range(int(r.heads[H_SENSOR]))}
    for k, v in got.items():
        x = base.value(k, "accel_z")
        assert v == (2.0 * x if ON <= k <= ON + 30 else x), k
    ev = [(e["id"], e["event"], e["step"]) for t, e in loop.event_log if t == "faults"]
    assert ev == [("x", "onset", ON), ("x", "end", ON + 30)]
    ctl = [e["op"] for t, e in loop.event_log if t == "control"]
    assert ctl == ["inject_fault", "clear_fault"]
    assert math.isclose(loop.status()["injected_faults"]["faults"][0]["onset_time"], 0.1)


def test_a_frame_fault_leaves_extended_frames_to_the_format_check(models):
    from bridge.can_e2e import C_FORMAT, FLAG_EXTENDED
    feed_classic = _brake_feed()

    def feed(loop, k):
        feed_classic(loop, k)
        if k == ON + 5:                   # the brake command's id as an extended-id frame: never applied
            fid, data = loop.codec.encode_command("brake_pressure_cmd", 9000.0, 15)
            loop.rx_writer.put(fid, data, FLAG_EXTENDED)
    run = Run(models, [dict(id="d", kind="frame_delay", target="BRAKE_CMD", delay=0.004, **AT)], feed=feed)
    assert run.loop.rx.state.counts[C_FORMAT] == 1
    assert [k for k, kind, _ in run.cmd if kind == 0] == [k + 4 if ON <= k < OFF else k for k in range(0, STEPS, 10)]


def test_a_bus_off_ends_on_time_in_the_model_fault_state(models):
    """The model fails (the test-only hook) while the bus is off: the faults' clock goes on, the bus-off ends
    at its step and SIM_STATUS resumes at its period (the model-fault state's bus contract)."""
    sim, sc = build_sim(None, None, models=models)
    loop = HilLoop(sim, Codec(sim.vm.dbc, sim.vm.channels), mode="lockstep", driver=sc.driver(), test_fault_at=0.15,
                   faults=[validate(FaultSpec, dict(id="off", kind="bus_off", target="bus", at=0.1, duration=0.2),
                                    "test")])
    loop.advance(600)
    assert loop.run_state == "model_fault" and loop.k == 600
    r = loop.rings
    st = loop.codec.status_frame.frame_id
    sent = [int(round(r.tx_t[j] / sim.dt)) for j in range(int(r.heads[H_TX])) if r.tx_id[j] == st]
    assert sent == [100 * n for n in range(1, 7) if not 100 <= 100 * n < 300]
    ev = [(e["id"], e["event"], e["step"]) for t, e in loop.event_log if t == "faults"]
    assert ev == [("off", "onset", 100), ("off", "end", 300)]
