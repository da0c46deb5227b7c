"""The validation workflow on data it has never seen, from a different simulator (tests/peer_sim.py: a
textbook pitch-plane car with its own tyre law, brakes, suspension and integrator, sharing only the
car's data files): the hidden effect is named and fitted, and the gap closes, exactly as on the
project's own data, on the wheel speeds.

accel_x: the two simulators differ in the pitch the body takes per m/s^2 (the multibody suspension
pitches about 1.4 times as much as the half-car with the config's wheel rates, so the accelerometer
sees a different share of gravity) and in the oscillation after the stop. That leaves 0.03-0.05
m/s^2 that no effect of the catalogue explains, about one standard error of the mean with the
peer's vibrating accelerometer (0.2 m/s^2 noise); its RMS still falls 5 times, and at least 80 %
(not 90 %) of its samples end inside the band."""
from __future__ import annotations

from pathlib import Path

import pytest

import peer_sim

from rtsim.validate.replay import Replayer
from rtsim.validate.workflow import Options, run

VEHICLE = Path(__file__).resolve().parents[1] / "configs" / "vehicles" / "xbw.toml"
WHEELS = ["wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"]

CASES = {    # hidden in the peer -> (effect, parameter, value)
    "brake_friction": ({"brake_scale": 0.75}, ("brake_friction", "scale", 0.75)),
    "rolling_resistance": ({"rr_added": 0.015}, ("rolling_resistance", "coefficient", 0.015)),
}


@pytest.fixture(scope="module")
def replayer():
    return Replayer(VEHICLE)


@pytest.mark.parametrize("case", list(CASES))
def test_peer_data_hidden_effect(replayer, tmp_path, case):
    hidden, (name, param, true) = CASES[case]
    car = peer_sim.Car.from_config(VEHICLE)
    peer_sim.write_runs(tmp_path / "runs", car, n=7, seed=21, **hidden)
    res = run(Options(VEHICLE, [tmp_path / "runs"], tmp_path / "report"), replayer=replayer)
    first = res.effects[0]
    equivalent = [lab for lab, _ in res.iterations[0].equivalent]
    assert first.name == name or any(name in lab for lab in equivalent), res.verdict
    if first.name == name:
        assert abs(first.params[param] - true) <= max(0.1 * true, first.uncertainty[param]), first.label()
    before, after = res.metrics(res.before), res.metrics(res.after)
    for c in WHEELS:
        assert before[c]["rms"] >= 5.0 * after[c]["rms"], (c, before[c], after[c])
        assert after[c]["inside_band"] >= 0.9, (c, after[c])
    assert before["accel_x"]["rms"] >= 5.0 * after["accel_x"]["rms"], (before["accel_x"], after["accel_x"])
    assert after["accel_x"]["inside_band"] >= 0.8, after["accel_x"]
