"""Open-loop profiles (drivers/profiles.py): exact values at table nodes, linear in between, steps,
ramps, pulses, sines, sums and sequences, and the packed all-channel kernel."""
from __future__ import annotations

import math

import numpy as np
import pytest

from drivers import profiles as P
from drivers.base import I_BRAKE, I_STEER, I_THROTTLE, NINPUT


def test_table_exact_at_nodes_and_linear_between():
    t = np.array([0.0, 0.37, 1.0, 2.5, 4.0, 7.3])
    v = np.array([2500.0, 2400.0, 0.0, 13.7, -5.0, 8.0])
    prof = P.table(t, v)
    assert np.array_equal(prof.sample(t), v)                  # bit-exact at the nodes
    rng = np.random.default_rng(1)
    tq = rng.uniform(t[0], t[-1], 500)
    np.testing.assert_allclose(prof.sample(tq), np.interp(tq, t, v), rtol=0, atol=1e-9)
    mid = 0.5 * (t[:-1] + t[1:])
    np.testing.assert_allclose(prof.sample(mid), 0.5 * (v[:-1] + v[1:]), rtol=0, atol=1e-9)
    # ends held
    assert np.array_equal(prof.sample([-10.0, -1e-9, 7.3 + 1e-9, 1e6]), [v[0], v[0], v[-1], v[-1]])


def test_table_zero_order_hold():
    prof = P.table([0.0, 1.0, 2.0], [1.0, 2.0, 3.0], hold=True)
    got = prof.sample([-1.0, 0.0, 0.5, 0.999, 1.0, 1.5, 2.0, 9.0])
    assert np.array_equal(got, [1.0, 1.0, 1.0, 1.0, 2.0, 2.0, 3.0, 3.0])
    # a time built as k*dt that lands a rounding error below a node counts as the node
    dt = 1e-3
    prof = P.table([0.0, 0.3], [0.0, 1.0], hold=True)
    assert prof.sample([300 * dt])[0] == 1.0


def test_single_node_table_is_constant():
    assert np.array_equal(P.table([2.0], [5.0]).sample([0.0, 2.0, 9.0]), [5.0, 5.0, 5.0])


def test_step_and_ramp_values():
    s = P.step(1.0, after=0.61, before=0.0)
    assert np.array_equal(s.sample([0.0, 1.0 - 1e-12, 1.0, 5.0]), [0.0, 0.0, 0.61, 0.61])
    s = P.step(1.0, after=0.6, before=0.2, ramp=0.2)
    np.testing.assert_allclose(s.sample([0.5, 1.0, 1.05, 1.1, 1.2, 3.0]), [0.2, 0.2, 0.3, 0.4, 0.6, 0.6],
                               atol=1e-12)
    r = P.ramp(2.0, 62.0, 0.0, math.pi / 2)
    np.testing.assert_allclose(r.sample([0.0, 2.0, 32.0, 62.0, 100.0]),
                               [0.0, 0.0, math.pi / 4, math.pi / 2, math.pi / 2], atol=1e-12)
    r = P.ramp(1.0, 3.0, v0=10.0, rate=-2.0)             # end value from the rate
    np.testing.assert_allclose(r.sample([0.0, 2.0, 3.0, 4.0]), [10.0, 8.0, 6.0, 6.0], atol=1e-12)
    r = P.ramp(1.0, v0=1.0, rate=0.5)                      # unbounded
    np.testing.assert_allclose(r.sample([0.0, 1.0, 11.0, 101.0]), [1.0, 1.0, 6.0, 51.0], atol=1e-12)


def test_pulse_trapezoid():
    p = P.pulse(5.0, 0.3, rise=1.0, width=3.0, fall=1.0, base=0.05)
    np.testing.assert_allclose(p.sample([0.0, 5.0, 5.5, 6.0, 9.0, 9.5, 10.0, 20.0]),
                               [0.05, 0.05, 0.175, 0.3, 0.3, 0.175, 0.05, 0.05], atol=1e-12)


def test_sine_against_its_formula():
    """offset before t0; after it offset + A sin(2 pi f (t - t0) + phase), the amplitude rising over the
    fade cycles as 1/2 (1 - cos(pi tau / T_fade)); value and rate continuous at t0 with phase 0."""
    a, f, ph, t0, off = 0.3, 0.2, 0.4, 1.5, -0.05
    s = P.sine(a, f, phase=ph, t0=t0, offset=off)
    t = np.linspace(-2.0, 30.0, 3201)
    want = np.where(t < t0, off, off + a * np.sin(2 * np.pi * f * (t - t0) + ph))
    np.testing.assert_allclose(s.sample(t), want, rtol=0, atol=1e-12)
    fade = P.sine(a, f, t0=t0, fade_cycles=1.5)
    tf = 1.5 / f                                            # 7.5 s of fade
    tau = t - t0
    w = np.where(tau < 0, 0.0, np.where(tau < tf, 0.5 * (1 - np.cos(np.pi * np.clip(tau, 0, tf) / tf)), 1.0))
    np.testing.assert_allclose(fade.sample(t), w * a * np.sin(2 * np.pi * f * tau), rtol=0, atol=1e-12)
    # smooth start: the first millisecond moves by far less than a sine at full amplitude would
    assert abs(fade.sample([t0 + 1e-3])[0]) < 1e-6
    # on a sequence segment's own clock
    seq = P.sequence([(2.0, P.constant(0.0)), (None, P.sine(1.0, 0.5))])
    np.testing.assert_allclose(seq.sample([1.0, 2.0, 2.5, 3.0, 4.0]), [0.0, 0.0, 1.0, 0.0, 0.0], atol=1e-12)


def test_sum_and_sequence():
    s = P.table([0.0, 4.0], [0.0, 4.0]) + P.step(2.0, 10.0) + P.constant(-1.0)
    np.testing.assert_allclose(s.sample([0.0, 1.0, 2.0, 3.0]), [-1.0, 0.0, 11.0, 12.0], atol=1e-12)
    seq = P.sequence([(2.0, P.constant(2500.0)),
                      (2.5, P.ramp(0.0, 2.5, 2500.0, 0.0)),    # local clock: starts at t = 2
                      (None, P.step(1.0, 800.0, ramp=2.0))])   # starts at t = 4.5
    t = [0.0, 1.99, 2.0, 3.25, 4.5, 5.5, 6.5, 7.5, 100.0]
    np.testing.assert_allclose(seq.sample(t), [2500, 2500, 2500, 1250, 0, 0, 400, 800, 800], atol=1e-9)
    # nested: a sequence inside a sum inside a sequence
    inner = P.sequence([(1.0, P.constant(1.0)), (1.0, P.constant(2.0))]) + P.constant(10.0)
    outer = P.sequence([(0.5, P.constant(0.0)), (3.0, inner)])
    np.testing.assert_allclose(outer.sample([0.25, 0.5, 1.49, 1.5, 2.49, 2.5, 3.49, 3.5]),
                               [0, 11, 11, 12, 12, 10, 10, 0], atol=1e-12)


def test_packed_kernel_all_channels_at_once():
    profs = {"throttle_angle_cmd": P.pulse(1.0, 0.3, 0.5, 1.0, 0.5),
             "brake_pressure_cmd": P.table([0.0, 1.0], [2500.0, 0.0]),
             "steering_wheel_angle_cmd": P.step(0.5, 0.2, ramp=0.1)}
    packed = P.pack(profs)
    out = np.full(NINPUT, np.nan)
    times = np.linspace(-0.5, 4.0, 91)
    got = P.sample(packed, times)
    for i, t in enumerate(times):
        P.eval_profiles(packed, t, out)
        assert np.array_equal(out, got[i])
    np.testing.assert_allclose(got[:, I_THROTTLE], profs["throttle_angle_cmd"].sample(times), atol=1e-15)
    np.testing.assert_allclose(got[:, I_BRAKE], profs["brake_pressure_cmd"].sample(times), atol=1e-15)
    np.testing.assert_allclose(got[:, I_STEER], profs["steering_wheel_angle_cmd"].sample(times), atol=1e-15)
    assert np.all(got[:, 3:] == 0.0)                      # channels without a profile


def test_uniform_table_o1_lookup():
    dt = 1e-3
    vals = np.sin(np.arange(2001) * dt)
    u = P.Uniform(0.0, dt, vals)
    k = np.arange(0, 2001, 7)
    np.testing.assert_allclose(u.sample(k * dt), vals[k], rtol=0, atol=1e-13)
    tq = np.array([0.0005, 1.2345, 1.9995])
    np.testing.assert_allclose(u.sample(tq), np.interp(tq, np.arange(2001) * dt, vals), atol=1e-13)
    assert u.sample([-1.0])[0] == vals[0] and u.sample([10.0])[0] == vals[-1]


@pytest.mark.parametrize("make", [
    lambda: P.table([0.0, 1.0, 1.0], [0.0, 1.0, 2.0]),
    lambda: P.table([0.0, 1.0], [0.0]),
    lambda: P.table([], []),
    lambda: P.table([0.0, np.nan], [0.0, 1.0]),
    lambda: P.step(1.0, 2.0, ramp=-0.1),
    lambda: P.ramp(2.0, 1.0, 0.0, 1.0),
    lambda: P.ramp(0.0, 1.0, 0.0, 1.0, rate=2.0),
    lambda: P.sequence([(None, P.constant(1.0)), (1.0, P.constant(2.0))]),
    lambda: P.sequence([(0.0, P.constant(1.0))]),
    lambda: P.sine(1.0, 0.0),
    lambda: P.sine(1.0, 1.0, fade_cycles=-1.0),
    lambda: P.sine(np.inf, 1.0),
])
def test_invalid_profiles_rejected(make):
    with pytest.raises(ValueError):
        make()
