"""Nuisance.mimic: how much of a model effect's change the nuisance adjustments reproduce within their
ranges (objective.py), checked against the analytic answers on a car driving at a constant 15 m/s: a
change that is a resistance offset inside its range is reproduced whole, one three times beyond the range
only up to the range (share 1 - (1 - 1/3)^2 = 5/9), and one of another shape not at all. And
project_direction: a sensitivity as the residual sees it is the difference of two projected residuals
while the adjustments stay inside their ranges (a sensor effect's J, identify.fit_sensor_effects)."""
from __future__ import annotations

import numpy as np

from rtsim.validate.objective import RESISTANCE_RANGE, Nuisance

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


def test_beyond_the_range_only_the_range_is_reproduced():
    nu = _nuisance()
    share, _ = nu.mimic(3.0 * RESISTANCE_RANGE * _resistance(nu))
    assert abs(share - 5.0 / 9.0) < 1e-6, share


def test_a_change_of_another_shape_is_not_reproduced():
    nu = _nuisance()
    n = 1201
    d = np.zeros(len(CHANNELS) * n)
    d[5 * n:] = np.cos(np.linspace(0.0, 12.0, n))       # a yaw-rate change: no adjustment touches gyro_z
    share, _ = nu.mimic(d)
    assert abs(share) < 1e-9, share


def test_a_direction_is_seen_as_the_difference_of_projected_residuals():
    nu = _nuisance()
    n = 1201
    rng = np.random.default_rng(3)
    r = 0.1 * RESISTANCE_RANGE * _resistance(nu) + 0.01 * rng.normal(size=len(CHANNELS) * n)
    d = np.zeros(len(CHANNELS) * n)
    d[4 * n:5 * n] = 1.0 / 0.05            # an accel_x bias of 1 m/s^2 per unit, normalised: part resistance
    h = 1e-4
    fd = (nu.project(r + h * d) - nu.project(r)) / h
    pd = nu.project_direction(d)
    assert np.allclose(pd, fd, rtol=1e-6, atol=1e-6)
    assert float(pd @ pd) < float(d @ d)    # the resistance offset absorbs part of a constant accel_x
