"""The data side of the validation workflow (rtsim/validate: data, signals, align, benchmark, stats), on
synthetic runs built here from closed-form signals (no vehicle model): the band against eq. (6) with
Student's t, wheel speeds derived from wheel angles against the analytic derivative, alignment
against known logger offsets, and bad input (different manoeuvres, missing channels, NaNs,
non-monotonic time, one run, two disagreeing runs) giving clear messages and sensible behaviour."""
from __future__ import annotations

import io
import json
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from rtsim.errors import ConfigError
from rtsim.validate.align import align
from rtsim.validate.benchmark import build_benchmark
from rtsim.validate.data import DataError, announce, load_run, load_runs, require_runs
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


# ------------------------------------------------------------------ the loud data checks (issue 30)
def _edit(path, edit):
    """Rewrite a CSV's lines (index 0: the header) with `edit(lines)`."""
    lines = path.read_text().splitlines()
    edit(lines)
    path.write_text("\n".join(lines) + "\n")
    return path


def _cells(lines, cells, text):
    """Put `text` in the (data row, column) cells; data row 1 is the line after the header."""
    for row, col in cells:
        c = lines[row].split(",")
        c[col] = text
        lines[row] = ",".join(c)


def _left_out(paths):
    """The one line per run left out that the workflow prints (data.announce), on runs loaded with every
    numpy or Python warning turned into an error (none may leak); MCAP runs read by the bridge's reader, as
    the command reads them."""
    from bridge.mcap_recorder import read_recording
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        runs, rejected = load_runs(paths, read_mcap=read_recording)
        out = io.StringIO()
        announce(rejected, out)
    return runs, out.getvalue().splitlines()


def _all_nan(lines):
    for k in range(1, len(lines)):
        lines[k] = ",".join(["nan"] * len(lines[k].split(",")))


def _backwards(lines):
    lines[51], lines[52] = lines[52], lines[51]


def _duplicated_stamp(lines):
    c = lines[300].split(",")
    c[0] = lines[299].split(",")[0]
    lines[300] = ",".join(c)


def _duplicated_column(lines):
    lines[0] = lines[0] + ",accel_x"
    for k in range(1, len(lines)):
        lines[k] = lines[k] + "," + lines[k].split(",")[4]


def _junk(lines):
    _cells(lines, [(1200, 4), (1201, 4), (2500, 1)], "x#1")


BAD = {    # case: (edit of run3.csv, the exact line naming it and the reason)
    "all-NaN run": (_all_nan, "run3.csv: every value is missing (NaN or empty): 4000 rows of time and 8 sensor "
                              "channel(s)"),
    "time going backwards": (_backwards, "run3.csv: time goes backwards at row 52: 3000.1 s after 3000.102 s (1 "
                                         "such row(s)); time must be strictly increasing"),
    "repeated time stamp": (_duplicated_stamp, "run3.csv: time stamp 3000.596 s repeated at row 300 (1 repeated "
                                               "stamp(s)); time must be strictly increasing"),
    "duplicated column": (_duplicated_column, "run3.csv: column 'accel_x' appears 2 times in the header (columns "
                                              "5, 10): which one holds the channel cannot be told"),
    "a few junk cells": (_junk, "run3.csv: column 'accel_x', row 1200: 'x#1' is not a finite number (3 "
                                "such cell(s) in 2 column(s)); a sample is a number, or empty or nan when missing"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_run_is_left_out_with_one_line_naming_it_and_the_reason(tmp_path, case):
    """The issue's bad-data cases: each run is named with its reason in one line, no warning leaks, and
    the good runs still make the benchmark (never a misleading "not repetitions")."""
    paths, _ = make_runs(tmp_path, n=5)
    edit, line = BAD[case]
    _edit(paths[3], edit)
    runs, lines = _left_out(paths)
    assert lines == ["rtsim validate: run left out: " + line]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bench = build_benchmark(runs, [])
    assert bench.n == 4 and not bench.rejected


def test_a_clean_run_with_missing_samples_is_used_and_the_gaps_noted(tmp_path):
    """Empty and nan cells are a logger's missing samples, not junk: short gaps are filled (above); text in
    a column that is no channel is not checked."""
    paths, _ = make_runs(tmp_path, n=3)
    _edit(paths[0], lambda ln: (_cells(ln, [(700, 4), (701, 4)], ""), _cells(ln, [(900, 2)], "NaN")))

    def text_column(lines):              # a column that is no channel may hold text: it is ignored
        lines[0] += ",mode"
        for k in range(1, len(lines)):
            lines[k] += ",cruise"
    _edit(paths[1], text_column)
    runs, lines = _left_out(paths)
    assert lines == [] and len(runs) == 3
    assert "ignored 1 non-sensor column(s): mode" in runs[1].notes
    assert any("channel accel_x: 2 missing/NaN sample(s) filled" in n for n in runs[0].notes)
    assert any("channel wheel_torque_rl: 1 missing/NaN sample(s) filled" in n for n in runs[0].notes)


def test_a_row_with_a_cell_too_many_is_named(tmp_path):
    paths, _ = make_runs(tmp_path, n=3)
    _edit(paths[1], lambda ln: ln.__setitem__(10, ln[10].replace(",", ",1,", 1)))
    _, lines = _left_out(paths)
    assert lines == ["rtsim validate: run left out: run1.csv: row 10 has 10 cells, the header 9: a cell holding "
                     "the separator ',' or a truncated line shifts the columns"]


def test_units_outside_the_dictionarys_plausible_range_are_named(tmp_path):
    """A brake pressure logged in Pa (kPa expected) and wheel angles in degrees (radians expected) fall
    outside their channels' plausible ranges (rtsim.channels.PLAUSIBLE); a wheel angle that a logger wraps
    at one turn is not mistaken for a fast one; a lone spike is named as such."""
    paths, _ = make_runs(tmp_path, n=4)
    text = paths[0].read_text().splitlines()
    head = text[0].split(",")
    jb, jw = head.index("brake_pressure"), head.index("wheel_angle_fl")

    def scale(lines, j, factor):
        for k in range(1, len(lines)):
            c = lines[k].split(",")
            c[j] = f"{float(c[j]) * factor:.10g}"
            lines[k] = ",".join(c)
    _edit(paths[1], lambda ln: scale(ln, jb, 1000.0))
    t = np.arange(int(DURATION * RATE)) / RATE
    fast = manoeuvre(t, amp=5.0)                     # up to 6.6 m/s: 23 rad/s, 1350 deg/s
    write(paths[2], t, {c: x * (180.0 / math.pi if c == "wheel_angle_fl" else 1.0) for c, x in fast.items()})

    def wrap(lines):
        for k in range(1, len(lines)):
            c = lines[k].split(",")
            c[jw] = f"{math.remainder(float(c[jw]), 2 * math.pi):.10g}"
            lines[k] = ",".join(c)
    before = load_run(paths[3]).channels["wheel_angle_fl"]
    _edit(paths[3], wrap)
    spike = write(tmp_path / "spike.csv", t, {**manoeuvre(t), "accel_x": np.where(np.arange(t.size) == 77, 1e30,
                                                                                  manoeuvre(t)["accel_x"])})
    runs, lines = _left_out([*paths, spike])
    assert lines == [
        "rtsim validate: run left out: run1.csv: column 'brake_pressure' reads up to 2.006e+06 kPa (3009 of 4000 "
        "samples outside its plausible range -200 .. 25000 kPa, the first at row 1): logged in Pa or psi instead of "
        "kPa?",
        "rtsim validate: run left out: run2.csv: column 'wheel_angle_fl' changes at up to 1310 rad/s (2644 of 3975 "
        "samples outside its plausible range -30 .. 400 rad/s, the first at row 1332): logged in degrees instead "
        "of rad?",
        "rtsim validate: run left out: spike.csv: column 'accel_x' reads up to 1e+30 m/s^2 (1 of 4000 samples outside "
        "its plausible range -60 .. 60 m/s^2, the first at row 78): a spike or junk values in the log?"]
    assert [r.name for r in runs] == ["run0.csv", "run3.csv"]
    unwrapped = runs[1].channels["wheel_angle_fl"]
    np.testing.assert_allclose(unwrapped - unwrapped[0], before - before[0], atol=1e-6)


def test_every_shipped_channel_declares_its_plausible_range():
    """Declared once, beside the dictionary: every sensor and command channel of every shipped vehicle."""
    from rtsim.channels import PLAUSIBLE, car_channels, two_wheeler_channels
    for d in (car_channels(), car_channels(("fl", "fr")), car_channels(eps=True), two_wheeler_channels()):
        for c in d.sensors + d.commands:
            p = PLAUSIBLE.get(c.name)
            assert p is not None and p.lo < p.hi and p.other_unit, c.name


def test_fewer_than_three_good_runs_stop_unless_the_minimum_is_lowered(tmp_path):
    paths, _ = make_runs(tmp_path, n=4)
    _edit(paths[0], _all_nan)
    _edit(paths[3], _backwards)
    runs, lines = _left_out(paths)
    assert len(lines) == 2 and len(runs) == 2
    _, rejected = load_runs(paths)
    with pytest.raises(DataError) as err:
        require_runs(runs, rejected)
    assert str(err.value) == ("2 usable run(s) of 4, at least 3 needed (--min-runs N lowers this); left out: "
                              "run0.csv, run3.csv")
    require_runs(runs, rejected, min_runs=2)
    require_runs(runs[:1], rejected, min_runs=1)


def test_the_cli_names_each_bad_run_and_stops_with_one_line(tmp_path):
    """`rtsim validate` in a process of its own: one line per run left out, then the one-line error and
    exit code 2 (before any model is built); nothing else on stderr (no warning)."""
    paths, _ = make_runs(tmp_path, n=5)
    _edit(paths[1], _all_nan)
    _edit(paths[2], _duplicated_column)
    _edit(paths[3], _junk)
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-m", "rtsim.cli", "validate", "--vehicle",
                        str(root / "configs" / "vehicles" / "xbw.toml"), "--runs", str(tmp_path), "--report",
                        str(tmp_path / "report"), "--no-progress"], cwd=root, capture_output=True, text=True,
                       timeout=300, env={**os.environ, "PYTHONPATH": str(root)})
    assert r.returncode == 2
    assert r.stderr.splitlines() == [
        "rtsim validate: run left out: " + BAD["all-NaN run"][1].replace("run3", "run1"),
        "rtsim validate: run left out: " + BAD["duplicated column"][1].replace("run3", "run2"),
        "rtsim validate: run left out: " + BAD["a few junk cells"][1],
        "rtsim: error: 2 usable run(s) of 5, at least 3 needed (--min-runs N lowers this); left out: run1.csv, "
        "run2.csv, run3.csv"]
    assert r.stdout == ""
    summ = json.loads((tmp_path / "report" / "summary.json").read_text())      # kept for the record
    assert summ["runs"] == {"used": ["run0.csv", "run4.csv"], "min_runs": 3, "left_out": [
        {"run": f"run{i}.csv", "reason": BAD[case][1].partition(": ")[2]}
        for i, case in ((1, "all-NaN run"), (2, "duplicated column"), (3, "a few junk cells"))]}
    assert summ["verdict"]["headline"].startswith("Stopped before any fit: 2 usable run(s) of 5")


def test_mcap_runs_get_the_same_checks(tmp_path):
    from bridge.mcap_log import write_run
    from rtsim.channels import SENSOR_NAMES
    t = np.arange(2000) / RATE
    ch = manoeuvre(t)
    cols = ("time", *[c for c in SENSOR_NAMES if c in ch])
    rows = np.column_stack([t, *[ch[c] for c in cols[1:]]])
    rows[700, 0], rows[701, 0] = rows[701, 0], rows[700, 0]
    write_run(tmp_path / "back.mcap", cols, rows, "xbw")
    rows = np.column_stack([t, *[ch[c] * (1000.0 if c == "brake_pressure" else 1.0) for c in cols[1:]]])
    write_run(tmp_path / "pascal.mcap", cols, rows, "xbw")
    _, lines = _left_out([tmp_path / "back.mcap", tmp_path / "pascal.mcap"])
    assert lines == [
        "rtsim validate: run left out: back.mcap: time goes backwards at message 702: 1.4 s after 1.402 s (1 such "
        "message(s)); time must be strictly increasing",
        "rtsim validate: run left out: pascal.mcap: column 'brake_pressure' reads up to 2e+06 kPa (744 of 2000 "
        "samples outside its plausible range -200 .. 25000 kPa, the first at message 1): logged in Pa or psi "
        "instead of kPa?"]


def test_mcap_recording_reads_like_csv(tmp_path):
    from bridge.mcap_log import write_run
    from rtsim.channels import SENSOR_NAMES
    t = np.arange(2000) / RATE
    ch = manoeuvre(t)
    cols = ("time", *[c for c in SENSOR_NAMES if c in ch])
    rows = np.column_stack([t, *[ch[c] for c in cols[1:]]])
    write_run(tmp_path / "run.mcap", cols, rows, "xbw")
    csv = write(tmp_path / "run.csv", t, {c: ch[c] for c in cols[1:]})
    from bridge.mcap_recorder import read_recording         # the command's reader (the bridge, a layer above)
    a, b = load_run(tmp_path / "run.mcap", read_mcap=read_recording), load_run(csv)
    assert set(a.channels) == set(b.channels)
    np.testing.assert_allclose(a.time, b.time, atol=1e-9)
    for c in a.channels:
        np.testing.assert_allclose(a.channels[c], b.channels[c], rtol=1e-9, atol=1e-9)
    with pytest.raises(ConfigError, match="not an MCAP file"):
        (tmp_path / "bad.mcap").write_bytes(b"hello")
        load_run(tmp_path / "bad.mcap", read_mcap=read_recording)
    # without a reader (the workflow called without the command's), an MCAP run is left out saying why
    runs, rejected = load_runs([tmp_path / "run.mcap", csv])
    assert [r.path.name for r in runs] == ["run.csv"]
    assert [r.line for r in rejected] == [
        "run.mcap: no MCAP reader was given (the rtsim validate command passes the bridge's); give the run as CSV"]
