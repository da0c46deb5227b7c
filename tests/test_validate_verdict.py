"""The verdict an engineer acts on (rtsim/validate/verdict.py), on workflow Results built here (no
simulation): the first line says what was found (effects with values and 95 % intervals, or "no catalogue
effect"), then every channel explained / structural with its shape / inside the band, then each candidate
turned down with the selection's reason; no section contradicts another (the issue's case: "no catalogue
effect explains this" beside "gyro_z: offset -0.0297 rad/s"), the terms are defined, a lowered --min-runs
is announced, and the nuisance-adjusted curve shown never moves a stopped wheel."""
from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from rtsim.validate.data import Rejected
from rtsim.validate.effectset import Effect
from rtsim.validate.identify import Candidate
from rtsim.validate.report import displayed_adjustment
from rtsim.validate.verdict import GLOSSARY, ChannelLine, Verdict, build, contradictions
from rtsim.validate.workflow import Iteration, Options, Result
from rtsim.vehicle.registry import open_vehicle

#: the car's validation profile (its effect catalogue gives the parameters' units)
PROFILE = open_vehicle("xbw").validation


def _cand(effect: Effect, note: str, signature=(), kind=None) -> Candidate:
    return Candidate(effect, kind or effect.kind, 1, 1.0, 0.0, 0.5, -5.0, True, True, 0.9, {}, 3, note=note,
                     signature=list(signature))


def _channel(status, by=(), kind="none", value=0.0, share=0.0, inside=0.97):
    return {"status": status, "text": "", "signature": {"kind": kind, "value": value, "share": share},
            "inside_band": inside, "rms": 0.01, "explained_by": list(by)}


def _result(effects, channels, candidates, min_runs=3, runs=7, rejected=(), confounded=()) -> Result:
    bench = SimpleNamespace(runs=[SimpleNamespace(name=f"run{i}.csv") for i in range(runs)], n=runs,
                            rejected=list(rejected))
    it = Iteration(1, [], 3.0, {}, [], candidates, None, None, "selection text", 0.1)
    return Result(Options(Path("xbw.toml"), [], Path("."), min_runs=min_runs), bench, None, None, None, None, [],
                  effects, {}, {}, [it], "selection text", PROFILE, channels=channels, confounded=list(confounded))


BIAS_NOTE = "its evidence on gyro_z stays below what five effective samples of smooth scatter can show"


def test_the_issues_contradiction_cannot_occur():
    """Nothing named, gyro_z left with an offset of -0.0297 rad/s, the gyro_z bias considered and turned
    down: the first line says no catalogue effect was found (never that none "explains this"), gyro_z's
    line calls its offset a structural shape, not an effect, and points to the turned-down bias, whose
    reason is listed."""
    bias = Effect("sensor_bias", {"channel": "gyro_z", "bias": -0.0297}, {"bias": 0.001})
    tyre = Effect("tyre_slip_stiffness", {"scale": 0.93}, {"scale": 0.05})
    res = _result([], {"gyro_z": _channel("structural", kind="offset", value=-0.0297, share=0.99, inside=0.12),
                       "accel_y": _channel("inside the band"), "wheel_speed_fl": _channel("inside the band")},
                  [_cand(bias, BIAS_NOTE), _cand(tyre, "it changes accel_y and gyro_z less than the structural "
                                                       "mismatch left there: it cannot be told apart from it",
                                                 signature=("accel_y", "gyro_z"))])
    v = build(res)
    assert v.headline == ("Found: no catalogue effect. What is left on gyro_z is structural (a difference in the "
                          "model's structure, described by its shape below; no catalogue effect was selected for "
                          "it).")
    assert v.lines() == [
        v.headline,
        "Per channel (after the named effects and the nuisance adjustments):",
        "  gyro_z: structural, not a catalogue effect; shape offset: the model reads -0.0297 rad/s more (99 % of the "
        "residual); considered and turned down on this channel: sensor_bias[gyro_z](bias = -0.0297), "
        "tyre_slip_stiffness(scale = 0.93) (reasons below) (12 % inside the band)",
        "  accel_y: inside the band (97 % inside the band)",
        "  wheel_speed_fl: inside the band (97 % inside the band)",
        "Considered and turned down:",
        f"  sensor_bias[gyro_z](bias = -0.0297): {BIAS_NOTE}",
        "  tyre_slip_stiffness(scale = 0.93): it changes accel_y and gyro_z less than the structural mismatch left "
        "there: it cannot be told apart from it",
        "Runs: 7 used"]
    assert [c.status for c in v.channels] == ["structural", "inside the band", "inside the band"]
    assert v.channels[0].shape == {"kind": "offset", "value": -0.0297, "unit": "rad/s", "share": 0.99}
    assert contradictions(v) == [] and not v.notice


def test_found_effects_come_first_with_values_and_intervals():
    """A named effect with its value and 95 % interval opens the verdict; a channel is explained only by a
    named effect (a label the structural report carries for an effect that was not named is not trusted);
    the named effect is never listed as turned down, though it was a candidate."""
    bias = Effect("sensor_bias", {"channel": "accel_x", "bias": 0.195}, {"bias": 0.01})
    mass = Effect("mass", {"added_mass": 12.8}, {"added_mass": 9.0})
    res = _result([bias], {"accel_x": _channel("explained", by=[bias.label()]),
                           "gyro_z": _channel("explained", by=[mass.label()]),
                           "accel_y": _channel("structural", kind="lag", value=0.024, share=0.8, inside=0.6)},
                  [_cand(Effect("sensor_bias", {"channel": "accel_x", "bias": 0.19}), "the winner"),
                   _cand(mass, "its 95 % interval includes no added mass")])
    v = build(res)
    assert v.headline == ("Found: sensor_bias on accel_x: bias = 0.195 m/s^2, 95 % interval 0.185 .. 0.205 "
                          "m/s^2. Structural, not a catalogue effect, on accel_y (see per channel).")
    assert v.found[0].values == [{"parameter": "bias", "value": 0.195, "half_width": 0.01, "low": 0.195 - 0.01,
                                  "high": 0.195 + 0.01, "unit": "m/s^2"}]
    byc = {c.channel: c for c in v.channels}
    assert byc["accel_x"].text == "accel_x: explained by sensor_bias[accel_x](bias = 0.195) (97 % inside the band)"
    assert byc["gyro_z"].status == "inside the band" and "mass" not in byc["gyro_z"].text
    assert byc["accel_y"].text.startswith("accel_y: structural, not a catalogue effect; shape lag: the model lags "
                                          "the car's signal by 24 ms (80 % of the residual)")
    assert [t.effect for t in v.turned_down] == [mass.label()]
    assert v.turned_down[0].reason == "its 95 % interval includes no added mass"
    assert contradictions(v) == []


def test_inside_the_band_as_given():
    res = _result([], {c: _channel("inside the band") for c in ("accel_x", "wheel_speed_fl")}, [])
    v = build(res)
    assert v.headline == ("Found: no catalogue effect. The model agrees with the data: every compared channel is "
                          "inside the band.")
    assert "Considered and turned down: none" in v.lines() and contradictions(v) == []


def test_one_run_has_no_band_and_judges_no_channel():
    res = _result([], {"accel_x": _channel("structural", kind="offset", value=0.1, share=0.9, inside=None)}, [],
                  min_runs=1, runs=1)
    v = build(res)
    assert v.headline == "Found: no catalogue effect. One run: no band to judge the channels by."
    assert [c.text for c in v.channels] == ["accel_x: no band (one run): not judged"]
    assert v.notice.startswith("Fewer runs allowed than the 3 the data checks ask for (--min-runs 1): 1 run(s) "
                               "used, no band (one run)") and contradictions(v) == []


def test_confounded_effects_are_said_in_the_first_line():
    a = Effect("mass", {"added_mass": 148.0}, {"added_mass": 3.0})
    b = Effect("road_grade", {"grade": 0.03}, {"grade": 0.0003})
    v = build(_result([a, b], {"accel_x": _channel("explained", by=[a.label(), b.label()])}, [],
                      confounded=[(a.label(), b.label(), 0.93)]))
    assert v.headline.endswith("The data cannot separate mass(added_mass = 148) and road_grade(grade = 0.03) "
                               "(correlation of their sensitivities +0.93).")
    assert v.headline.startswith("Found: mass: added_mass = 148 kg, 95 % interval 145 .. 151 kg; road_grade: "
                                 "grade = 0.03")


def test_a_lowered_minimum_and_the_runs_left_out_are_stated():
    res = _result([], {"accel_x": _channel("inside the band")}, [], min_runs=2, runs=2,
                  rejected=[Rejected(Path("/data/run2.csv"), "time goes backwards at row 52")])
    v = build(res)
    assert v.notice == ("Fewer runs allowed than the 3 the data checks ask for (--min-runs 2): 2 run(s) used, the "
                        "band of their mean is wide; read the verdict as weak.")
    assert v.lines()[-2:] == ["Runs: 2 used, 1 left out:", "  run2.csv: time goes backwards at row 52"]
    assert v.runs_summary() == {"used": ["run0.csv", "run1.csv"], "min_runs": 2,
                                "left_out": [{"run": "run2.csv", "reason": "time goes backwards at row 52"}]}
    s = json.loads(json.dumps(v.summary()))
    assert s["text"] == v.text and s["glossary"] == GLOSSARY and s["notice"] == v.notice
    assert set(GLOSSARY) >= {"band", "structural", "nuisance adjustment", "in the model's terms"}


def test_the_contradiction_check_can_fail():
    """contradictions() finds each kind of disagreement between sections (so its empty answer above means
    something)."""
    bad = Verdict("Found: no catalogue effect.", [], [
        ChannelLine("gyro_z", "explained", "gyro_z: explained by sensor_bias[gyro_z](bias = -0.0297)",
                    ["sensor_bias[gyro_z](bias = -0.0297)"]),
        ChannelLine("accel_y", "inside the band", "accel_y: structural offset")], [], [], [], [], 3, "")
    found = contradictions(bad)
    assert "gyro_z explained by sensor_bias[gyro_z](bias = -0.0297), which was not named" in found
    assert "accel_y called structural with status inside the band" in found
    named = build(_result([Effect("mass", {"added_mass": 100.0}, {"added_mass": 5.0})], {}, []))
    named.headline = "Found: no catalogue effect."
    assert contradictions(named) == ["the first line and the effects found disagree"]


def test_the_nuisance_adjusted_wheel_speed_shown_stays_at_rest_when_the_car_stands():
    """The issue's -1.2 rad/s at standstill: a resistance offset's speed deficit carried past the stop. As
    shown, an adjusted wheel speed never crosses or leaves zero; other channels are shown as adjusted."""
    after = {"wheel_speed_fl": np.array([20.0, 5.0, 0.4, 0.0, 0.0]), "accel_x": np.array([0.1, -2.0, -3.0, 0.0, 0.0])}
    adjusted = {"wheel_speed_fl": after["wheel_speed_fl"] - 1.2, "accel_x": after["accel_x"] - 0.03}
    res = SimpleNamespace(after=after, objective=SimpleNamespace(adjusted=lambda out: adjusted))
    shown = displayed_adjustment(res)
    np.testing.assert_array_equal(shown["wheel_speed_fl"], [18.8, 3.8, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(shown["accel_x"], adjusted["accel_x"])
