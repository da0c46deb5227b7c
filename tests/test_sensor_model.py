"""The one sensor model (rtsim.vehicle.kit.sensor_model) against analytic references: bias adds, scale
multiplies, quantisation rounds, white noise has its standard deviation and replays from its seed (in
any thread), a delay (also between steps) reproduces x(t - d), neutral channels pass bit for bit; and
in the service's compiled loop it is applied once: a bias b shows as b in the sensor samples, the CAN
sensor frames and the MCAP recording, not 2 b; the validation workflow applies the same model."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rtsim.vehicle.kit.sensor_model import (SM_BIAS, SM_DELAY, SM_NOISE, SM_QUANTUM, SM_SCALE, apply_to_series,
                                            delayed, neutral_params, sensor_params)

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
    a = apply_to_series(p, x, seed=7)[:, 0]
    b = apply_to_series(p, x, seed=7)[:, 0]
    assert np.array_equal(a, b)
    assert not np.array_equal(a, apply_to_series(p, x, seed=8)[:, 0])
    # sample standard deviation of n normal draws: relative standard error 1/sqrt(2n) = 0.35 %
    assert np.std(a) == pytest.approx(0.02, rel=0.02)
    assert abs(np.mean(a)) < 4 * 0.02 / np.sqrt(n)
    # white: the lag-1 autocorrelation of n independent draws has standard error 1/sqrt(n) = 0.005
    assert abs(np.corrcoef(a[1:], a[:-1])[0, 1]) < 4 / np.sqrt(n)


def test_noise_on_quantised_biased_channel_keeps_the_chain_order():
    """y = quantise(scale x + bias + noise): every value a multiple of the quantum, the mean of the
    error bias (scale 1), its spread the noise's with the quantisation's q^2/12 added."""
    n = 40000
    x = np.full((n, 1), 0.013)
    p = neutral_params(1)
    p[0, SM_BIAS], p[0, SM_NOISE], p[0, SM_QUANTUM] = 0.5, 0.2, 0.01
    y = apply_to_series(p, x, seed=3)[:, 0]
    assert np.allclose(y / 0.01, np.round(y / 0.01), rtol=0, atol=1e-9)
    assert np.mean(y - 0.013) == pytest.approx(0.5, abs=4 * 0.2 / np.sqrt(n))
    assert np.std(y) == pytest.approx(np.sqrt(0.2 ** 2 + 0.01 ** 2 / 12), rel=0.02)


def test_delayed_series_is_the_model_with_that_delay():
    t, x = _series()
    y = delayed(x[:, 0], DT, 0.0123)
    late = t >= 0.0123
    assert np.allclose(y[late], 0.3 + 2.0 * (t[late] - 0.0123), rtol=0, atol=1e-12)


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


ROOT = Path(__file__).resolve().parents[1]
BIAS_CONFIG, BIAS_EFFECT = 0.2, 0.05         # m/s^2 on accel_x: the config's and a sensor effect's


def _vehicle_file(folder: Path, extra: str) -> Path:
    """The prototype's vehicle file in `folder` with `extra` TOML appended (its relative paths made
    absolute)."""
    text = (ROOT / "configs/vehicles/xbw.toml").read_text()
    text = text.replace('property_file = "../tyres/', f'property_file = "{(ROOT / "configs/tyres").as_posix()}/')
    text = text.replace('dbc = "../can/', f'dbc = "{(ROOT / "configs/can").as_posix()}/')
    path = folder / "vehicle.toml"
    path.write_text(text + extra)
    return path


@pytest.fixture(scope="module")
def biased_vehicle(tmp_path_factory):
    return _vehicle_file(tmp_path_factory.mktemp("biased"), f"""
[sensors.channels.accel_x]
bias = {BIAS_CONFIG}

[[effects.sensor_bias]]
channel = "accel_x"
bias = {BIAS_EFFECT}
""")


def test_the_service_applies_the_sensor_model_once(biased_vehicle):
    """The same session with and without a sensor bias (config 0.2 m/s^2 on accel_x, plus a 0.05 sensor
    effect): every sensor sample of the service's compiled loop differs by exactly 0.25 on accel_x and
    not at all elsewhere."""
    from bridge.can_codec import Codec
    from rtsim.channels import SENSOR_NAMES
    from rtsim.service.loop import HilLoop
    from rtsim.service.resim import Collector
    from rtsim.service.server import build_sim

    runs = []
    for vehicle in (None, biased_vehicle):
        sim, _ = build_sim(ROOT / "configs/scenarios/step_steer_80kph.toml", vehicle)
        loop = HilLoop(sim, Codec(), mode="fast")
        col = Collector(loop)
        loop.advance(500)
        runs.append(np.array([v for _, v in col.sensors]))
    base, bias = runs
    assert base.shape == bias.shape and base.shape[0] >= 240
    ax = SENSOR_NAMES.index("accel_x")
    assert np.allclose(bias[:, ax] - base[:, ax], BIAS_CONFIG + BIAS_EFFECT, rtol=0, atol=1e-12)
    others = [c for c in range(len(SENSOR_NAMES)) if c != ax]
    assert np.array_equal(bias[:, others], base[:, others])


def _served(vehicle, record: Path, steps: int, in_thread: bool = False):
    """`steps` steps of the assembled service (fast mode, CAN on a loopback hub, no Zenoh, recording to
    `record`; `in_thread`: stepped in a thread of its own, as `rtsim demo` does not but a host may);
    returns (the recorded messages, the service's codec)."""
    import threading

    from bridge.can_bus import LoopbackHub
    from bridge.mcap_recorder import read_recording
    from rtsim.service.server import ServeOptions, Service
    from waits import HUB_START

    hub = LoopbackHub(0, start_timeout=HUB_START)
    svc = None
    try:
        svc = Service(ServeOptions(scenario=ROOT / "configs/scenarios/step_steer_80kph.toml", vehicle=vehicle,
                                   mode="fast", can_interface="remote", can_channel=hub.channel, start_hub=False,
                                   zenoh=False, record=record), out=lambda *a: None)
        done = []
        if in_thread:
            th = threading.Thread(target=lambda: done.append(svc.pacer.run(steps=steps)))
            th.start()
            th.join()
        else:
            done.append(svc.pacer.run(steps=steps))
        assert done == [steps]
    finally:
        if svc is not None:
            svc.close()
        hub.close()
    messages, info = read_recording(record)
    assert info.complete
    return messages, svc.codec


def test_a_bias_shows_once_in_the_sensor_frames_and_the_recording(biased_vehicle, tmp_path):
    """Through the assembled service (compiled loop, publisher, MCAP recorder): a bias of b = 0.25 m/s^2
    on accel_x shows as b in the recorded sensor samples (exactly) and in the sensor frames sent (to the
    DBC's resolution: the biased frame decodes to the unbiased value plus b, within one scale step of
    rounding), and nowhere else."""
    from rtsim.channels import SENSOR_NAMES

    b = BIAS_CONFIG + BIAS_EFFECT
    got = []
    for name, vehicle in (("base", None), ("biased", biased_vehicle)):
        messages, codec = _served(vehicle, tmp_path / f"{name}.mcap", 400)
        samples = {round(m.data["time"] * 1e3): m.data for m in messages["rtsim/xbw/sensors"]}
        sensor_ids = {f.frame_id for f in codec.sensor_frames}
        frames = {}
        for m in messages["rtsim/xbw/can/tx"]:
            fid, data = m.data["id"], bytes.fromhex(m.data["data"])
            if fid in sensor_ids:                    # keyed by frame and its sim_time_ms (bytes 0-1)
                frames[(fid, int.from_bytes(data[0:2], "little"))] = codec.db.decode_message(
                    fid, data, decode_choices=False)
        got.append((samples, frames, codec))
    (s0, f0, codec), (s1, f1, _) = got
    common = sorted(set(s0) & set(s1))
    assert len(common) >= 150                        # 0.4 s of 500 Hz samples
    for ms in common:
        assert s1[ms]["accel_x"] - s0[ms]["accel_x"] == pytest.approx(b, abs=1e-9)
        assert all(s1[ms][c] == s0[ms][c] for c in SENSOR_NAMES if c != "accel_x")
    frame = codec.db.get_message_by_name(codec.sensor_frame_of["accel_x"])
    scale = frame.get_signal_by_name("accel_x").scale
    keys = sorted(set(f0) & set(f1))
    with_ax = [k for k in keys if "accel_x" in f0[k]]
    assert len(with_ax) >= 150
    for k in keys:
        for sig, v0 in f0[k].items():
            v1 = f1[k][sig]
            if sig == "accel_x":
                assert abs((v1 - v0) - b) <= scale + 1e-9, (k, v0, v1)
            else:
                assert v1 == v0, (k, sig)


def test_a_noisy_session_resimulates_bit_for_bit(tmp_path):
    """Noise, quantisation and a delay of a fraction of a step in the vehicle file; the service stepped
    in another thread than the one that built it: `rtsim resim` of the recording reproduces every
    sensor sample exactly (the noise comes from the sensor model's own seeded generator), and the
    recorded gyro_z carries noise of the configured standard deviation."""
    from rtsim.service.resim import resim

    vehicle = _vehicle_file(tmp_path, """
[sensors.channels.gyro_z]
noise_std = 0.01

[sensors.channels.accel_y]
noise_std = 0.05
quantum = 0.02
delay_s = 0.0035
""")
    messages, _ = _served(vehicle, tmp_path / "noisy.mcap", 400, in_thread=True)
    report = resim(tmp_path / "noisy.mcap")
    assert report["sensors"]["matched"] >= 150 and report["identical"], report
    gz = np.array([m.data["gyro_z"] for m in messages["rtsim/xbw/sensors"]])
    # white noise: its second differences have variance 6 sigma^2 (the smooth yaw rate's are tiny)
    assert np.std(np.diff(gz, 2)) / np.sqrt(6.0) == pytest.approx(0.01, rel=0.2)
    ay = np.array([m.data["accel_y"] for m in messages["rtsim/xbw/sensors"]])
    assert np.allclose(ay / 0.02, np.round(ay / 0.02), rtol=0, atol=1e-6)


def test_sensor_noise_replays_from_its_seed_in_any_thread(tmp_path):
    """The noise generator is part of the sensor model's state: two cars seeded alike report the same
    noisy values, the one stepped in another thread and with other random draws in between included;
    the noise has its configured standard deviation around the noise-free value."""
    import threading

    from rtsim.channels import SENSOR_NAMES
    from rtsim.road.config import load_road
    from rtsim.vehicle.car.build import build_vehicle
    from rtsim.vehicle.car.config import load_vehicle
    from rtsim.vehicle.car.sim import VehicleSim

    cfg, base = load_vehicle(_vehicle_file(tmp_path, "\n[sensors.channels.gyro_z]\nnoise_std = 0.01\n"))
    model = build_vehicle(cfg, base)
    road = load_road(ROOT / "configs/roads/flat.toml")
    gz = SENSOR_NAMES.index("gyro_z")

    def reports(out):
        sim = VehicleSim(model, road, 1e-3, speed=10.0)
        sim.seed_sensor_noise(11)
        for _ in range(1500):
            sim.step(1)
            np.random.seed(5)                     # another user of a global generator
            np.random.normal(size=3)
            out.append((sim.sensors()[gz], sim.physical_sensors()[gz]))

    here, there = [], []
    reports(here)
    th = threading.Thread(target=reports, args=(there,))
    th.start()
    th.join()
    here, there = np.array(here), np.array(there)
    assert np.array_equal(here, there)
    err = here[:, 0] - here[:, 1]
    assert np.std(err) == pytest.approx(0.01, rel=0.1)   # 1500 draws: relative standard error 1.8 %


def test_the_validation_workflow_reports_through_the_same_model(biased_vehicle):
    """The validation workflow's replays give the physical values; what the sensors report of them is
    the one sensor model with the config's [sensors.channels] and the sensor effects combined (biases
    add, delays add: here 0.2 + 0.05 m/s^2 and a 15 ms delay interpolated between 10 ms grid samples);
    a wheel angle's delay carries over to its derived speed; channels without parameters are untouched."""
    from rtsim.channels import SENSOR_NAMES
    from rtsim.validate.effectset import Effect
    from rtsim.validate.replay import Replayer
    from rtsim.validate.signals import derive_wheel_speeds

    rp = Replayer(biased_vehicle)
    t = 0.01 * np.arange(300)
    raw = {n: 0.1 * k + 0.5 * t for k, n in enumerate(SENSOR_NAMES)}
    raw["wheel_angle_fl"] = 30.0 * t ** 2
    raw.update(derive_wheel_speeds(raw, 0.01))
    effects = [Effect("sensor_bias", {"channel": "accel_x", "bias": BIAS_EFFECT}),
               Effect("sensor_delay", {"channel": "wheel_angle_fl", "delay": 0.015}),
               Effect("rolling_resistance", {"coefficient": 0.01})]
    out = rp.reported(raw, t, effects)
    assert np.allclose(out["accel_x"], raw["accel_x"] + BIAS_CONFIG + BIAS_EFFECT, rtol=0, atol=1e-12)
    late = t >= 0.015
    # linear interpolation of a parabola between samples 10 ms apart: error 30 * 0.005^2 at most
    assert np.max(np.abs(out["wheel_angle_fl"][late] - 30.0 * (t[late] - 0.015) ** 2)) <= 30.0 * 0.005 ** 2 + 1e-12
    assert np.array_equal(out["wheel_speed_fl"], derive_wheel_speeds(out, 0.01)["wheel_speed_fl"])
    assert not np.array_equal(out["wheel_speed_fl"], raw["wheel_speed_fl"])
    for n in SENSOR_NAMES:
        if n not in ("accel_x", "wheel_angle_fl"):
            assert out[n] is raw[n] or np.array_equal(out[n], raw[n])
    assert rp.reported(raw, t, []) is not raw                   # the config's bias alone still applies
    assert rp.reported(raw, t, [])["accel_x"][0] == pytest.approx(raw["accel_x"][0] + BIAS_CONFIG)
