"""Synthetic "field data" for the validation workflow on a lateral manoeuvre: the rtsim vehicle model with
a hidden effect switched on drives, seven times, what a HIL user runs to validate the lateral dynamics:
standing on the brake, release, a throttle press through the engine model to about 12 m/s, a single
sine of the steering wheel (a lane change: +-1 rad at the wheel, about 3 m/s^2 and 0.25 rad/s at that
speed; the steer-by-wire command range is +-11 rad), then braking to a stop. Run to run the pedal and
steering timing (1 sigma 15 ms) and amplitudes (1.5 %) vary; sensors are sampled at 500 Hz with the
white noise of the straight-line generator (tests/validate_fieldgen.py, which runs the model and
writes the files from this module's command profiles), and each recording starts and ends at a
slightly different time on its own clock. Only the CSV files reach the workflow. `crop_runs` makes the same recordings start later, with
the car already moving (a logger triggered at speed).

The steering-wheel angle recorded is the steer-by-wire column angle the model reports (the actuator's
output), as a real logger records it: the workflow replays that measured angle.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

import validate_fieldgen as fieldgen


DURATION = 12.0
#: brake line pressure command nodes (s, kPa): held, released, off, the stop
BRAKE_T = (0.0, 1.0, 2.0, 9.0, 10.5)
BRAKE_P = (2500.0, 2500.0, 0.0, 0.0, 3000.0)
#: throttle pulse (t0, rise, width, fall s; amplitude rad): about 12 m/s at its end
THROTTLE = (1.8, 0.5, 3.5, 0.5, 0.4)
#: steering-wheel sine (start s, period s, amplitude rad; positive left): one full period
STEER = (6.3, 2.5, 1.0)
#: run-to-run variation of the steering: timing (s) and amplitude (relative), 1 sigma, as the pedals'
JITTER = fieldgen.JITTER
SPREAD = fieldgen.SPREAD


def profiles(rng: np.random.Generator | None):
    """Brake (kPa), throttle (rad) and steering-wheel (rad) commands as functions of time, varied run
    to run (the pedals as the straight-line generator varies them)."""
    brake, throttle = fieldgen.pedal_profiles(rng, BRAKE_T, BRAKE_P, THROTTLE)
    s0, period, samp = STEER
    if rng is not None:
        s0 += rng.normal(0.0, JITTER)
        period *= 1.0 + rng.normal(0.0, SPREAD / 3.0)
        samp *= 1.0 + rng.normal(0.0, SPREAD)

    def steer(t: float) -> float:
        return samp * math.sin(2.0 * math.pi * (t - s0) / period) if s0 < t < s0 + period else 0.0

    return brake, throttle, steer


def write_runs(folder: Path, model, road, effects: dict | None = None, n: int = 7, seed: int = 0,
               channels: tuple[str, ...] | None = None) -> list[Path]:
    """n recordings of the lateral manoeuvre with the hidden effects (a set_effects mapping), CSV files
    in `folder` (the straight-line generator's format, noise and logger offsets)."""
    return fieldgen.write_runs(folder, model, road, effects, n, seed, channels, profiles, DURATION)


def crop_runs(paths: list[Path], folder: Path, start: float) -> list[Path]:
    """The same recordings as if each logger had been triggered `start` s later, i.e. with the car
    already moving (CSV files in `folder`)."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for p in paths:
        head = p.read_text().split("\n", 1)[0]
        data = np.loadtxt(p, delimiter=",", skiprows=1)
        keep = data[data[:, 0] - data[0, 0] >= start]
        path = folder / p.name
        with path.open("w") as fh:
            fh.write(head + "\n")
            np.savetxt(fh, keep, delimiter=",", fmt="%.9g")
        out.append(path)
    return out
