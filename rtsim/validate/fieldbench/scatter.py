"""Run-to-run scatter and the field logger's imperfections.

- The driver's input amplitude varies smoothly within a run and between runs: a gain
  g(t) = 1 + a + b sin(2 pi t / T + phase), a ~ N(0, `GAIN_SD`), b ~ U(0, `GAIN_WANDER`), T ~ U(4, 10) s
  (together about +-2 %);
- timing: the whole manoeuvre shifted by N(0, `SHIFT_SD`) s and stretched by 1 + N(0, `STRETCH_SD`), each
  node of an input profile jittered by N(0, `JITTER_SD`) s;
- speed (lateral runs): the target speed times 1 + N(0, `SPEED_SD`);
- sensor noise on every channel: an AR(1) process of standard deviation `sd` and step correlation `rho`
  at the logger rate (low-pass, a time constant of -1 / (rate ln rho)) plus white noise `white`;
- quantisation to the channel's step `lsb` (a wheel angle counter's tooth edge, a converter's step),
  after the noise;
- each logger starts and stops up to 125 samples late / early, on its own clock.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import lfilter

GAIN_SD = 0.01
GAIN_WANDER = 0.01
SHIFT_SD = 0.02
STRETCH_SD = 0.004
JITTER_SD = 0.015
SPEED_SD = 0.005
#: channel -> (coloured sd, rho at 500 Hz, white sd, quantisation step), SI units
NOISE = {
    "accel_x": (0.06, 0.98, 0.05, 0.005), "accel_y": (0.06, 0.98, 0.05, 0.005),
    "gyro_z": (0.0015, 0.98, 0.001, 0.0002), "roll": (0.0005, 0.995, 0.0002, 0.0002),
    "steering_wheel_angle": (0.0005, 0.95, 0.0002, 0.001), "brake_pressure": (3.0, 0.9, 2.0, 1.0),
    "wheel_torque_rl": (0.8, 0.9, 0.5, 0.5), "wheel_torque_rr": (0.8, 0.9, 0.5, 0.5),
    **{f"wheel_angle_{w}": (0.001, 0.9, 0.0, 2 * math.pi / 256) for w in ("fl", "fr", "rl", "rr")},
}


class Scatter:
    """One repetition's draws (in this order from `rng`): gain, timing."""

    def __init__(self, rng: np.random.Generator):
        self.a = rng.normal(0.0, GAIN_SD)
        self.b = rng.uniform(0.0, GAIN_WANDER)
        self.period = rng.uniform(4.0, 10.0)
        self.phase = rng.uniform(0.0, 2 * math.pi)
        self.shift = rng.normal(0.0, SHIFT_SD)
        self.stretch = 1.0 + rng.normal(0.0, STRETCH_SD)
        self.rng = rng

    def gain(self, t: np.ndarray) -> np.ndarray:
        return 1.0 + self.a + self.b * np.sin(2 * math.pi * t / self.period + self.phase)

    def nodes(self, t_nodes) -> np.ndarray:
        """Node times shifted, stretched and jittered, kept increasing."""
        t = np.asarray(t_nodes, float)
        t = self.shift + t * self.stretch + np.concatenate([[0.0], self.rng.normal(0.0, JITTER_SD, t.size - 1)])
        return np.maximum.accumulate(t + np.arange(t.size) * 1e-6)


def ar1(rng: np.random.Generator, n: int, sd: float, rho: float) -> np.ndarray:
    """A stationary AR(1) series of standard deviation sd and step correlation rho."""
    w = rng.standard_normal(n)
    zi = np.array([rho * rng.standard_normal()])
    return sd * lfilter([math.sqrt(1.0 - rho * rho)], [1.0, -rho], w, zi=zi)[0]


def sensor_noise(rng: np.random.Generator, channel: str, x: np.ndarray) -> np.ndarray:
    """The channel as logged: coloured and white noise added, then quantised."""
    sd, rho, white, lsb = NOISE[channel]
    y = x + ar1(rng, x.size, sd, rho) + rng.normal(0.0, white, x.size) * (white > 0)
    return lsb * np.round(y / lsb)


def sensor_effect(t: np.ndarray, x: np.ndarray, bias: float = 0.0, scale: float = 1.0,
                  delay: float = 0.0) -> np.ndarray:
    """A hidden sensor effect on a channel: y = scale x(t - delay) + bias (linear interpolation, the first
    value held before the start)."""
    y = np.interp(t - delay, t, x) if delay else x
    return scale * y + bias
