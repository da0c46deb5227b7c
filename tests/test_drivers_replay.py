"""Replay of recorded inputs (drivers/replay.py): resampling from 500 Hz to the 1 ms step is exact at
the samples and for linear signals; malformed recordings raise ConfigError naming file, column, row."""
from __future__ import annotations

import numpy as np
import pytest

from drivers.base import INPUT_NAMES
from drivers.driver import Driver
from drivers.replay import read_recording, replay_profiles, resample
from rtsim.errors import ConfigError

DT = 1e-3


def write_csv(path, header, rows):
    """Full-precision CSV (repr of each float round-trips exactly)."""
    lines = [",".join(header)] + [",".join(repr(float(x)) for x in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def recording_500hz(tmp_path, n=1001):
    t = 0.002 * np.arange(n)                              # 500 Hz, 2 s
    brake = 100.0 + 2000.0 * t                            # linear
    steer = 0.1 - 0.05 * t                                # linear
    torque = 50.0 * np.sin(3.0 * t) + 60.0                # not linear
    rows = [(a, b, c, d, d) for a, b, c, d in zip(t, brake, steer, torque)]
    path = write_csv(tmp_path / "rec.csv",
                     ["time", "brake_pressure", "steering_wheel_angle", "wheel_torque_rl", "wheel_torque_rr"], rows)
    return path, t, brake, steer, torque


def test_resampling_exact_for_linear_signals_and_at_samples(tmp_path):
    path, t, brake, steer, torque = recording_500hz(tmp_path)
    rec = read_recording(path)
    assert rec.rate == pytest.approx(500.0)
    assert set(rec.input_columns()) == {"brake_pressure_cmd", "steering_wheel_angle_cmd", "wheel_torque_rl",
                                        "wheel_torque_rr"}
    profs = replay_profiles(rec, DT)
    # on the integrator grid and between grid points: exact for the linear signals
    tq = np.concatenate([DT * np.arange(2001), np.random.default_rng(0).uniform(0.0, 2.0, 300)])
    np.testing.assert_allclose(profs["brake_pressure_cmd"].sample(tq), 100.0 + 2000.0 * tq, rtol=0, atol=1e-9)
    np.testing.assert_allclose(profs["steering_wheel_angle_cmd"].sample(tq), 0.1 - 0.05 * tq, rtol=0, atol=1e-13)
    # at the sample times: the samples themselves, whatever the signal
    np.testing.assert_allclose(profs["wheel_torque_rl"].sample(t), torque, rtol=0, atol=1e-11)
    # between samples of a non-linear signal: the straight line between them
    mid = t[:-1] + 0.001
    np.testing.assert_allclose(profs["wheel_torque_rl"].sample(mid), 0.5 * (torque[:-1] + torque[1:]), atol=1e-11)
    # ends held
    assert profs["brake_pressure_cmd"].sample([-1.0])[0] == brake[0]
    assert profs["brake_pressure_cmd"].sample([50.0])[0] == pytest.approx(brake[-1], abs=1e-9)


def test_zero_order_hold(tmp_path):
    path, t, brake, steer, torque = recording_500hz(tmp_path)
    rec = read_recording(path, channels=["wheel_torque_rl"])
    prof = replay_profiles(rec, DT, {"wheel_torque_rl": "wheel_torque_rl"}, hold=True)["wheel_torque_rl"]
    grid = DT * np.arange(2001)
    expected = torque[np.minimum(np.arange(2001) // 2, t.size - 1)]     # last sample at or before
    assert np.array_equal(prof.sample(grid), expected)
    assert np.array_equal(prof.sample(t + 0.0015), torque)             # held between samples


def test_start_offset_and_irregular_times(tmp_path):
    t = np.array([10.0, 10.002, 10.005, 10.006, 10.01])      # logger clock, irregular
    v = 1000.0 * (t - 10.0)
    path = write_csv(tmp_path / "r.csv", ["time", "brake_pressure_cmd"], list(zip(t, v)))
    rec = read_recording(path)
    prof = replay_profiles(rec, DT)["brake_pressure_cmd"]      # recording start plays at t = 0
    np.testing.assert_allclose(prof.sample(DT * np.arange(11)), np.arange(11.0), atol=1e-9)
    prof = replay_profiles(rec, DT, start=10.005)["brake_pressure_cmd"]
    np.testing.assert_allclose(prof.sample([0.0, 0.003, 0.005]), [5.0, 8.0, 10.0], atol=1e-9)


def test_resample_grid_covers_recording():
    t = np.array([0.0, 0.002, 0.004, 0.0055])
    start, g = resample(t, t * 2.0, DT)
    assert start == 0.0 and g.size == 7                       # 0 .. 6 ms covers 5.5 ms
    np.testing.assert_allclose(g[:6], 2.0 * DT * np.arange(6), atol=1e-15)
    assert g[6] == 2.0 * 0.0055


def test_replay_through_driver(tmp_path):
    path, t, brake, steer, torque = recording_500hz(tmp_path)
    drv = Driver(replay_profiles(read_recording(path), DT))
    out = drv.step(0.5)
    assert out[INPUT_NAMES.index("brake_pressure_cmd")] == pytest.approx(1100.0, abs=1e-9)
    assert out[INPUT_NAMES.index("steering_wheel_angle_cmd")] == pytest.approx(0.075, abs=1e-13)
    assert out[INPUT_NAMES.index("throttle_angle_cmd")] == 0.0


BAD = {
    "non_monotonic": ("time,brake_pressure\n0.000,1\n0.002,2\n0.004,3\n0.004,4\n0.008,5\n",
                      ["'time'", "row 4", "line 5", "increas"]),
    "backwards": ("time,brake_pressure\n0.000,1\n0.002,2\n0.001,3\n",
                  ["'time'", "row 3", "line 4", "increas"]),
    "nan": ("time,brake_pressure\n0.000,1\n0.002,nan\n0.004,3\n",
            ["'brake_pressure'", "row 2", "line 3", "not finite"]),
    "empty_cell": ("time,brake_pressure\n0.000,1\n0.002,\n0.004,3\n",
                   ["'brake_pressure'", "row 2", "line 3", "empty"]),
    "not_a_number": ("time,brake_pressure\n0.000,1\n0.002,2\n0.004,abc\n",
                     ["'brake_pressure'", "row 3", "line 4", "'abc'", "not a number"]),
    "nan_time": ("time,brake_pressure\n0.000,1\nNaN,2\n0.004,3\n",
                 ["'time'", "row 2", "not finite"]),
    "no_time": ("t,brake_pressure\n0.000,1\n0.002,2\n", ["'time'", "columns present: t, brake_pressure"]),
    "no_channel": ("time,speed\n0.000,1\n0.002,2\n", ["no input channel column"]),
    "out_of_range": ("time,brake_pressure\n0.000,1\n0.002,-50\n", ["'brake_pressure'", "row 2", "-50",
                                                                   "allowed 0 .. 20000 kPa"]),
    "one_row": ("time,brake_pressure\n0.000,1\n", ["1 data row"]),
    "duplicate": ("time,brake_pressure,brake_pressure\n0,1,1\n0.002,2,2\n", ["'brake_pressure'", "more than once"]),
    "empty": ("\n\n", ["empty"]),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_recordings_raise_config_error(tmp_path, case):
    text, needles = BAD[case]
    path = tmp_path / f"{case}.csv"
    path.write_text(text)
    with pytest.raises(ConfigError) as exc:
        read_recording(path)
    msg = str(exc.value)
    assert str(path) in msg
    for n in needles:
        assert n in msg, (n, msg)


def test_missing_requested_channel(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("time,brake_pressure\n0.000,1\n0.002,2\n")
    with pytest.raises(ConfigError) as exc:
        read_recording(path, channels=["steering_wheel_angle_cmd"])
    msg = str(exc.value)
    assert str(path) in msg and "steering_wheel_angle_cmd" in msg and "'steering_wheel_angle'" in msg
    with pytest.raises(ConfigError, match="column 'wheel_torque_rl' missing"):
        read_recording(path, columns=["wheel_torque_rl"])
    with pytest.raises(ConfigError, match="cannot open"):
        read_recording(tmp_path / "nope.csv")


def test_comments_blank_lines_and_other_columns(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("# recorded 2009-05-12, run 3\ntime,accel_x,brake_pressure\n\n0.000,n/a,1\n"
                    "# pause\n0.002,0.1,2\n")
    rec = read_recording(path)                          # accel_x is not an input: not parsed
    assert list(rec.columns) == ["brake_pressure"]
    np.testing.assert_array_equal(rec.time, [0.0, 0.002])
    path.write_text("time,brake_pressure\n0.000,1\n0.002,2\n0.001,3\n")
    with pytest.raises(ConfigError, match=r"row 3 \(line 4\)"):
        read_recording(path)
