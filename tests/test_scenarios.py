"""Scenario files (configs/scenarios/*.toml) and their loader (drivers/scenario.py): every file loads
and describes its manoeuvre; bad values raise ConfigError naming file, key and value."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.base import I_BRAKE, I_STEER, I_THROTTLE, I_TORQUE_RL, I_TORQUE_RR, DriverView
from drivers.scenario import SCENARIO_DIR, load_all, load_scenario
from rtsim.errors import ConfigError

FILES = sorted(SCENARIO_DIR.glob("*.toml"))
DEG = math.pi / 180.0


def test_scenario_dir_has_the_manoeuvres():
    names = {f.stem for f in FILES}
    assert {"straight_line", "step_steer_80kph", "step_steer_braking_80kph", "steady_circle"} <= names


@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_every_scenario_loads_and_runs(path):
    sc = load_scenario(path)
    assert sc.name == path.stem
    assert sc.spec.description
    assert sc.road_path.is_absolute() and sc.road_path.parent.name == "roads"
    drv = sc.driver()
    state = sc.initial_state()
    for t in np.arange(0.0, sc.duration, 0.25):
        out = drv.step(t, state)
        assert np.all(np.isfinite(out))
        assert 0.0 <= out[I_THROTTLE] <= math.pi / 2 and 0.0 <= out[I_BRAKE] <= 20000.0


@pytest.mark.skipif(not (SCENARIO_DIR.parent / "roads").is_dir(), reason="no road configurations yet")
@pytest.mark.parametrize("path", FILES, ids=[f.stem for f in FILES])
def test_referenced_road_files_exist(path):
    sc = load_scenario(path, check_files=True)
    assert sc.road_path.is_file()


def test_load_all():
    assert set(load_all()) == {load_scenario(f).name for f in FILES}


def sampled(sc, times, state=None):
    drv = sc.driver()
    st = sc.initial_state() if state is None else state
    return np.array([drv.step(t, st).copy() for t in times])


def test_straight_line_phases():
    sc = load_scenario(SCENARIO_DIR / "straight_line.toml")
    assert 30.0 <= sc.duration <= 40.0 and sc.dt == 1e-3
    assert sc.road_path.name == "campus.toml"
    assert sc.spec.initial.speed == 0.0
    assert not sc.driver().closed_loop
    assert sc.spec.reference == {"distance": 63.5, "peak_speed": pytest.approx(23.0 / 3.6, abs=0.01)}
    t = np.arange(0.0, sc.duration, 0.01)
    u = sampled(sc, t)
    thr, brk, steer = u[:, I_THROTTLE], u[:, I_BRAKE], u[:, I_STEER]
    assert brk[0] >= 2000.0                                       # held by the brake at the start
    release = np.nonzero(brk == 0.0)[0][0]                        # brake fully off ...
    assert 2.0 <= t[release] - t[np.nonzero(brk < brk[0])[0][0] - 1] <= 3.0 + 1e-9   # ... after a 2-3 s release
    assert np.all(np.diff(brk[:release + 1]) <= 0.0)              # released monotonically
    assert np.all(thr[brk > 0.0] == 0.0)                          # never both pedals
    on = np.nonzero(thr > 0.0)[0]
    assert on.size and t[on[0]] >= t[release]                     # throttle after the release ...
    assert thr[-1] == 0.0 and t[on[-1]] < t[np.nonzero(brk > 0.0)[0][-1]]   # ... released before braking
    late = np.nonzero((t > t[on[-1]]) & (brk > 0.0))[0]
    assert late.size and np.all(np.diff(brk[late]) >= 0.0)       # slow braking, never released again
    assert (brk[late[-1]] - brk[late[0]]) / (t[late[-1]] - t[late[0]] + 1e-9) < 1000.0  # slow: < 1 MPa/s
    assert brk[-1] > 0.0 and np.all(steer == 0.0)


def test_step_steer_80kph():
    sc = load_scenario(SCENARIO_DIR / "step_steer_80kph.toml")
    assert sc.spec.initial.speed == pytest.approx(80.0 / 3.6, abs=0.01)
    assert sc.duration == pytest.approx(6.0) and sc.road_path.name == "flat.toml"
    drv = sc.driver()
    assert drv.flags.tolist() == [1, 0]                           # speed follower, no path follower
    u = sampled(sc, [0.0, 0.999, 1.05, 1.3, 5.9])
    np.testing.assert_allclose(u[:, I_STEER], [0.0, 0.0, u[2, I_STEER], 35 * DEG, 35 * DEG], atol=1e-9)
    assert 0.0 < u[2, I_STEER] < 35 * DEG                         # ramped, 0.1-0.2 s
    ramp = sc.spec.inputs.steering_wheel_angle_cmd.ramp
    assert 0.1 <= ramp <= 0.2
    # slower than the target: the follower opens the throttle; faster: it brakes
    slow = sc.initial_state()
    slow[DriverView.SPEED] = 20.0
    assert sampled(sc, [0.0, 0.1], slow)[-1, I_THROTTLE] > 0.0
    fast = sc.initial_state()
    fast[DriverView.SPEED] = 25.0
    assert sampled(sc, [0.0, 0.1], fast)[-1, I_BRAKE] > 0.0


def test_step_steer_braking_80kph():
    sc = load_scenario(SCENARIO_DIR / "step_steer_braking_80kph.toml")
    assert sc.duration == pytest.approx(9.0) and sc.spec.initial.speed == pytest.approx(22.22)
    u = sampled(sc, [0.0, 0.999, 1.5, 4.9])
    np.testing.assert_allclose(u[:, I_STEER], [0.0, 0.0, 20 * DEG, 20 * DEG], atol=1e-9)
    sf = sc.spec.inputs.speed_follower
    v_ref = np.interp([4.9, 5.0, 7.0, 9.0], sf.time, sf.speed)
    assert v_ref[0] == v_ref[1] == pytest.approx(22.22) and v_ref[2] < v_ref[1] and v_ref[3] < v_ref[2]
    # at 80 km/h after 5 s the deceleration target makes it brake (feed-forward), not before
    st = sc.initial_state()
    u = sampled(sc, np.arange(0.0, 6.0, 0.001), st)
    t = np.arange(0.0, 6.0, 0.001)
    assert np.all(u[(t > 0.5) & (t < 4.99), I_BRAKE] == 0.0)
    assert np.all(u[t > 5.05, I_BRAKE] > 1000.0)


def test_steady_circle():
    sc = load_scenario(SCENARIO_DIR / "steady_circle.toml")
    assert sc.duration >= 60.0 and sc.spec.initial.speed == pytest.approx(10.0)
    u = sampled(sc, [0.0, 2.0, 32.0, 62.0, sc.duration])
    np.testing.assert_allclose(u[:, I_STEER], [0.0, 0.0, 45 * DEG, 90 * DEG, 90 * DEG], atol=1e-9)


# ---------------------------------------------------------------------------------------------------
# Loader behaviour on hand-written files

BASE = """
name = "t"
road = "flat.toml"
duration = 5.0
[initial]
speed = 10.0
[inputs.steering_wheel_angle_cmd]
type = "step"
t0 = 1.0
after = 0.1
"""


STEP = 'type = "step"\nt0 = 1.0\nafter = 0.1\n'
SINE = 'type = "sine"\namplitude = 0.3\nfrequency = 0.2\n'


def write(tmp_path, text, name="sc.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, key, value", [
    (BASE.replace("duration = 5.0", "duration = -2.0"), "duration", "-2.0"),
    (BASE.replace("speed = 10.0", "speed = 120.0"), "initial.speed", "120.0"),
    (BASE + "[inputs.throttle_cmd]\ntype = 'constant'\nvalue = 0.1\n", "inputs.throttle_cmd", "'constant'"),
    (BASE.replace("after = 0.1", "after = 20.0"), "inputs.steering_wheel_angle_cmd.after", "20.0"),
    (BASE.replace('type = "step"', 'type = "stepp"'), "inputs.steering_wheel_angle_cmd.type", "'stepp'"),
    (BASE + "[inputs.brake_pressure_cmd]\ntype = 'table'\ntime = [0, 2, 1]\nvalue = [0, 1, 2]\n",
     "inputs.brake_pressure_cmd.time[2]", "1.0"),
    (BASE.replace("duration = 5.0", "duration = 5.0\ndt = 0.5"), "dt", "0.5"),
    (BASE + "[inputs.speed_follower]\ntime = [0, 1]\nspeed = [10, 101]\n", "inputs.speed_follower.speed[1]", "101"),
    (BASE + "[inputs.speed_follower]\ntime = [0]\nspeed = [10]\nkp = -1\n", "inputs.speed_follower.kp", "-1"),
    (BASE + "[inputs.path_follower]\nx = [0, 1]\ny = [0, 0]\n", "inputs.steering_wheel_angle_cmd", "'step'"),
    (BASE.replace("duration = 5.0", "duration = 5.0\nwheelbase = 2.6"), "wheelbase", "2.6"),
    (BASE.replace("after = 0.1", "after = 0.1\nduration = 3.0"), "inputs.steering_wheel_angle_cmd.duration", "3.0"),
    (BASE.replace(STEP, SINE.replace("frequency = 0.2", "frequency = 0.0")),
     "inputs.steering_wheel_angle_cmd.frequency", "0.0"),
    (BASE.replace(STEP, SINE + "fade_cycles = -1\n"), "inputs.steering_wheel_angle_cmd.fade_cycles", "-1"),
    (BASE.replace(STEP, SINE.replace("amplitude = 0.3", "amplitude = -0.3")),
     "inputs.steering_wheel_angle_cmd.amplitude", "-0.3"),
    (BASE.replace(STEP, SINE + "offset = 12.4\n"), "inputs.steering_wheel_angle_cmd.amplitude", "0.3"),
    (BASE.replace(STEP, SINE + "cycles = 3\n"), "inputs.steering_wheel_angle_cmd.cycles", "3"),
])
def test_bad_values_name_file_key_value(tmp_path, text, key, value):
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as exc:
        load_scenario(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}: {key} = "), msg
    assert value in msg, msg


def test_range_messages_state_the_allowed_range(tmp_path):
    with pytest.raises(ConfigError, match=r"duration = -2.0: out of range \(allowed 0 < duration <= 3600 s\)"):
        load_scenario(write(tmp_path, BASE.replace("duration = 5.0", "duration = -2.0")))
    with pytest.raises(ConfigError, match=r"initial.speed = 120.0: out of range \(allowed 0 <= speed <= 100 m/s\)"):
        load_scenario(write(tmp_path, BASE.replace("speed = 10.0", "speed = 120.0")))
    with pytest.raises(ConfigError, match=r"unknown key \(allowed: throttle_angle_cmd, brake_pressure_cmd, "
                                          r"steering_wheel_angle_cmd, speed_follower, path_follower\)"):
        load_scenario(write(tmp_path, BASE + "[inputs.throttle_cmd]\ntype = 'constant'\nvalue = 0.1\n"))
    # a sum that leaves the channel's range somewhere in the run
    text = BASE + ("[inputs.brake_pressure_cmd]\ntype = 'sum'\n[[inputs.brake_pressure_cmd.terms]]\n"
                   "type = 'constant'\nvalue = 15000\n[[inputs.brake_pressure_cmd.terms]]\ntype = 'step'\n"
                   "t0 = 2.0\nafter = 6000\n")
    with pytest.raises(ConfigError, match=r"inputs.brake_pressure_cmd: the profile reaches 21000 kPa at t = 2 s"):
        load_scenario(write(tmp_path, text))


def test_sine_input(tmp_path):
    """A sine loads into the driver with its start, phase, offset and fade; its ranges are in the
    messages."""
    text = BASE.replace(STEP, SINE + "t0 = 1.0\nphase = 0.5\noffset = 0.02\nfade_cycles = 1.0\n")
    sc = load_scenario(write(tmp_path, text))
    t = np.array([0.0, 1.0, 3.5, 6.0, 6.25, 8.5])
    got = sampled(sc, t)[:, I_STEER]
    w = np.where(t < 1.0, 0.0, np.where(t < 6.0, 0.5 * (1 - np.cos(np.pi * (t - 1.0) / 5.0)), 1.0))
    want = 0.02 + w * 0.3 * np.sin(2 * np.pi * 0.2 * (t - 1.0) + 0.5)
    np.testing.assert_allclose(got, want, atol=1e-12)
    with pytest.raises(ConfigError, match=r"frequency = 500.0: out of range \(allowed 0 < frequency <= 100 Hz\)"):
        load_scenario(write(tmp_path, BASE.replace(STEP, SINE.replace("0.2", "500.0"))))
    with pytest.raises(ConfigError, match=r"phase = 7.0: out of range \(allowed -6.28319 <= phase <= 6.28319 rad\)"):
        load_scenario(write(tmp_path, BASE.replace(STEP, SINE + "phase = 7.0\n")))
    with pytest.raises(ConfigError, match=r"amplitude = 0.3: offset \+12.4 \+- amplitude reaches 12.7, out of "
                                          r"range for steering_wheel_angle_cmd \(allowed -12.5664 .. 12.5664 rad\)"):
        load_scenario(write(tmp_path, BASE.replace(STEP, SINE + "offset = 12.4\n")))


def test_missing_and_syntax_errors(tmp_path):
    with pytest.raises(ConfigError, match=r"sc.toml: duration: missing"):
        load_scenario(write(tmp_path, BASE.replace("duration = 5.0", "")))
    with pytest.raises(ConfigError, match=r"sc.toml: not valid TOML: .*line"):
        load_scenario(write(tmp_path, BASE + "x = = 1\n"))
    with pytest.raises(ConfigError, match=r"cannot read"):
        load_scenario(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match=r"road = 'flat.toml': file not found"):
        load_scenario(write(tmp_path, BASE), check_files=True)


def test_sequence_replay_and_torque_mode(tmp_path):
    t = (0.002 * np.arange(1001)).tolist()
    rows = "\n".join(f"{a!r},{3000.0 - 1000.0 * a!r},{100.0 + 50 * a!r},{110.0 + 50 * a!r}" for a in t)
    (tmp_path / "rec.csv").write_text("time,brake_pressure,wheel_torque_rl,wheel_torque_rr\n" + rows + "\n")
    text = """
name = "replayed"
road = "flat.toml"
duration = 3.0
[inputs.brake_pressure_cmd]
type = "sequence"
[[inputs.brake_pressure_cmd.segments]]
type = "constant"
value = 3000.0
duration = 0.5
[[inputs.brake_pressure_cmd.segments]]
type = "replay"
file = "rec.csv"
[torque_mode.wheel_torque_rl]
type = "replay"
file = "rec.csv"
[torque_mode.wheel_torque_rr]
type = "replay"
file = "rec.csv"
hold = true
"""
    sc = load_scenario(write(tmp_path, text))
    assert sc.torque_mode and len(sc.recordings) == 1
    u = sampled(sc, [0.2, 0.5, 1.0, 1.5011, 2.5, 2.9])
    np.testing.assert_allclose(u[:, I_BRAKE], [3000.0, 3000.0, 2500.0, 3000.0 - 1001.1, 1000.0, 1000.0], atol=1e-6)
    np.testing.assert_allclose(u[:, I_TORQUE_RL], [110.0, 125.0, 150.0, 175.055, 200.0, 200.0], atol=1e-6)
    np.testing.assert_allclose(u[:, I_TORQUE_RR], [120.0, 135.0, 160.0, 185.0, 210.0, 210.0], atol=1e-6)
    assert np.all(u[:, I_THROTTLE] == 0.0)
    # torque mode excludes the throttle
    bad = text + "[inputs.throttle_angle_cmd]\ntype = 'constant'\nvalue = 0.1\n"
    with pytest.raises(ConfigError, match=r"inputs.throttle_angle_cmd = 'constant': not allowed in torque mode"):
        load_scenario(write(tmp_path, bad, "bad.toml"))


def test_bad_replay_file_names_scenario_and_csv(tmp_path):
    (tmp_path / "rec.csv").write_text("time,brake_pressure\n0.0,1.0\n0.002,nan\n0.004,2.0\n")
    text = BASE + "[inputs.brake_pressure_cmd]\ntype = 'replay'\nfile = 'rec.csv'\n"
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as exc:
        load_scenario(path)
    msg = str(exc.value)
    assert msg.startswith(f"{path}: inputs.brake_pressure_cmd.file = 'rec.csv': ")
    assert str(tmp_path / "rec.csv") in msg and "'brake_pressure'" in msg and "row 2" in msg
    (tmp_path / "rec.csv").write_text("time,throttle_angle\n0.0,0.1\n0.002,0.1\n")
    with pytest.raises(ConfigError, match=r"no column for brake_pressure_cmd"):
        load_scenario(path)


def test_path_follower_scenario_closes_the_loop(tmp_path):
    (tmp_path / "path.csv").write_text("x,y\n" + "\n".join(f"{x},{0.0}" for x in range(0, 200, 5)) + "\n")
    text = """
name = "lane"
road = "flat.toml"
duration = 8.0
[initial]
speed = 10.0
y = 0.5
[inputs.speed_follower]
distance = [0.0, 1000.0]
speed = [10.0, 10.0]
[inputs.path_follower]
file = "path.csv"
method = "stanley"
wheelbase = 2.5
"""
    sc = load_scenario(write(tmp_path, text))
    drv = sc.driver()
    assert drv.flags.tolist() == [1, 1]
    st = sc.initial_state()
    out = drv.step(0.0, st)
    out = drv.step(0.01, st)
    assert out[I_STEER] < 0.0                                   # left of the path: steers right
    with pytest.raises(ConfigError, match=r"inputs.path_follower.file = 'missing.csv': .*cannot open"):
        load_scenario(write(tmp_path, text.replace("path.csv", "missing.csv"), "b.toml"))
