"""`rtsim validate` on motorcycle runs (rtsim.validate.replay_two_wheeler): field runs of rtsim's own
motorcycle ridden by the rider model with a hidden effect and run-to-run variation (tests/two_wheeler_field),
7 repetitions as 100 Hz CSV logs; the workflow must name the hidden effect with its value (20 % for a model
effect, 10 % for a sensor effect), shrink the gap, name nothing on a set without an effect, and report a
replay that falls as a clear error naming the fall and its time."""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rtsim.errors import SimulationError
from rtsim.validate.workflow import Options, run

sys.path.insert(0, str(Path(__file__).resolve().parent))
import two_wheeler_field as field  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
N_RUNS = 7


SETS = {"mass": dict(added_mass=25.0), "gyro": dict(bias={"gyro_z": 0.03}), "none": {}}
SEED0 = {"mass": 0, "gyro": 100, "none": 200}


class _Runs(dict):
    """The field sets, ridden when first asked for (each set: 7 runs, about 5 s)."""

    def __init__(self, base: Path):
        super().__init__()
        self.base = base

    def __missing__(self, key):
        self[key] = [field.ride(self.base / key, "straight", SEED0[key] + s, **SETS[key]) for s in range(N_RUNS)]
        return self[key]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("moto_field")
    return base, _Runs(base)


def _validate(paths, report, **kw):
    return run(Options(vehicle=field.VEHICLE, runs=list(paths), report=report, workers=2, max_iterations=1, **kw))


def test_added_mass_is_named(runs):
    base, r = runs
    res = _validate(r["mass"], base / "rep_mass")
    assert res.effects, res.verdict
    e = res.effects[0]
    assert e.name == "mass", res.verdict
    assert abs(e.params["added_mass"] - 25.0) <= 0.2 * 25.0, e.label()
    before = res.objective.cost(res.before)
    after = res.objective.cost(res.after)
    assert after < 0.5 * before, (before, after)


def test_gyro_bias_is_named_and_cli(runs):
    base, r = runs
    rep = base / "rep_gyro"
    proc = subprocess.run([sys.executable, "-m", "rtsim.cli", "validate", "--vehicle", str(field.VEHICLE),
                           "--runs", *map(str, r["gyro"]), "--report", str(rep), "--max-iterations", "1"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    import json
    summary = json.loads((rep / "summary.json").read_text())
    named = summary["effects"]
    assert named and named[0]["name"] == "sensor_bias", summary["verdict"]
    assert named[0]["parameters"]["channel"] == "gyro_z"
    assert abs(named[0]["parameters"]["bias"] - 0.03) <= 0.1 * 0.03


def test_no_effect_names_nothing(runs):
    base, r = runs
    res = _validate(r["none"], base / "rep_none")
    assert not res.effects, res.verdict


def test_fall_during_replay_is_a_clear_failure(runs, tmp_path):
    """A replay that cannot follow the recorded roll (a lean of 80 deg, past the fall limit) raises a
    SimulationError naming the fall and its time, never a NaN or a crash."""
    from rtsim.validate.benchmark import build_benchmark
    from rtsim.validate.data import load_runs
    from rtsim.validate.replay_two_wheeler import TwoWheelerReplayer
    src = np.genfromtxt(runs[1]["none"][0], delimiter=",", names=True)
    names = src.dtype.names
    data = np.column_stack([src[n] for n in names])
    t = data[:, 0]
    k = names.index("roll")
    data[:, k] = np.where(t > 2.0, np.minimum((t - 2.0) * 1.0, math.radians(80.0)), 0.0)
    p = tmp_path / "fall.csv"
    np.savetxt(p, data, delimiter=",", header=",".join(names), comments="")
    loaded, rej = load_runs([p], field.NAMES)
    rp = TwoWheelerReplayer(field.VEHICLE)
    bench = build_benchmark(loaded, rej, profile=rp.profile)
    with pytest.raises(SimulationError, match="fell"):
        rp.simulate(rp.inputs(bench), [])


def test_effects_change_the_model_through_its_parameters(runs):
    """Each model effect of the catalogue, replayed on one noise-free field run: an added mass slows the
    braking by M / (M + dm) (the brakes' and the drag's forces do not depend on the mass); a grade slows
    the motorcycle by g sin(atan(grade)) while the IMU's specific force barely changes and its pitch
    reads the slope; a lower pad friction brakes less and leaves the acceleration phase alone; the tyres'
    cornering stiffness does nothing on a straight."""
    from rtsim.validate.benchmark import build_benchmark
    from rtsim.validate.data import load_runs
    from rtsim.validate.effectset import Effect
    from rtsim.validate.replay_two_wheeler import TwoWheelerReplayer
    base = runs[0]
    old = field.NOISE_ON
    field.NOISE_ON = 0.0
    try:
        path = field.ride(base / "clean", "straight", 1)
    finally:
        field.NOISE_ON = old
    loaded, rej = load_runs([path], field.NAMES)
    rp = TwoWheelerReplayer(field.VEHICLE)
    bench = build_benchmark(loaded, rej, profile=rp.profile)
    inp = rp.inputs(bench)
    cfg = rp.config
    total = sum(b.mass_kg for b in (cfg.rear_frame, cfg.rider, cfg.swingarm, cfg.upper_fork, cfg.lower_fork,
                                    cfg.front_wheel, cfg.rear_wheel))
    braking, driving = inp.brake_front > 200.0, inp.throttle > 0.3
    assert braking.sum() > 50 and driving.sum() > 50
    r0 = rp.simulate(inp, [])
    ax0 = r0["accel_x"]

    rm = rp.simulate(inp, [Effect("mass", {"added_mass": 25.0})])
    assert np.mean(rm["accel_x"][braking]) / np.mean(ax0[braking]) == pytest.approx(total / (total + 25.0), rel=5e-3)

    grade = 0.05
    rg = rp.simulate(inp, [Effect("road_grade", {"grade": grade})])
    t = bench.t
    k0 = int(np.searchsorted(t, 0.5))
    k1 = int(np.searchsorted(t, 1.0))                     # holding speed: the engine near one operating point
    dv = (rg["wheel_speed_front"][k1] - r0["wheel_speed_front"][k1]) - (rg["wheel_speed_front"][k0] - r0["wheel_speed_front"][k0])
    slow = 9.81 * math.sin(math.atan(grade)) * (t[k1] - t[k0])          # m/s lost to the slope
    assert -dv / rp._spin_per_speed == pytest.approx(slow, rel=0.15)
    assert np.median(np.abs(rg["accel_x"] - ax0)) < 0.15
    assert np.median(rg["pitch"] - r0["pitch"]) == pytest.approx(-math.atan(grade), abs=0.005)

    rb = rp.simulate(inp, [Effect("brake_friction", {"scale": 0.8})])
    assert np.mean(rb["accel_x"][braking]) > np.mean(ax0[braking]) + 0.05       # less deceleration
    free = driving & (inp.brake_front < 1.0) & (inp.brake_rear < 1.0)
    first = int(np.argmax(braking))                       # before the first braking: the same motion
    np.testing.assert_allclose(rb["accel_x"][:first][free[:first]], ax0[:first][free[:first]], atol=1e-6)

    rt = rp.simulate(inp, [Effect("tyre_cornering_stiffness", {"scale": 0.7})])
    np.testing.assert_allclose(rt["wheel_speed_front"], r0["wheel_speed_front"], atol=1e-6)
