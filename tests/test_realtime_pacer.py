"""Pacer and clocks: fake clock only, except the stop() test (bounded, no timing assertions)."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from rtsim.realtime import FakeClock, MonotonicClock, Pacer
from waits import EVENT

P = 1e-3


class Recorder:
    """A step callable that records its calls and optionally spends fake time/CPU per step."""

    def __init__(self, clock=None, cost=0.0):
        self.clock = clock
        self.cost = cost
        self.calls: list[int] = []
        self.starts: list[float] = []

    def __call__(self, n: int) -> None:
        self.calls.append(n)
        if self.clock is not None:
            self.starts.append(self.clock.now())
            if self.cost:
                self.clock.advance(self.cost)


def test_fake_clock_sleep_spin_advance_and_stalls():
    c = FakeClock(stalls=[(0.5, 0.1)])
    c.sleep(0.2)
    c.spin_until(0.3)
    assert c.now() == pytest.approx(0.3) and c.sleeps == [0.2] and c.spins == [pytest.approx(0.1)]
    c.advance(0.1, cpu=0.05)
    assert c.thread_time() == pytest.approx(0.1 + 0.05)   # spin burns CPU, sleep does not
    c.sleep(0.15)                                           # crosses 0.5: +0.1 stall
    assert c.now() == pytest.approx(0.65) and c.stalled == [(0.5, 0.1)]
    c.sleep(1.0)
    assert c.now() == pytest.approx(1.65)                   # a stall fires once
    c.spin_until(0.1)                                       # in the past: nothing
    assert c.now() == pytest.approx(1.65)


def test_monotonic_clock_basics():
    c = MonotonicClock()
    t = c.now()
    c.spin_until(t + 1e-4)
    assert c.now() >= t + 1e-4
    assert c.thread_time() >= 0.0


def test_no_stall_k_steps_take_k_periods_zero_lateness():
    clock = FakeClock(start=3.0)
    rec = Recorder(clock)
    pacer = Pacer(rec, period=P, clock=clock)
    k = 1000
    assert pacer.run(steps=k) == k
    assert clock.now() - 3.0 == pytest.approx(k * P, abs=1e-12)
    assert rec.calls == [1] * k
    starts = np.array(rec.starts) - 3.0
    np.testing.assert_allclose(starts, np.arange(k) * P, rtol=0, atol=1e-12)
    lat = pacer.health.lateness_samples()
    assert lat.size == k and np.all(lat == 0.0)
    s = pacer.health.summary()
    assert s["steps"] == k and s["overruns"] == 0 and s["stalls"] == 0
    assert s["catch_up_steps"] == 0 and s["skipped_steps"] == 0
    assert s["lateness_max_s"] == 0.0
    assert pacer.sim_time == pytest.approx(k * P) and pacer.lag == 0.0


def test_duration_and_until():
    clock = FakeClock()
    pacer = Pacer(Recorder(clock), period=P, clock=clock)
    assert pacer.run(duration=0.05) == 50
    assert clock.now() == pytest.approx(0.05, abs=1e-12)
    assert pacer.run(until=0.08) == 30                     # sim time 0.05 -> 0.08
    assert pacer.sim_time == pytest.approx(0.08)
    assert pacer.run(until=0.08) == 0


def test_sleep_spin_split_honoured():
    clock = FakeClock()
    rec = Recorder(clock, cost=1e-4)                        # each step works 0.1 ms
    pacer = Pacer(rec, period=P, clock=clock, spin=2e-4)
    pacer.run(steps=100)
    # after each step the gap to the next boundary is 0.9 ms: sleep 0.7 ms, spin the last 0.2 ms
    assert len(clock.sleeps) == 100 and len(clock.spins) == 100
    np.testing.assert_allclose(clock.sleeps, 7e-4, rtol=0, atol=1e-12)
    np.testing.assert_allclose(clock.spins, 2e-4, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pacer.health.cpu_samples(), 1e-4, rtol=0, atol=1e-12)
    assert np.all(pacer.health.lateness_samples() == 0.0)


def test_spin_longer_than_gap_never_sleeps():
    clock = FakeClock()
    pacer = Pacer(Recorder(clock, cost=1e-4), period=P, clock=clock, spin=2e-3)
    pacer.run(steps=50)
    assert clock.sleeps == [] and len(clock.spins) == 50


class OvershootingClock(FakeClock):
    """sleep() overshoots by up to 150 us (less than the spin), as a real OS sleep does."""

    def __init__(self, seed=0, **kw):
        super().__init__(**kw)
        self.rng = np.random.default_rng(seed)

    def sleep(self, dt):
        super().sleep(dt + float(self.rng.uniform(0.0, 1.5e-4)))


def test_sleep_overshoot_does_not_drift():
    clock = OvershootingClock()
    rng = np.random.default_rng(1)
    costs = iter(rng.uniform(0.0, 0.5 * P, 10_000))

    def step(n):
        clock.advance(float(next(costs)))

    pacer = Pacer(step, period=P, clock=clock, spin=2e-4)
    pacer.run(steps=10_000)
    assert clock.now() == pytest.approx(10_000 * P, abs=1e-9)
    assert np.max(np.abs(pacer.health.lateness_samples())) < 1e-12
    assert pacer.health.overruns == 0


def test_15ms_stall_catches_up_15_steps_then_realigns_no_drift():
    clock = FakeClock(stalls=[(0.010, 0.015)])
    rec = Recorder(clock)
    pacer = Pacer(rec, period=P, clock=clock, max_catch_up=20)
    total = 26 + 10_000
    pacer.run(steps=total)
    h = pacer.health
    assert h.stalls == 1 and h.catch_up_steps == 15 and h.skipped_steps == 0
    starts = np.array(rec.starts)
    # steps 0..9 on their boundaries; step 10 (late 15 ms) and 15 catch-up steps 11..25 back to back
    np.testing.assert_allclose(starts[:10], np.arange(10) * P, atol=1e-12, rtol=0)
    np.testing.assert_allclose(starts[10:26], 0.025, atol=1e-12, rtol=0)
    lat = h.lateness_samples()
    assert lat[10] == pytest.approx(0.015, abs=1e-12)
    np.testing.assert_allclose(lat[11:26], (np.arange(14, -1, -1)) * P, atol=1e-12, rtol=0)
    # re-aligned: every later step starts exactly on its boundary; sim time == wall time
    np.testing.assert_allclose(starts[26:], np.arange(26, total) * P, atol=1e-9, rtol=0)
    assert np.max(np.abs(lat[26:])) < 1e-12
    assert pacer.sim_time == pytest.approx(clock.now(), abs=1e-9)
    assert pacer.lag == 0.0
    assert h.max_lateness == pytest.approx(0.015, abs=1e-12)


def test_50ms_stall_catches_up_20_skips_30_and_realigns():
    clock = FakeClock(stalls=[(0.010, 0.050)])
    rec = Recorder(clock)
    pacer = Pacer(rec, period=P, clock=clock, max_catch_up=20)
    total = 31 + 10_000
    pacer.run(steps=total)
    h = pacer.health
    assert h.stalls == 1 and h.catch_up_steps == 20 and h.skipped_steps == 30
    starts = np.array(rec.starts)
    np.testing.assert_allclose(starts[10:31], 0.060, atol=1e-12, rtol=0)   # late step + 20 catch-up
    lat = h.lateness_samples()
    assert lat[10] == pytest.approx(0.050, abs=1e-12)
    np.testing.assert_allclose(lat[11:31], np.arange(19, -1, -1) * P, atol=1e-12, rtol=0)
    # afterwards: on the wall-clock grid again, lagging by exactly the 30 skipped steps
    np.testing.assert_allclose(starts[31:], (np.arange(31, total) + 30) * P, atol=1e-9, rtol=0)
    assert np.max(np.abs(lat[31:])) < 1e-12
    assert pacer.lag == pytest.approx(0.030)
    assert clock.now() - pacer.sim_time == pytest.approx(0.030, abs=1e-9)
    s = h.summary()
    assert s["skipped_steps"] == 30 and s["catch_up_steps"] == 20 and s["stalls"] == 1
    assert s["steps"] == total


def test_max_catch_up_zero_skips_everything():
    clock = FakeClock(stalls=[(0.005, 0.0104)])
    pacer = Pacer(Recorder(clock), period=P, clock=clock, max_catch_up=0)
    pacer.run(steps=100)
    assert pacer.health.catch_up_steps == 0 and pacer.health.skipped_steps == 10
    assert clock.now() == pytest.approx((100 + 10) * P, abs=1e-9)


def test_small_lateness_is_not_a_stall():
    clock = FakeClock(stalls=[(0.010, 0.0005)])
    pacer = Pacer(Recorder(clock), period=P, clock=clock)
    pacer.run(steps=100)
    h = pacer.health
    assert h.stalls == 0 and h.catch_up_steps == 0 and h.skipped_steps == 0 and h.overruns == 0
    assert h.max_lateness == pytest.approx(0.0005, abs=1e-12)
    assert clock.now() == pytest.approx(100 * P, abs=1e-12)   # next boundary still on the grid


def test_slow_catch_up_shares_episode_budget():
    # each step costs 0.6 periods: catching up 20 steps takes 12 ms, so new boundaries pass meanwhile;
    # they belong to the same episode and the total catch-up is bounded by max_catch_up
    clock = FakeClock(stalls=[(0.010, 0.050)])
    pacer = Pacer(Recorder(clock, cost=0.6 * P), period=P, clock=clock, max_catch_up=20)
    pacer.run(steps=500)
    h = pacer.health
    assert h.stalls == 1
    assert h.catch_up_steps == 20
    assert h.steps == 500
    # after the episode the loop is back on the grid with a whole number of skipped periods
    lat = h.lateness_samples()
    assert np.max(np.abs(lat[-100:])) < 1e-12
    assert clock.now() == pytest.approx((500 + h.skipped_steps) * P, abs=1e-9)


def test_fast_mode_never_sleeps():
    clock = FakeClock()
    rec = Recorder(clock, cost=1e-5)
    pacer = Pacer(rec, period=P, mode="fast", clock=clock)
    assert pacer.run(steps=1000) == 1000
    assert clock.sleeps == [] and clock.spins == []
    assert clock.now() == pytest.approx(1000 * 1e-5)
    assert np.all(pacer.health.lateness_samples() == 0.0)
    assert pacer.run(until=1.5) == 500
    assert clock.sleeps == []


def test_lockstep_runs_exactly_requested_steps():
    rec = Recorder()
    pacer = Pacer(rec, period=P, mode="lockstep", clock=FakeClock())
    pacer.advance(7)
    pacer.advance(1)
    pacer.advance(0)
    assert rec.calls == [7, 1]
    assert pacer.steps == 8 and pacer.health.steps == 8
    assert pacer.sim_time == pytest.approx(8 * P)
    with pytest.raises(RuntimeError):
        pacer.run(steps=1)
    with pytest.raises(RuntimeError):
        Pacer(rec, mode="realtime", clock=FakeClock()).advance(1)


def test_invalid_arguments():
    with pytest.raises(ValueError):
        Pacer(Recorder(), mode="bogus")
    with pytest.raises(ValueError):
        Pacer(Recorder(), period=0.0)
    with pytest.raises(ValueError):
        Pacer(Recorder(), spin=-1.0)
    with pytest.raises(ValueError):
        Pacer(Recorder(), max_catch_up=-1)


def test_stop_from_within_step_fake_clock():
    clock = FakeClock()
    pacer = None

    def step(n):
        if pacer.health.steps == 5:
            pacer.stop()

    pacer = Pacer(step, period=P, clock=clock)
    assert pacer.run() == 6
    assert not pacer.running


def test_stop_from_other_thread_real_clock():
    steps = []
    pacer = Pacer(steps.append, period=2e-3, clock=MonotonicClock())
    t = threading.Thread(target=pacer.run, daemon=True)
    t.start()
    deadline = time.monotonic() + EVENT                # bounds on the waits, not timing criteria
    while not steps and time.monotonic() < deadline:
        time.sleep(1e-3)
    assert steps, "pacer did not start stepping"
    pacer.stop()
    t.join(timeout=EVENT)
    assert not t.is_alive()
    assert not pacer.running


def test_owner_stop_event_set_before_run_still_stops_it():
    """A service that is told to stop while it is still starting must not then run on alone."""
    stop = threading.Event()
    calls = []
    p = Pacer(lambda n: calls.append(n), 1e-3, "realtime", clock=FakeClock(), stop_event=stop)
    stop.set()
    assert p.run() == 0 and calls == []
    stop.clear()                                   # the owner clears it; the pacer never does
    assert p.run(steps=3) == 3 and calls == [1, 1, 1]
