"""Nuisance.mimic: how much of a model effect's change the nuisance adjustments reproduce within their
ranges (objective.py), checked against the analytic answers on a car driving at a constant 15 m/s: a
change that is a resistance offset inside its range is reproduced whole, one three times beyond the range
only up to the range (share 1 - (1 - 1/3)^2 = 5/9), and one of another shape not at all."""
from __future__ import annotations

import numpy as np

from rtsim.validate.objective import MIMIC, RESISTANCE_RANGE, Nuisance

RADIUS = 0.3
CHANNELS = ["wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr", "accel_x", "gyro_z"]


def _nuisance() -> Nuisance:
    t = np.linspace(0.0, 12.0, 1201)
    mean = {c: np.full(t.size, 15.0 / RADIUS) for c in CHANNELS[:4]}
    mean["accel_x"] = np.zeros(t.size)
    mean["gyro_z"] = 0.2 * np.sin(t)
    scale = {c: 0.05 for c in CHANNELS}
    return Nuisance.build(CHANNELS, scale, mean, t, RADIUS)


def _resistance(nu: Nuisance) -> np.ndarray:
    return nu.D[:, next(i for i, n in enumerate(nu.names) if n.startswith("resistance offset"))]


def test_a_resistance_inside_its_range_is_reproduced():
    nu = _nuisance()
    share, name = nu.mimic(0.5 * RESISTANCE_RANGE * _resistance(nu))
    assert share > 0.999 and name.startswith("resistance offset"), (share, name)
    assert share >= MIMIC


def test_beyond_the_range_only_the_range_is_reproduced():
    nu = _nuisance()
    share, _ = nu.mimic(3.0 * RESISTANCE_RANGE * _resistance(nu))
    assert abs(share - 5.0 / 9.0) < 1e-6, share
    assert share < MIMIC


def test_a_change_of_another_shape_is_not_reproduced():
    nu = _nuisance()
    n = 1201
    d = np.zeros(len(CHANNELS) * n)
    d[5 * n:] = np.cos(np.linspace(0.0, 12.0, n))       # a yaw-rate change: no adjustment touches gyro_z
    share, _ = nu.mimic(d)
    assert abs(share) < 1e-9, share
