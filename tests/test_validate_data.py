"""The data side of the validation workflow (rtsim/validate: data, signals, align, benchmark, stats), on
synthetic runs built here from closed-form signals (no vehicle model): the band against eq. (6) with
Student's t, wheel speeds derived from wheel angles against the analytic derivative, alignment
against known logger offsets, and bad input (different manoeuvres, missing channels, NaNs,
non-monotonic time, one run, two disagreeing runs) giving clear messages and sensible behaviour."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.validate.align import align
from rtsim.validate.benchmark import build_benchmark
from rtsim.validate.data import load_run, load_runs
from rtsim.validate.signals import wheel_speed
from rtsim.validate.stats import band, error_metrics, inside_fraction, t_critical

RATE = 500.0
DURATION = 8.0
R = 0.28


def manoeuvre(t, shift=0.0, amp=1.0, pulse_at=2.0):
    """Closed-form inputs and responses: brake release, a torque pulse, braking; speed is the
    integral of a smooth acceleration (m/s), wheel angle = distance / R."""
    s = t - shift
    brake = np.interp(s, [0.0, 0.5, 1.5, 5.0, 7.0], [2000.0, 2000.0, 0.0, 0.0, 1500.0])
    torque = amp * np.interp(s, [pulse_at, pulse_at + 0.4, pulse_at + 1.6, pulse_at + 2.0], [0, 200.0, 200.0, 0])
    acc = 0.004 * torque - 0.0012 * np.maximum(brake - 100.0, 0.0) * (s > 4.0)
    dt = t[1] - t[0]
    v = np.maximum(np.cumsum(acc) * dt, 0.0)
    dist = np.cumsum(v) * dt
    return {"brake_pressure": brake, "wheel_torque_rl": torque, "wheel_torque_rr": torque, "accel_x": acc,
            **{f"wheel_angle_{w}": dist / R for w in ("fl", "fr", "rl", "rr")}}


def write(path, t, ch, rng=None, noise=True):
    names = list(ch)
    x = np.column_stack([ch[c] for c in names])
    if rng is not None and noise:
        x = x + rng.normal(0.0, 1.0, x.shape) * np.array([2.0 if "brake" in c else 0.5 if "torque" in c else
                                                         0.02 if "accel" in c else 0.001 for c in names])
    with open(path, "w") as fh:
        fh.write(",".join(["time", *names]) + "\n")
        np.savetxt(fh, np.column_stack([t, x]), delimiter=",", fmt="%.10g")
    return path


def make_runs(tmp_path, n=7, offsets=None, seed=0, **kw):
    rng = np.random.default_rng(seed)
    offsets = offsets if offsets is not None else rng.uniform(0.0, 0.3, n)
    paths = []
    for i, off in enumerate(offsets):
        t = np.arange(int(DURATION * RATE)) / RATE
        ch = manoeuvre(t, shift=off, amp=1.0 + rng.normal(0.0, 0.01), **kw)
        paths.append(write(tmp_path / f"run{i}.csv", t + 1000.0 * i, ch, rng))
    return paths, offsets


# -------------------------------------------------------------------------------------- statistics
def test_band_is_eq6_with_student_t():
    x = np.array([[1.0, 2.0], [2.0, 2.5], [3.0, 1.5], [4.0, 2.0], [5.0, 2.0], [6.0, 3.0], [7.0, 1.0]])
    b = band(x.T.T)
    assert t_critical(7) == pytest.approx(2.446911851, abs=1e-8)        # t_(0.975, 6), tables
    s = np.array([math.sqrt(sum((v - 4.0) ** 2 for v in range(1, 8)) / 6.0), np.std(x[:, 1], ddof=1)])
    np.testing.assert_allclose(b.mean, [4.0, 2.0])
    np.testing.assert_allclose(b.half, 2.446911851 * s / math.sqrt(7), rtol=1e-9)
    assert inside_fraction(np.array([4.0 + 0.99 * b.half[0], 2.0 + 1.01 * b.half[1]]), b) == 0.5
    one = band(x[:1])
    assert not one.has_band and inside_fraction(x[0], one) is None
    assert error_metrics(x[0] + 1.0, one) == {"rms": 1.0, "max": 1.0, "inside_band": None}


def test_wheel_speed_from_angle_matches_the_derivative_and_survives_wrapping():
    dt = 0.01
    t = np.arange(0.0, 10.0, dt)
    theta = 0.8 * t ** 2 + 3.0 * t + 0.05 * np.sin(2 * math.pi * 0.5 * t)
    exact = 1.6 * t + 3.0 + 0.05 * math.pi * np.cos(2 * math.pi * 0.5 * t)
    w = wheel_speed(theta, dt)
    assert np.max(np.abs(w - exact)) < 2e-3
    wrapped = np.angle(np.exp(1j * theta))                       # a logger wrapping at +-pi
    run_dir_free = np.unwrap(wrapped)
    np.testing.assert_allclose(wheel_speed(run_dir_free, dt), w, atol=1e-9)


# --------------------------------------------------------------------------------------- alignment
def test_alignment_recovers_known_offsets(tmp_path):
    paths, offsets = make_runs(tmp_path, offsets=[0.0, 0.137, 0.251, 0.05, 0.199, 0.31, 0.083])
    runs, rejected = load_runs(paths)
    assert not rejected
    al = align(runs, "xcorr")
    got = np.array(al.offsets) - np.array([r.time[0] for r in runs])
    np.testing.assert_allclose(got - got[0], np.array(offsets) - offsets[0], atol=3e-3)
    ev = align(runs, "event:brake_pressure")
    got = np.array(ev.offsets) - np.array([r.time[0] for r in runs])
    np.testing.assert_allclose(got - got[0], np.array(offsets) - offsets[0], atol=3e-3)
    bench = build_benchmark(runs, rejected)
    assert bench.n == 7 and "cross-correlation" in bench.alignment.method
    # aligned means: the band of a repeated manoeuvre is narrow where the runs agree
    assert bench.repeatability["brake_pressure"]["relative"] < 0.02


def test_a_different_manoeuvre_is_left_out_with_the_reason(tmp_path):
    paths, _ = make_runs(tmp_path, n=6)
    t = np.arange(int(DURATION * RATE)) / RATE
    odd = write(tmp_path / "other.csv", t, manoeuvre(t, pulse_at=4.5, amp=0.5), np.random.default_rng(9))
    runs, rejected = load_runs([*paths, odd])
    bench = build_benchmark(runs, rejected)
    assert bench.n == 6
    assert [r.path.name for r in bench.rejected] == ["other.csv"]
    assert "not a repetition" in bench.rejected[0].reason


def test_two_runs_that_disagree_are_an_error(tmp_path):
    t = np.arange(int(DURATION * RATE)) / RATE
    a = write(tmp_path / "a.csv", t, manoeuvre(t))
    b = write(tmp_path / "b.csv", t, manoeuvre(t, pulse_at=4.5, amp=0.4))
    runs, rej = load_runs([a, b])
    with pytest.raises(ConfigError, match="not repetitions of one manoeuvre"):
        build_benchmark(runs, rej)


def test_single_run_compares_without_a_band(tmp_path):
    paths, _ = make_runs(tmp_path, n=1)
    runs, rej = load_runs(paths)
    bench = build_benchmark(runs, rej)
    assert bench.n == 1 and not bench.bands["accel_x"].has_band
    assert any("no confidence interval" in n for n in bench.notes)
    m = error_metrics(bench.mean("accel_x") + 0.1, bench.bands["accel_x"])
    assert m["inside_band"] is None and m["rms"] == pytest.approx(0.1)


# -------------------------------------------------------------------------------------- bad input
def test_missing_input_channel_leaves_the_run_out(tmp_path):
    paths, _ = make_runs(tmp_path, n=5)
    t = np.arange(int(DURATION * RATE)) / RATE
    ch = manoeuvre(t)
    del ch["wheel_torque_rl"]
    lacking = write(tmp_path / "lacking.csv", t, ch)
    runs, rej = load_runs([*paths, lacking])
    bench = build_benchmark(runs, rej)
    assert bench.n == 5
    assert "missing input channel wheel_torque_rl" in bench.rejected[0].reason


def test_no_output_channel_is_a_clear_error(tmp_path):
    t = np.arange(int(DURATION * RATE)) / RATE
    ch = {k: v for k, v in manoeuvre(t).items() if k in ("brake_pressure", "wheel_torque_rl", "wheel_torque_rr")}
    p = [write(tmp_path / f"r{i}.csv", t, ch, np.random.default_rng(i)) for i in range(3)]
    runs, rej = load_runs(p)
    with pytest.raises(ConfigError, match="no output channel to compare"):
        build_benchmark(runs, rej)


def test_nans_short_gaps_filled_long_gaps_drop_the_channel(tmp_path):
    paths, _ = make_runs(tmp_path, n=4)
    text = paths[0].read_text().splitlines()
    header = text[0].split(",")
    j = header.index("accel_x")
    for k in (100, 101, 102):                          # 3 samples (6 ms): filled
        cells = text[k].split(",")
        cells[j] = "nan"
        text[k] = ",".join(cells)
    paths[0].write_text("\n".join(text) + "\n")
    lines = paths[1].read_text().splitlines()
    for k in range(200, 800):                          # 1.2 s empty: channel dropped from that run
        cells = lines[k].split(",")
        cells[j] = ""
        lines[k] = ",".join(cells)
    paths[1].write_text("\n".join(lines) + "\n")
    r0, r1 = load_run(paths[0]), load_run(paths[1])
    assert "accel_x" in r0.channels and np.all(np.isfinite(r0.channels["accel_x"]))
    assert any("3 missing/NaN sample(s) filled" in n for n in r0.notes)
    assert "accel_x" not in r1.channels and any("channel accel_x dropped" in n for n in r1.notes)
    runs, rej = load_runs(paths)
    bench = build_benchmark(runs, rej)
    assert bench.values["accel_x"].shape[0] == 3 and bench.bands["accel_x"].n == 3
    assert any("accel_x: recorded in 3 of 4 runs" in n for n in bench.notes)


def test_non_monotonic_time_rejects_the_run_naming_the_row(tmp_path):
    paths, _ = make_runs(tmp_path, n=3)
    lines = paths[2].read_text().splitlines()
    lines[51], lines[52] = lines[52], lines[51]
    paths[2].write_text("\n".join(lines) + "\n")
    runs, rej = load_runs(paths)
    assert len(runs) == 2 and len(rej) == 1
    assert "column 'time', row 52" in rej[0].reason and "does not increase" in rej[0].reason
    for p in paths[:2]:
        p.write_text("time,accel_x\n0,1\n0,2\n")
    runs, rej = load_runs(paths)
    assert not runs and len(rej) == 3
    with pytest.raises(ConfigError, match="no usable run"):
        build_benchmark(runs, rej)


def test_mcap_recording_reads_like_csv(tmp_path):
    from bridge.mcap_log import write_run
    from rtsim.channels import SENSOR_NAMES
    t = np.arange(2000) / RATE
    ch = manoeuvre(t)
    cols = ("time", *[c for c in SENSOR_NAMES if c in ch])
    rows = np.column_stack([t, *[ch[c] for c in cols[1:]]])
    write_run(tmp_path / "run.mcap", cols, rows, "xbw")
    csv = write(tmp_path / "run.csv", t, {c: ch[c] for c in cols[1:]})
    a, b = load_run(tmp_path / "run.mcap"), load_run(csv)
    assert set(a.channels) == set(b.channels)
    np.testing.assert_allclose(a.time, b.time, atol=1e-9)
    for c in a.channels:
        np.testing.assert_allclose(a.channels[c], b.channels[c], rtol=1e-9, atol=1e-9)
    with pytest.raises(ConfigError, match="not an MCAP file"):
        (tmp_path / "bad.mcap").write_bytes(b"hello")
        load_run(tmp_path / "bad.mcap")
