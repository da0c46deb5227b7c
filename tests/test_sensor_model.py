"""The one sensor model (rtsim.vehicle.kit.sensor_model) against analytic references: bias adds, scale
multiplies, quantisation rounds, white noise has its standard deviation and replays from its seed, a
delay (also between steps) reproduces x(t - d), neutral channels pass bit for bit; and in the service's
compiled loop it is applied once: a bias b shows as b in the sensor samples, not 2 b."""
from __future__ import annotations

import numpy as np
import pytest

from rtsim.vehicle.kit.sensor_model import (SM_BIAS, SM_DELAY, SM_NOISE, SM_QUANTUM, SM_SCALE, apply_to_series,
                                            neutral_params, seed_noise, sensor_params)

DT = 1e-3


def _series(n=2000):
    t = DT * np.arange(n)
    return t, np.column_stack([0.3 + 2.0 * t, np.sin(2 * np.pi * 3.0 * t), np.cos(2 * np.pi * 0.5 * t)])


def test_neutral_channels_pass_exactly():
    _, x = _series()
    assert np.array_equal(apply_to_series(neutral_params(3), x), x)


def test_bias_scale_and_quantisation():
    _, x = _series()
    p = neutral_params(3)
    p[0, SM_BIAS] = 0.25
    p[1, SM_SCALE] = 1.5
    p[2, SM_QUANTUM] = 0.1
    y = apply_to_series(p, x)
    assert np.array_equal(y[:, 0], x[:, 0] + 0.25)
    assert np.array_equal(y[:, 1], 1.5 * x[:, 1])
    assert np.allclose(y[:, 2], 0.1 * np.round(x[:, 2] / 0.1), atol=1e-15)
    assert np.max(np.abs(y[:, 2] - x[:, 2])) <= 0.05 + 1e-12


@pytest.mark.parametrize("delay", [0.004, 0.0037, 0.0125])
def test_delay_reproduces_the_past_value(delay):
    """Linear interpolation between recorded rows: exact on a ramp; on a 3 Hz sine within the
    interpolation error bound h^2/8 max|x''|; the first value held before the start."""
    t, x = _series()
    p = sensor_params(["ramp", "sine", "slow"], DT, effects={"sensor_delay": [
        {"channel": c, "delay": delay} for c in ("ramp", "sine", "slow")]})
    assert p[0, SM_DELAY] == pytest.approx(delay / DT)
    y = apply_to_series(p, x)
    late = t >= delay
    assert np.allclose(y[late, 0], 0.3 + 2.0 * (t[late] - delay), rtol=0, atol=1e-12)
    w = 2 * np.pi * 3.0
    assert np.max(np.abs(y[late, 1] - np.sin(w * (t[late] - delay)))) <= DT ** 2 / 8 * w ** 2 + 1e-12
    assert np.all(y[~late, 0] == x[0, 0])


def test_noise_has_its_standard_deviation_and_replays_from_the_seed():
    n = 40000
    x = np.zeros((n, 1))
    p = neutral_params(1)
    p[0, SM_NOISE] = 0.02
    seed_noise(7)
    a = apply_to_series(p, x)[:, 0]
    seed_noise(7)
    b = apply_to_series(p, x)[:, 0]
    assert np.array_equal(a, b)
    # sample standard deviation of n normal draws: relative standard error 1/sqrt(2n) = 0.35 %
    assert np.std(a) == pytest.approx(0.02, rel=0.02)
    assert abs(np.mean(a)) < 4 * 0.02 / np.sqrt(n)


def test_config_and_effects_combine():
    """Biases and delays add, scales multiply; an unknown channel is an error naming it."""
    p = sensor_params(["a", "b"], DT, channels={"a": {"bias": 0.1, "scale": 2.0, "delay_s": 0.002}},
                      effects={"sensor_bias": [{"channel": "a", "bias": 0.05}],
                               "sensor_scale": [{"channel": "a", "scale": 1.5}],
                               "sensor_delay": [{"channel": "a", "delay": 0.003}]})
    assert p[0, SM_BIAS] == pytest.approx(0.15) and p[0, SM_SCALE] == pytest.approx(3.0)
    assert p[0, SM_DELAY] == 5.0 and np.array_equal(p[1], neutral_params(1)[0])
    with pytest.raises(ValueError, match="'c'"):
        sensor_params(["a"], DT, channels={"c": {"bias": 1.0}})


def test_the_service_applies_the_sensor_model_once(tmp_path):
    """The same session with and without a sensor bias (config 0.2 m/s^2 on accel_x, plus a 0.05 sensor
    effect): every sensor sample of the service's compiled loop differs by exactly 0.25 on accel_x and
    not at all elsewhere."""
    from pathlib import Path

    from bridge.can_codec import Codec
    from rtsim.channels import SENSOR_NAMES
    from rtsim.service.loop import HilLoop
    from rtsim.service.resim import Collector
    from rtsim.service.server import build_sim

    root = Path(__file__).resolve().parents[1]
    text = (root / "configs/vehicles/xbw.toml").read_text()
    text = text.replace('property_file = "../tyres/', f'property_file = "{(root / "configs/tyres").as_posix()}/')
    biased = tmp_path / "biased.toml"
    biased.write_text(text + "\n[sensors.channels.accel_x]\nbias = 0.2\n"
                             "\n[[effects.sensor_bias]]\nchannel = \"accel_x\"\nbias = 0.05\n")
    runs = []
    for vehicle in (None, biased):
        sim, _ = build_sim(root / "configs/scenarios/step_steer_80kph.toml", vehicle)
        loop = HilLoop(sim, Codec(), mode="fast")
        col = Collector(loop)
        loop.advance(500)
        runs.append(np.array([v for _, v in col.sensors]))
    base, bias = runs
    assert base.shape == bias.shape and base.shape[0] >= 240
    ax = SENSOR_NAMES.index("accel_x")
    assert np.allclose(bias[:, ax] - base[:, ax], 0.25, rtol=0, atol=1e-12)
    others = [c for c in range(len(SENSOR_NAMES)) if c != ax]
    assert np.array_equal(bias[:, others], base[:, others])
