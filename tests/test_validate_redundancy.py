"""The model-free check of a sensor's lag and gain (rtsim.validate.redundancy) on synthetic data with a
known answer: a yaw rate r(t) from a lane change, the rear wheels' speed difference proportional to it
(plus a rolling-radius offset proportional to speed, and noise), the gyro reading r delayed and scaled.
References are the constructed values, never the code's own output."""
from __future__ import annotations

import numpy as np
import pytest

from rtsim.validate.redundancy import check, shifted
from rtsim.vehicle.car.validation import RELATIONS

DT = 0.01                       # s, the workflow's grid
T = np.arange(0.0, 12.0, DT)
TRACK_OVER_RADIUS = 1.6 / 0.31


def _yaw(t: np.ndarray) -> np.ndarray:
    """A lane change's yaw rate (rad/s): two smooth lobes of opposite sign."""
    return 0.25 * (np.exp(-((t - 4.0) / 0.9) ** 2) - np.exp(-((t - 7.0) / 0.9) ** 2))


def _channels(rng, yaw, gyro_delay=0.0, gyro_gain=1.0, wheel_noise=0.02, radius_offset=0.004) -> dict:
    """One run's channels: wheel speeds from the yaw rate at 15 m/s, the gyro with its effect and noise."""
    omega = 15.0 / 0.31
    diff = yaw * TRACK_OVER_RADIUS + radius_offset * omega
    rl = omega - 0.5 * diff + rng.normal(0.0, wheel_noise, yaw.size)
    rr = omega + 0.5 * diff + rng.normal(0.0, wheel_noise, yaw.size)
    gyro = gyro_gain * shifted(yaw, DT, gyro_delay) + 0.002 + rng.normal(0.0, 0.0015, yaw.size)
    return {"wheel_speed_rl": rl, "wheel_speed_rr": rr, "gyro_z": gyro}


def _model(yaw) -> dict:
    """The model's replay: noise-free, with a lag of its own (the model's yaw response 20 ms behind the car's
    would read, against the data, as a gyro lead), a different yaw gain (a structural mismatch)."""
    return _channels(np.random.default_rng(0), 1.06 * shifted(yaw, DT, 0.02), wheel_noise=0.0, radius_offset=0.0)


GYRO = next(r for r in RELATIONS if r.channel == "gyro_z")


@pytest.mark.parametrize("delay", [0.0, 0.04, 0.08])
def test_the_gyro_lag_against_the_wheels_is_the_sensor_delay_alone(delay):
    """Seven runs whose gyro lags the true yaw rate by `delay`: the check finds it within 5 ms and its
    interval holds it, whatever the model's own lag and gain."""
    rng = np.random.default_rng(1)
    runs = [_channels(rng, _yaw(T + rng.normal(0.0, 0.01)), gyro_delay=delay) for _ in range(7)]
    ck = check(GYRO, "delay", runs, _model(_yaw(T)), DT)
    assert ck is not None
    assert abs(ck.value - delay) < 0.005
    assert abs(ck.value - delay) <= ck.half_width + 0.002


def test_a_structural_lag_is_not_confirmed_as_a_gyro_delay():
    """A car whose yaw responds later than the model (the gyro and wheels both see it) asks the model for a
    gyro delay; the check sees none and turns the candidate down, while a real delay is confirmed."""
    rng = np.random.default_rng(2)
    structural = [_channels(rng, _yaw(T - 0.04)) for _ in range(7)]
    model = _channels(np.random.default_rng(0), _yaw(T), wheel_noise=0.0, radius_offset=0.0)
    ck = check(GYRO, "delay", structural, model, DT)
    assert abs(ck.value) < 0.005
    assert not ck.confirms(0.04)
    real = [_channels(rng, _yaw(T), gyro_delay=0.04) for _ in range(7)]
    assert check(GYRO, "delay", real, model, DT).confirms(0.04)


def test_the_gain_is_the_data_coefficient_over_the_models():
    """A gyro reading 8 % high: the gain check gives 1.08 against a model whose own wheel-to-gyro ratio is
    different (its coefficient cancels)."""
    rng = np.random.default_rng(3)
    runs = [_channels(rng, _yaw(T), gyro_gain=1.08) for _ in range(7)]
    ck = check(GYRO, "scale", runs, _model(_yaw(T)), DT)
    assert abs(ck.value - 1.08) < 0.01
    assert ck.confirms(1.08) and not ck.confirms(0.95)


def test_a_missing_channel_gives_no_check():
    rng = np.random.default_rng(4)
    runs = [_channels(rng, _yaw(T)) for _ in range(3)]
    for r in runs:
        del r["wheel_speed_rl"]
    assert check(GYRO, "delay", runs, _model(_yaw(T)), DT) is None
