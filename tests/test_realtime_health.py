"""LoopHealth: ring buffers, counters, percentiles, /proc/stat steal parsing."""
from __future__ import annotations

import os

import numpy as np
import pytest

from rtsim.realtime import LoopHealth, parse_proc_stat_steal, read_steal_seconds

SAMPLE = """cpu  10132153 290696 3084719 46828483 16683 0 25195 175628 0 0
cpu0 1393280 32966 572056 13343292 6130 0 17875 87814 0 0
cpu1 1335012 32990 566107 13352498 5902 0 6127 87814 0 0
intr 199292 0 9 0 0
ctxt 5432
btime 1700000000
"""


def test_percentiles_equal_numpy_on_recorded_data():
    rng = np.random.default_rng(0)
    lat = rng.exponential(1e-5, 2500)
    cpu = rng.uniform(1e-6, 2e-3, 2500)
    h = LoopHealth(window=1000, period=1e-3)
    for a, b in zip(lat, cpu):
        h.record(float(a), float(b))
    np.testing.assert_array_equal(h.lateness_samples(), lat[-1000:])
    np.testing.assert_array_equal(h.cpu_samples(), cpu[-1000:])
    s = h.summary()
    assert s["lateness_p50_s"] == np.percentile(lat[-1000:], 50)
    assert s["lateness_p99_s"] == np.percentile(lat[-1000:], 99)
    assert s["step_cpu_p50_s"] == np.percentile(cpu[-1000:], 50)
    assert s["step_cpu_p99_s"] == np.percentile(cpu[-1000:], 99)
    assert s["lateness_max_s"] == lat.max()               # maxima over the whole run
    assert s["step_cpu_max_s"] == cpu.max()
    assert s["steps"] == 2500 and s["samples_in_window"] == 1000
    assert s["overruns"] == int(np.sum((lat > 1e-3) | (cpu > 1e-3)))


def test_partial_window_and_counters():
    h = LoopHealth(window=8, period=1e-3)
    assert h.summary()["lateness_p50_s"] is None
    h.record(0.0, 1e-4)
    h.record(2e-3, 1e-4, catch_up=True)
    h.record(0.0, 3e-3)
    h.note_stall()
    h.note_skipped(4)
    h.count_steps(10)
    s = h.summary()
    assert s["samples_in_window"] == 3
    assert s["lateness_p50_s"] == np.percentile([0.0, 2e-3, 0.0], 50)
    assert (s["steps"], s["overruns"], s["catch_up_steps"], s["skipped_steps"], s["stalls"]) == (13, 2, 1, 4, 1)
    h.reset()
    assert h.summary()["steps"] == 0 and h.lateness_samples().size == 0


def test_ring_buffers_are_preallocated():
    h = LoopHealth(window=16)
    buf_l, buf_c = h._lateness, h._cpu
    for i in range(100):
        h.record(float(i), float(i))
    assert h._lateness is buf_l and h._cpu is buf_c
    np.testing.assert_array_equal(h.lateness_samples(), np.arange(84, 100, dtype=float))


def test_parse_proc_stat_sample():
    assert parse_proc_stat_steal(SAMPLE) == 175628
    assert parse_proc_stat_steal("cpu0 1 2 3 4 5 6 7 8\n") is None       # no aggregate line
    assert parse_proc_stat_steal("cpu  1 2 3 4\n") is None                 # old kernel: no steal
    assert parse_proc_stat_steal("") is None


def test_read_steal_seconds_from_file(tmp_path):
    f = tmp_path / "stat"
    f.write_text(SAMPLE)
    assert read_steal_seconds(str(f)) == pytest.approx(175628 / os.sysconf("SC_CLK_TCK"))
    assert read_steal_seconds(str(tmp_path / "missing")) is None


def test_steal_over_run():
    values = iter([100.0, 100.25])
    h = LoopHealth(window=4, steal_source=lambda: next(values))
    h.begin()
    h.end()
    assert h.summary()["steal_s"] == pytest.approx(0.25)
    h2 = LoopHealth(window=4, steal_source=lambda: None)
    h2.begin()
    h2.end()
    assert h2.summary()["steal_s"] is None
    assert LoopHealth(window=4).summary()["steal_s"] is None            # never begun


def test_real_proc_stat_if_present():
    v = read_steal_seconds()
    assert v is None or v >= 0.0


def test_recent_percentiles_use_the_newest_samples_only():
    h = LoopHealth(window=100, period=1e-3, steal_source=lambda: None)
    assert h.recent_percentiles(10)["cpu_p50"] is None
    for i in range(250):                      # wraps the ring twice and a half
        h.record(lateness=i * 1e-6, cpu=i * 1e-6)
    r = h.recent_percentiles(10)             # samples 240..249
    assert r["cpu_p50"] == pytest.approx(np.percentile(np.arange(240, 250) * 1e-6, 50))
    assert r["lateness_p99"] == pytest.approx(np.percentile(np.arange(240, 250) * 1e-6, 99))
    r = h.recent_percentiles(1000)           # capped at the window: samples 150..249
    assert r["cpu_p50"] == pytest.approx(np.percentile(np.arange(150, 250) * 1e-6, 50))
