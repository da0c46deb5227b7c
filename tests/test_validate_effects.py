"""The validation workflow on field data with a hidden effect (rtsim/validate): the rtsim model with the
effect switched on (tests/validate_fieldgen.py) drives seven repetitions of a short straight-line
manoeuvre with run-to-run pedal variation, sensor noise and logger offsets; only the CSV files reach
the workflow, which starts from the nominal model. For every case: the right effect is named, its
parameter is within 10 % (or within its stated 95 % uncertainty), the RMS error of the affected
channels falls at least 5 times and at least 90 % of their samples end inside the 95 % band.
Plus data without a missing effect (nothing is added). The model is built once for the module
(workflow.run(..., replayer=...)). Hidden rolling resistance, brake friction and mass, and two effects at
once (brake friction with an accelerometer bias), are tested on data the model did not make instead
(tests/test_validate_peer.py, test_validate_independent.py: the stronger check); their cases here are
kept in CASES (the others' seeds are their positions) and run with RTSIM_VALIDATE_ALL=1.

The effects are large enough that the gap they make dominates the floor the method itself leaves on
accel_x (0.05-0.07 m/s^2 RMS here: the mean's noise and the pitch oscillation after the stop, which
the average of runs stopping at slightly different times smears while the model replaying the mean
inputs shows it crisp); the 5x criterion cannot be met by effects smaller than five times that."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from validate_fieldgen import write_runs

from rtsim.validate.replay import Replayer
from rtsim.validate.workflow import Options, run

VEHICLE = Path(__file__).resolve().parents[1] / "configs" / "vehicles" / "xbw.toml"
WHEELS = ["wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"]
MOTION = [*WHEELS, "accel_x"]

#: case -> (hidden effects, [(effect, parameter, true value, channel or None)], affected channels)
CASES = {
    "rolling_resistance": ({"rolling_resistance": {"coefficient": 0.015}},
                           [("rolling_resistance", "coefficient", 0.015, None)], MOTION),
    "brake_friction": ({"brake_friction": {"scale": 0.75}}, [("brake_friction", "scale", 0.75, None)], MOTION),
    "brake_lag": ({"brake_lag": {"time_constant": 0.35}}, [("brake_lag", "time_constant", 0.35, None)], MOTION),
    "mass": ({"mass": {"added_mass": 250.0}}, [("mass", "added_mass", 250.0, None)], MOTION),
    "road_grade": ({"road_grade": {"grade": 0.03}}, [("road_grade", "grade", 0.03, None)], MOTION),
    "sensor_delay": ({"sensor_delay": [{"channel": "accel_x", "delay": 0.12}]},
                     [("sensor_delay", "delay", 0.12, "accel_x")], ["accel_x"]),
    "sensor_scale": ({"sensor_scale": [{"channel": "wheel_angle_rl", "scale": 1.03}]},
                     [("sensor_scale", "scale", 1.03, "wheel_angle_rl")], ["wheel_speed_rl"]),
}


@pytest.fixture(scope="module")
def replayer():
    return Replayer(VEHICLE)


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("validate_runs")


def _workflow(replayer, runs_dir, name, effects, seed):
    folder = runs_dir / name
    write_runs(folder, replayer.model, replayer.road, effects, n=7, seed=seed)
    return run(Options(VEHICLE, [folder], runs_dir / f"{name}_report"), replayer=replayer)


def _check_effect(res, found, name, param, true, channel):
    assert found.name == name or any(name in lab for lab, _ in res.iterations[0].equivalent), \
        f"named {found.label()} for hidden {name}: {res.verdict}"
    if found.name != name:          # indistinguishable pair (rolling resistance / bearing drag): same force
        return
    if channel is not None:
        assert found.channel == channel
    value = found.params[param]
    unc = found.uncertainty[param]
    assert abs(value - true) <= max(0.1 * abs(true), unc), f"{name}.{param} = {value} +- {unc}, true {true}"


def _check_gap(res, channels):
    before, after = res.metrics(res.before), res.metrics(res.after)
    for c in channels:
        assert before[c]["rms"] >= 5.0 * after[c]["rms"], (c, before[c]["rms"], after[c]["rms"])
        assert after[c]["inside_band"] >= 0.9, (c, after[c]["inside_band"])


#: the cases the independent peers cover (run here only with RTSIM_VALIDATE_ALL=1: the suite's time budget)
ON_PEER_DATA = frozenset(() if os.environ.get("RTSIM_VALIDATE_ALL") else ("rolling_resistance", "brake_friction", "mass"))


@pytest.mark.parametrize("case", [c for c in CASES if c not in ON_PEER_DATA])
def test_hidden_effect_is_named_fitted_and_closes_the_gap(replayer, runs_dir, case):
    hidden, expected, channels = CASES[case]
    res = _workflow(replayer, runs_dir, case, hidden, seed=list(CASES).index(case) + 11)
    assert res.effects, res.verdict
    name, param, true, channel = expected[0]
    _check_effect(res, res.effects[0], name, param, true, channel)
    assert len(res.effects) == 1, [e.label() for e in res.effects]
    _check_gap(res, channels)


def test_no_missing_effect_adds_nothing(replayer, runs_dir):
    res = _workflow(replayer, runs_dir, "none", {}, seed=3)
    assert res.effects == [], [e.label() for e in res.effects]
    assert "no missing effect" in res.verdict
    for c, m in res.metrics(res.after).items():
        assert m["inside_band"] >= 0.9, (c, m)


@pytest.mark.skipif(not os.environ.get("RTSIM_VALIDATE_ALL"), reason="two effects at once are tested on the "
                    "independent peers' data (test_validate_independent.py); RTSIM_VALIDATE_ALL=1 runs it here too")
def test_two_effects_are_found_in_two_iterations(replayer, runs_dir):
    hidden = {"mass": {"added_mass": 200.0}, "sensor_bias": [{"channel": "accel_x", "bias": 0.2}]}
    res = _workflow(replayer, runs_dir, "two", hidden, seed=5)
    names = [e.name for e in res.effects]
    assert names == ["mass", "sensor_bias"], [e.label() for e in res.effects]
    assert [it.winner.effect.name for it in res.iterations if it.winner] == names
    _check_effect(res, res.effects[0], "mass", "added_mass", 200.0, None)
    _check_effect(res, res.effects[1], "sensor_bias", "bias", 0.2, "accel_x")
    _check_gap(res, MOTION)
