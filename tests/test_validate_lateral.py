"""The validation workflow on a lateral manoeuvre (rtsim/validate): the rtsim model with a hidden effect
(tests/validate_fieldgen_lateral.py) drives seven repetitions of a lane change at about 12 m/s between a
throttle start from rest and a braked stop, with run-to-run variation of pedals and steering, sensor
noise and logger offsets; only the CSV files reach the workflow, which starts from the nominal model and
replays the measured rear-wheel torques, brake pressure and steering-wheel angle. For every hidden
effect: the benchmark flags the manoeuvre as lateral (accel_y, gyro_z and roll compared, a steered
phase found), the right effect is named, its parameter is within 10 % of the hidden value,
the RMS error of the affected channels falls at least 5 times and at least 90 % of their samples end
inside the 95 % band. Plus data without a missing effect (nothing added, the replayed steering-wheel
angle follows the measured one) and the same recordings started with the car already moving.

Effect sizes: the method's floor on accel_y is the mean's noise, about 0.016 m/s^2 RMS (0.1 m/s^2
sensor noise, seven runs, 100 Hz grid), so a gain error of accel_y must move it by more than five times
that (here 10 %: 0.11 m/s^2 RMS); a softer tyre (slip stiffness x 0.6) shows in every channel but
accel_x, whose gap stays within its floor (0.018 m/s^2 RMS) and is not counted as affected.

Logger triggered at speed: the replay starts rolling straight with no tyre forces and the suspension at
its static position, so the first 0.2 s accelerate the model a little less than the car; that leaves
about 0.1 rad/s (0.3 %) on the wheel speeds for the rest of the run (inside the band, but larger than
what the softer tyre changes there, 0.2 rad/s): on wheel speeds only >= 90 % inside is asserted there,
the 5x criterion on the lateral channels."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from validate_fieldgen import write_runs as write_straight
from validate_fieldgen_lateral import crop_runs, write_runs

from rtsim.errors import ConvergenceError
from rtsim.validate import report, tasks
from rtsim.validate.benchmark import LATERAL, build_benchmark
from rtsim.validate.data import load_runs
from rtsim.validate.replay import Replayer
from rtsim.validate.signals import box_average
from rtsim.validate.workflow import Options, run

VEHICLE = Path(__file__).resolve().parents[1] / "configs" / "vehicles" / "xbw.toml"
WHEELS = ["wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"]
LAT = list(LATERAL)

#: case -> (hidden effects, (effect, parameter, true value, channel or None), affected channels)
CASES = {
    "tyre_slip_stiffness": ({"tyre_slip_stiffness": {"scale": 0.6}},
                            ("tyre_slip_stiffness", "scale", 0.6, None), [*WHEELS, *LAT]),
    "accel_y_scale": ({"sensor_scale": [{"channel": "accel_y", "scale": 1.1}]},
                      ("sensor_scale", "scale", 1.1, "accel_y"), ["accel_y"]),
    "mass": ({"mass": {"added_mass": 250.0}}, ("mass", "added_mass", 250.0, None), [*WHEELS, "accel_x", *LAT]),
}


@pytest.fixture(scope="module")
def replayer():
    return Replayer(VEHICLE)


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("validate_lateral")


@pytest.fixture(scope="module")
def generated(replayer, runs_dir):
    """name -> run files, each case generated once for the module."""
    cache = {}

    def get(name: str, effects: dict, seed: int) -> list[Path]:
        if name not in cache:
            cache[name] = write_runs(runs_dir / name, replayer.model, replayer.road, effects, n=7, seed=seed)
        return cache[name]
    return get


def _workflow(replayer, runs_dir, name, paths):
    return run(Options(VEHICLE, list(paths), runs_dir / f"{name}_report"), replayer=replayer)


def _check_lateral(res):
    bench = res.bench
    assert bench.lateral
    assert set(LAT) <= set(bench.compared), bench.compared
    assert "steering-wheel angle" in res.inputs.mode and "matched" in res.inputs.mode, res.inputs.mode
    assert res.regimes.steering.any()
    assert any("steering" in p.regime for p in res.regimes.phases), [p.label() for p in res.regimes.phases]


def _check_effect(res, found, name, param, true, channel):
    assert found.name == name, f"named {found.label()} for hidden {name}: {res.verdict}"
    if channel is not None:
        assert found.channel == channel
    value = found.params[param]
    assert abs(value - true) <= 0.1 * abs(true), f"{name}.{param} = {value}, true {true}"


def _check_gap(res, channels, ratio=5.0):
    before, after = res.metrics(res.before), res.metrics(res.after)
    for c in channels:
        assert before[c]["rms"] >= ratio * after[c]["rms"], (c, before[c]["rms"], after[c]["rms"])
        assert after[c]["inside_band"] >= 0.9, (c, after[c]["inside_band"])


#: seeds as the cases have always had them (a gyro_z bias case was cut: the field benchmark's lateral
#: cases and tests/test_validate_independent.py cover it on data the model did not make)
SEEDS = {"tyre_slip_stiffness": 41, "accel_y_scale": 43, "mass": 44}


#: cases that fail with issue 30's selection rule (cross-validation across the runs): strict, with reasons
KNOWN_FAILURES: dict[str, str] = {
    "tyre_slip_stiffness": (
        "not named since the candidate fits replay at 5 ms (passed at 2 ms): the 0.6 scale is fitted at 0.572 and "
        "predicts the left-out runs better (p = 0.011), but the channels it improves significantly are the four "
        "wheel speeds, which it moves by 1.3 standard errors, under 1.96 times the mismatch it leaves there "
        "(at least 1): turned down as indistinguishable from the structural mismatch. Marginal either way: a "
        "replication of this case outside the test, with its seed, was turned down the same way at 2 ms"),
}


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.xfail(strict=True, raises=AssertionError,
                                                                          reason=KNOWN_FAILURES[c]))
                                  if c in KNOWN_FAILURES else c for c in CASES])
def test_hidden_lateral_effect_is_named_fitted_and_closes_the_gap(replayer, runs_dir, generated, case):
    hidden, (name, param, true, channel), channels = CASES[case]
    res = _workflow(replayer, runs_dir, case, generated(case, hidden, SEEDS[case]))
    _check_lateral(res)
    assert len(res.effects) == 1, [e.label() for e in res.effects]
    _check_effect(res, res.effects[0], name, param, true, channel)
    _check_gap(res, channels)
    if case == "mass":                         # the report shows the lateral channels and says why
        report.write(res, runs_dir / "report_html")
        html = (runs_dir / "report_html" / "report.html").read_text()
        assert "manoeuvre: lateral" in html and "steering-wheel command matched" in html
        for c in LAT:
            assert (runs_dir / "report_html" / f"channel_{c}.png").stat().st_size > 1000


def test_no_missing_effect_on_lateral_data_adds_nothing(replayer, runs_dir, generated):
    res = _workflow(replayer, runs_dir, "none", generated("none", {}, 40))
    _check_lateral(res)
    assert res.effects == [], [e.label() for e in res.effects]
    assert "no missing effect" in res.verdict
    for c, m in res.metrics(res.after).items():
        assert m["inside_band"] >= 0.9, (c, m)
    # the replayed steering-wheel angle follows the measured mean within the matching's target, which
    # the measured angle fed straight in as the command does not (the loop's lag and overshoot)
    inp, sw = res.inputs, "steering_wheel_angle"
    err = float(np.sqrt(np.mean((res.before[sw] - res.bench.mean(sw)) ** 2)))
    plain = replayer._run(inp, [], replayer.dt, inp.steer)[sw]
    err_plain = float(np.sqrt(np.mean((plain - res.bench.mean(sw)) ** 2)))
    assert err <= inp.steer_tol and err_plain >= 5.0 * err, (err, err_plain, inp.steer_tol)


def test_logger_triggered_at_speed(replayer, runs_dir, generated):
    """The same recordings started 5.8 s in (about 11.5 m/s, just before the lane change)."""
    hidden, (name, param, true, channel), _ = CASES["tyre_slip_stiffness"]
    for case, effects in (("none", {}), ("tyre_slip_stiffness", hidden)):
        seed = 40 if case == "none" else 41
        paths = crop_runs(generated(case, effects, seed), runs_dir / f"{case}_at_speed", 5.8)
        res = _workflow(replayer, runs_dir, f"{case}_at_speed", paths)
        assert res.inputs.speed0 > 10.0, res.inputs.speed0
        _check_lateral(res)
        if case == "none":
            assert res.effects == [], [e.label() for e in res.effects]
            for c, m in res.metrics(res.after).items():
                assert m["inside_band"] >= 0.9, (c, m)
            continue
        assert len(res.effects) == 1, [e.label() for e in res.effects]
        _check_effect(res, res.effects[0], name, param, true, channel)
        _check_gap(res, LAT)
        after = res.metrics(res.after)
        for c in WHEELS:
            assert after[c]["inside_band"] >= 0.9, (c, after[c])


def test_straight_line_runs_are_not_lateral(replayer, runs_dir):
    paths = write_straight(runs_dir / "straight", replayer.model, replayer.road, {}, n=3, seed=2)
    runs, rejected = load_runs(paths)
    bench = build_benchmark(runs, rejected)
    assert not bench.lateral
    assert not set(LAT) & set(bench.compared)


def test_box_average_keeps_a_ramp_at_the_edges():
    """The anti-alias average is centred up to the ends: a ramp (a wheel angle at constant speed when a
    recording starts in motion) comes back unchanged, so its derivative at the first sample is right."""
    t = np.arange(200) * 0.002
    x = 40.0 * t + 3.0
    assert np.allclose(box_average(t, x, 0.01), x, atol=1e-9)


def test_a_failing_worker_task_comes_back_as_a_failure(monkeypatch):
    """A simulation error inside a forked worker (e.g. a per-run replay that does not converge) is
    returned as text: SimulationError cannot be unpickled, and an exception that fails to unpickle in
    the parent kills the pool's result thread and hangs the workflow."""
    def fail(ctx, cand, i):
        raise ConvergenceError(f"run {i}: Newton-Raphson did not converge", 1, 0.001)
    monkeypatch.setattr(tasks, "run_estimate", fail)
    out = tasks.map_tasks(None, [("run", None, 0), ("run", None, 1)], 2, tasks.Quiet())
    assert [type(r) for r in out] == [tasks.Failed] * 2
    assert "ConvergenceError: run 1" in out[1].message
