"""The validation workflow on data the model did not make, with the structural mismatch left in.

Lateral: tests/peer_sim_lateral.py, a planar two-track car with its own tyre law (linear stiffnesses on
a tanh friction circle), quasi-static load transfer, no roll, no steering compliance, its own integrator,
sharing only the car's `rtsim describe` numbers: 15 m/s, steering-wheel ramps to +-0.6 rad held 3 s,
rear wheel torques that hold the speed recorded, seven repetitions. Against rtsim it differs, with no
hidden effect, by a resistance offset (the wheel speeds drift apart by 0.8 rad/s over 12 s), the axles'
rolling radii, and a lag of the model's lateral response behind the peer's, about 10 ms on gyro_z and
25 ms on accel_y: structural mismatch the catalogue does not have. It is the model's roll, which the peer
lacks: with anti-roll bars 33 times stiffer (a fifth of the roll) the lag is under 2 ms on both channels
and a 6 % gain difference from the changed load transfer takes its place; lengthening the model's tyre
relaxation by 0.3 m adds only 3-5 ms. The lag has the signature a sensor delay on accel_y or gyro_z has.
The tyre laws differ too: the peer's stiffness scale x is about 1.08 x in the model's terms
(peer_sim_lateral.equivalent_slip_stiffness), the value the intervals of the stiffness cases must hold.
The peer declares its accelerations level-frame (`# accel_frame: level`: it has no roll), and the
cases compare them so (Options.accel_frame): in rtsim's body frame the accelerometer rolls with the body
and reads gravity's component, accel_y 6-7 % higher in steady cornering, which hid any accel_y scale.
Longitudinal: tests/peer_sim.py, the pitch-plane peer (tests/test_validate_peer.py has its single-effect
cases), here with a grade, no effect, and two effects at once.

The bar (issue 30): a sensor bias, scale or delay on one channel is named with its value within 10 %
(a model effect that changes the outputs by more than the structural mismatch: 20 %), and that
channel's RMS falls to within RMS_FLOOR (1.25) times the floor and at least RMS_FALL (3) times (all RMS
with the nuisance adjustments fitted to them applied, as the report's per-channel table shows them).
The floor is what any model of that form reaches on those runs: the same runs generated without the
hidden sensor effect (the same seed), the model with the model effects found replayed with every run's
inputs and averaged like the data, and the sensor effect's value that brings the channel closest to the
runs' mean found by scipy's bounded scalar search (not the workflow's fitting code): the RMS left there
is the noise left in the mean plus the structural mismatch the effect does not touch. No hidden effect
gives "no catalogue effect" with the per-channel structural report and never a named effect; an effect
smaller than the structural mismatch gives "cannot be told apart". Every named effect's 95 % interval,
model error included, holds the true value, in the model's terms for the tyre stiffness
(peer_sim_lateral.equivalent_slip_stiffness, from the two tyre laws alone) and the sensor effects (the
hidden value composed with the value that search finds on the runs without it). How far the RMS bar
can be met at all on a case's runs: test_rms_bar_reach. Tolerances are fixed numbers.

Tuning vs held-out (marked per case below). TUNING: the cases the method's rules were decided or changed
on: every lateral case except stiffness 0.6 and the accel_y bias (the nuisance prior, the
signature-channel information criterion and the accel_y/roll confounding were added after they failed;
gyro_z scale and delay, held out in the body frame where they passed the first time, and accel_y delay
failed in the level frame with road_grade added beside the sensor effect, and the rule that a grade is
not named from level-frame data that never stand still was added on them), and the longitudinal none
and two-at-once cases (a first rule on what a sensor effect may leave on its channel was dropped after
two-at-once failed), and the longitudinal accel_x scale (held out at first: fitting the sensor effects
on the per-run replays averaged was decided on it). HELD-OUT: the longitudinal grade passed the first
time it ran; stiffness 0.6 (seed 99) and the accel_y bias and scale 1.1 (which fails: KNOWN_FAILURES)
were written and run once after the rules that concern them were final (the level-frame grade rule
changed neither: no grade was involved), and so was the longitudinal accel_x scale 1.2 (which fails too),
after test_rms_bar_reach had shown that scale 1.1's RMS cannot fall 5 times on its runs for any model;
the longitudinal pairs of model effects: see below.

Two model effects at once (the joint fit, rtsim.validate.joint.joint_model). It was developed on mass
200 kg with rolling resistance 0.012 (seed 77, TUNING; before it rolling resistance was named first at
0.0268, then brake_lag; after it 0.0119 and 198.8 kg). Mass 150 kg with grade 0.03 had been run once
before, failing (the grade added first at 0.045, then brake_lag and an accel_x bias). With the joint fit
it was run twice: the first run failed (an edit had left an accepted partner out of the effects, and the
pair tried was grade with brake friction 0.65, since the mass, whose single fit sat on its 600 kg bound,
was predicted by that fit's secant to remove too little to be tried); the partners' promise was then
taken from their sensitivity near the off value, where the joint fit starts them, and the second run
passed (grade 0.0300, mass 148.4 kg; a third, after changes to docstrings and the report only, gave the
same). That change was made after seeing this case, so it counts as TUNING now. Brake friction 0.8 with
grade 0.03 (HELD-OUT) was written down before the joint fit first ran on it and never tuned on; run three
times: first with the same dropped-partner bug (grade 0.02998 alone), then twice with the final method
(grade 0.02998, brake friction 0.8019, the sensitivities correlating +0.50).

Intervals (item 4): none of these cases is held out for them. The block jackknife was added after mass
148.4 +- 0.7 kg (true 150) and grade 0.04011 +- 0.00006 (true 0.04) missed; the discrepancy bound after the
tyre stiffness intervals (+-0.03) missed the peer's values; the tyre-level equivalence that the stiffness
intervals are held against was computed from the two tyre laws alone, after that (it does not use the
vehicle fits). The linear problem of tests/test_validate_uncertainty.py, with a known answer, checks the
coverage over many draws. Sensor effects' intervals are held against their value in the model's terms
(_sensor_terms: the hidden value composed with what the model reads in the same runs without it), since
fitting them on the per-run replays averaged narrowed the accelerometer bias's interval of the
longitudinal two-at-once case from +-0.052 to +-0.007 around 0.2586, off 0.25: the model reads 0.0086
m/s^2 of bias in the runs without one. That reference uses the model (it is what the model can see), and
sensor delays, exempt before, are held to it too.
"""
from __future__ import annotations

import json

from pathlib import Path

import numpy as np
import pytest

import peer_sim_lateral as lateral

from rtsim.validate import report
from rtsim.validate.benchmark import build_benchmark
from rtsim.validate.data import load_runs
from rtsim.validate.effectset import kind
from rtsim.validate.identify import Context
from rtsim.validate.objective import Objective
from rtsim.validate.replay import Replayer
from rtsim.validate.signals import DERIVED
from rtsim.validate.workflow import Options, _ensemble, _sensor_names, run

VEHICLE = Path(__file__).resolve().parents[1] / "configs" / "vehicles" / "xbw.toml"
WHEELS = ["wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"]

#: lateral case -> (hidden in the peer, expected (effect, parameter, value, channel) or a verdict word,
#: "tuning"/"held-out")
LATERAL = {
    "none": ({}, "no catalogue effect", "tuning"),
    "gyro_z_bias": ({"sensor": {"gyro_z": {"bias": 0.03}}}, [("sensor_bias", "bias", 0.03, "gyro_z")], "tuning"),
    "stiffness_0.5": ({"stiffness_scale": 0.5}, [("tyre_slip_stiffness", "scale", 0.5, None)], "tuning"),
    "gyro_z_scale": ({"sensor": {"gyro_z": {"scale": 1.1}}}, [("sensor_scale", "scale", 1.1, "gyro_z")], "tuning"),
    "gyro_z_delay": ({"sensor": {"gyro_z": {"delay": 0.1}}}, [("sensor_delay", "delay", 0.1, "gyro_z")], "tuning"),
    # 200 kg on a manoeuvre at constant speed: the speed controller's extra torque is a resistance
    # offset (a nuisance) and the yaw response barely moves; no named effect is the right answer
    "mass": ({"added_mass": 200.0}, ("no catalogue effect", "cannot be told apart"), "tuning"),
    "two_at_once": ({"stiffness_scale": 0.5, "sensor": {"gyro_z": {"bias": 0.03}}},
                    [("tyre_slip_stiffness", "scale", 0.5, None), ("sensor_bias", "bias", 0.03, "gyro_z")],
                    "tuning"),
    # 0.92 in the peer is 0.99 in the model's terms (peer_sim_lateral.equivalent_slip_stiffness: the peer's
    # tyre at full stiffness is the model's at 1.08): it moves the outputs by less than a standard error, no
    # effect stands out, and none may be named
    "smaller_than_structural": ({"stiffness_scale": 0.92}, ("cannot be told apart", "no catalogue effect"), "tuning"),
    "stiffness_0.6": ({"stiffness_scale": 0.6}, [("tyre_slip_stiffness", "scale", 0.6, None)], "held-out"),
    # accel_y, compared in the level frame the peer declares (no roll): written before their first run and
    # never changed; scale 1.1 and delay fail (KNOWN_FAILURES); delay is tuning: it showed the level-frame
    # grade problem with the gyro_z cases, and the rule that a model effect the nuisance adjustments
    # reproduce is not named (Nuisance.mimic) was added on it (a mass of -99 kg had been named beside the
    # delay for the wheel speeds' resistance drift)
    "accel_y_bias": ({"sensor": {"accel_y": {"bias": 0.3}}}, [("sensor_bias", "bias", 0.3, "accel_y")], "held-out"),
    "accel_y_scale": ({"sensor": {"accel_y": {"scale": 1.1}}}, [("sensor_scale", "scale", 1.1, "accel_y")],
                      "held-out"),
    "accel_y_delay": ({"sensor": {"accel_y": {"delay": 0.1}}}, [("sensor_delay", "delay", 0.1, "accel_y")],
                      "tuning"),
    # chosen after scale 1.1 failed, as the smallest step of 0.1 whose change of accel_y (RMS 0.49 m/s^2)
    # is more than 5 times the floor the no-effect case leaves there (0.056 m/s^2: the structural lag and
    # the mean's noise), so that the 5x bar can be met at all
    "accel_y_scale_1.2": ({"sensor": {"accel_y": {"scale": 1.2}}}, [("sensor_scale", "scale", 1.2, "accel_y")],
                          "tuning"),
}

#: longitudinal (pitch-plane peer) case -> (hidden, expected, "tuning"/"held-out")
LONGITUDINAL = {
    "grade": ({"grade": 0.04}, [("road_grade", "grade", 0.04, None)], "held-out"),
    "none": ({}, ("no catalogue effect", "no missing effect"), "tuning"),
    "two_at_once": ({"brake_scale": 0.75, "accel_bias": 0.25},
                    [("brake_friction", "scale", 0.75, None), ("sensor_bias", "bias", 0.25, "accel_x")], "tuning"),
    "mass_and_grade": ({"added_mass": 150.0, "grade": 0.03},
                       [("mass", "added_mass", 150.0, None), ("road_grade", "grade", 0.03, None)], "tuning"),
    # the joint fit of two model effects was developed on this one (before it: rolling resistance 0.0268 named
    # first, carrying the mass, then brake_lag)
    "mass_and_rolling_resistance": ({"added_mass": 200.0, "rr_added": 0.012},
                                    [("mass", "added_mass", 200.0, None),
                                     ("rolling_resistance", "coefficient", 0.012, None)], "tuning"),
    # written before the joint fit of two model effects was run on it, never tuned on
    "brake_and_grade": ({"brake_scale": 0.8, "grade": 0.03},
                        [("brake_friction", "scale", 0.8, None), ("road_grade", "grade", 0.03, None)], "held-out"),
    # sensor scale and delay on the longitudinal channels ("any one channel"): written down before their
    # first run, after the method of this file was final; delay and the wheel's scale passed, accel_x's
    # scale was not named; fitting the sensor effects on the per-run replays averaged was decided on it
    # (tuning now): named since, its RMS bar out of reach (KNOWN_FAILURES)
    "accel_x_scale": ({"sensor": {"accel_x": {"scale": 1.1}}}, [("sensor_scale", "scale", 1.1, "accel_x")],
                      "tuning"),
    "accel_x_delay": ({"sensor": {"accel_x": {"delay": 0.1}}}, [("sensor_delay", "delay", 0.1, "accel_x")],
                      "held-out"),
    "wheel_angle_scale": ({"sensor": {"wheel_angle_fl": {"scale": 1.03}}},
                          [("sensor_scale", "scale", 1.03, "wheel_angle_fl")], "held-out"),
    # written down, with the method final, before its first run, after the peer itself was found unable to
    # take scale 1.1's RMS 5 times down (test_rms_bar_reach): the smallest step of 0.1 the peer can; with
    # the 0.050 m/s^2 the model leaves on accel_x it was expected to reach about 5.3 times; it did not
    # (KNOWN_FAILURES)
    "accel_x_scale_1.2": ({"sensor": {"accel_x": {"scale": 1.2}}}, [("sensor_scale", "scale", 1.2, "accel_x")],
                          "held-out"),
}


@pytest.fixture(scope="module")
def replayer():
    return Replayer(VEHICLE)


@pytest.fixture(scope="module")
def car(replayer):
    from rtsim.vehicle.car.describe import describe
    from rtsim.vehicle.car.sim import VehicleSim
    desc = describe(replayer.model, VehicleSim(replayer.model, replayer.road, 1e-3))
    return lateral.car_parameters(desc, VEHICLE)


@pytest.fixture(scope="module")
def tyre_params(replayer):
    """The packed Magic Formula parameters of the model's tyres."""
    from rtsim.vehicle.car.sim import VehicleSim
    return VehicleSim(replayer.model, replayer.road, 1e-3).tp


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return tmp_path_factory.mktemp("validate_independent")


def _tol(name: str) -> float:
        return 0.1 if kind(name) == "sensor" else 0.2


def _show(case, res):
    """What was found (shown with pytest -s): effects, per-channel RMS before -> after, verdict."""
    b, a = res.metrics(res.before), res.metrics(res.after)
    ba, aa = res.metrics(res.before, adjusted=True), res.metrics(res.after, adjusted=True)
    print(f"\n[{case}] effects: {[e.label() for e in res.effects]} +- {[e.uncertainty for e in res.effects]}")
    print("  RMS before -> after (nuisance adjusted): " + ", ".join(
        f"{c} {b[c]['rms']:.4g} -> {a[c]['rms']:.4g} ({ba[c]['rms']:.4g} -> {aa[c]['rms']:.4g})" for c in b))
    print("  channels: " + "; ".join(f"{c}: {v['text']}" for c, v in res.channels.items()))
    print(f"  nuisance: {res.nuisance}\n  correlations: {res.correlations}\n  verdict: {res.verdict}")


def _best_delay(t: np.ndarray, model: np.ndarray, data: np.ndarray, delays: np.ndarray) -> float:
    """The delay d (s) of `delays` for which the model's signal, shifted later by d (interpolated),
    matches the data best in the least-squares sense: a measure of a lag apart from the workflow's own."""
    return float(delays[np.argmin([np.mean((np.interp(t - d, t, model) - data) ** 2) for d in delays])])


def _bench(paths: list[Path], replayer=None):
    """The benchmark `rtsim validate` builds of `paths` with its default options."""
    from rtsim.vehicle.registry import open_vehicle
    opts = Options(VEHICLE, paths, Path("."))
    profile = replayer.profile if replayer is not None else open_vehicle(VEHICLE).validation
    runs, rejected = load_runs(paths, _sensor_names(profile, replayer))
    return build_benchmark(runs, rejected, opts.rate, opts.align, opts.compare, profile)


def _apply(name: str, t: np.ndarray, y: np.ndarray, value: float) -> np.ndarray:
    """A sensor effect of the catalogue's form on a reading (its definition, not the workflow's code): a
    bias added, a scale multiplied, a delay (s) shifting it later (interpolated)."""
    if name == "sensor_bias":
        return y + value
    if name == "sensor_scale":
        return y * value
    return np.interp(t - value, t, y)


SEARCH = {"sensor_bias": (-1.0, 1.0), "sensor_scale": (0.5, 1.5), "sensor_delay": (-0.1, 0.3)}


def _reference(replayer, res, paths, name: str, channel: str) -> tuple[float, float, str]:
    """On `paths` (the same runs without the hidden sensor effect), the model with the model effects `res`
    found, replayed with every run's inputs and averaged like the data: the value of the sensor effect
    `name` on `channel` that brings that channel closest to the runs' mean (least RMS with the nuisance
    adjustments applied, scipy's bounded scalar search over SEARCH) and the RMS left there. The value is
    what the structural mismatch reads as that effect (the hidden value in the model's terms is it
    composed with the hidden one); the RMS is the floor any model of this form reaches on those runs: the
    noise left in the mean plus the structural mismatch the effect does not touch (issue 30, item 6)."""
    from scipy.optimize import minimize_scalar
    bench = _bench(paths, replayer)
    obj = Objective.from_benchmark(bench, replayer.wheel_radius)
    model = [e for e in res.effects if e.kind == "model"]
    ens, _ = _ensemble(Context(bench, obj, replayer, replayer.inputs(bench), model, {}, {}, 0.0, bench.n), 2, {})
    c = channel if channel in obj.channels else next(s for s, a in DERIVED.items() if a == channel)
    t = bench.t

    def rms(v: float) -> float:
        out = dict(ens.outputs)
        out[c] = _apply(name, t, ens.outputs[c], v)
        return float(np.sqrt(np.mean((obj.adjusted(out)[c] - obj.mean[c]) ** 2)))

    lo, hi = SEARCH[name]
    best = minimize_scalar(rms, bounds=(lo, hi), method="bounded", options={"xatol": 1e-5})
    return float(best.x), float(best.fun), c


def _sensor_terms(replayer, res, expected, clean_paths) -> dict:
    """(effect, channel) -> (the hidden sensor effect's value in the model's terms, the channel's RMS
    floor): the value composed with what the model reads in the same runs without it (_reference), a
    bias or a delay added, a scale multiplied."""
    out = {}
    for name, param, true, channel in expected if isinstance(expected, list) else []:
        if channel is None:
            continue
        base, floor, c = _reference(replayer, res, clean_paths, name, channel)
        value = true * base if name == "sensor_scale" else true + base
        out[(name, channel)] = (value, floor)
        print(f"  {name}[{channel}] in the model's terms: {true} composed with {base:.4g} read without it: "
              f"{value:.4g}; {c}'s floor {floor:.4g}")
    return out


class ValueBar(AssertionError):
    """A named effect's value is not within the bar's tolerance of the hidden value."""


class RmsBar(AssertionError):
    """A sensor effect's channel RMS does not fall to within RMS_FLOOR of the floor, or not RMS_FALL times."""


RMS_FLOOR = 1.25     # a sensor effect's channel RMS falls to within this factor of the floor (_reference)
RMS_FALL = 3.0       # and at least this many times


def _check(res, expected, in_model_terms: dict | None = None):
    """`in_model_terms`: (effect name, channel) -> the hidden value in the model's terms, where the peer's
    parameter means something else in rtsim's model (its tyre stiffness: equivalent_slip_stiffness), or
    (that value, the channel's RMS floor) for a sensor effect beside the model's own structural mismatch on
    its channel (_sensor_terms); the interval must hold that value."""
    if isinstance(expected, (str, tuple)):
        words = (expected,) if isinstance(expected, str) else expected
        assert res.effects == [], (res.verdict, [e.label() for e in res.effects])
        assert any(w in res.verdict for w in words), res.verdict
        return
    found = {(e.name, e.channel): e for e in res.effects}
    for name, param, true, channel in expected:
        assert (name, channel) in found, (name, channel, res.verdict)
        e = found[(name, channel)]
        if not abs(e.params[param] - true) <= _tol(name) * abs(true):
            raise ValueBar((e.label(), true, res.verdict))
        assert e.uncertainty[param] >= e.model_error[param] > 0.0, (e.uncertainty, e.model_error)
        # the interval, model error included, holds the true value in the model's terms (issue 15, item 4)
        ref = (in_model_terms or {}).get((name, channel), true)
        ref, floor = ref if isinstance(ref, tuple) else (ref, None)
        assert abs(e.params[param] - ref) <= e.uncertainty[param], (e.label(), e.uncertainty, ref)
        if channel is not None:          # a sensor effect: its own channel's RMS falls to within RMS_FLOOR of
            # the floor and RMS_FALL times, all with the nuisance adjustments (the structural mismatch they
            # stand for, left in the data on purpose) applied
            before, after = res.metrics(res.before, adjusted=True), res.metrics(res.after, adjusted=True)
            c = channel if channel in before else next(s for s, a in DERIVED.items() if a == channel)
            if not (before[c]["rms"] >= RMS_FALL * after[c]["rms"]
                    and (floor is None or after[c]["rms"] <= RMS_FLOOR * floor)):
                raise RmsBar((c, before[c]["rms"], after[c]["rms"], floor))
    assert len(res.effects) == len(expected), [e.label() for e in res.effects]




#: cases that fail, with the one part of the bar each fails (any other failure fails the test): the limits
#: of what the data can tell, kept so that a change shows (strict: a pass fails)
KNOWN_FAILURES = {
    "accel_x_scale": (AssertionError, "not named: the 1.095 scale (true 1.1) moves accel_x by 1.5 standard errors "
                      "of the mean, less than 1.96 times the mismatch it leaves (0.65, taken at its floor of 1: the "
                      "noise left in the mean), so it cannot be told from a structural gain of that size; the "
                      "field benchmark would not count it larger than the structural mismatch (2 times the floor); "
                      "had it been named, its RMS bar was out of reach anyway (2.5 times, test_rms_bar_reach)"),
    "accel_y_delay": (ValueBar, "named 0.0751 +- 0.013 s (true 0.1): the model's accel_y lags the peer's by "
                      "25 ms (its roll, which the peer lacks), a structural lag with a sensor delay's signature "
                      "on that channel, which reads as a delay of -0.025 s in the same runs without the hidden "
                      "one: in the model's terms the delay is 0.075, what is found (gyro_z's 9.5 ms make its "
                      "0.1 s delay 0.0903, inside the 10 %)"),
}
#: the longitudinal (pitch-plane peer) cases that fail with issue 30's selection rule (strict, with reasons)
LONGITUDINAL_FAILURES = {
    "mass_and_rolling_resistance": (AssertionError, "nothing is named: no candidate alone passes the rule"),
}
KNOWN_FAILURES.update(LONGITUDINAL_FAILURES)


#: the order the lateral cases' seeds were drawn in (17 + position; a stiffness 0.7 case, fourth, was cut:
#: 0.5 and 0.6 and the field benchmark cover it)
_LAT_ORDER = ("none", "gyro_z_bias", "stiffness_0.5", "stiffness_0.7", "gyro_z_scale", "gyro_z_delay", "mass",
              "two_at_once", "smaller_than_structural", "stiffness_0.6", "accel_y_bias", "accel_y_scale",
              "accel_y_delay", "accel_y_scale_1.2")


def _lat_seed(case: str) -> int:
    return 99 if case == "stiffness_0.6" else 5 if case in ("none", "gyro_z_bias", "stiffness_0.5") else \
        17 + _LAT_ORDER.index(case)


def _known(case: str):
    error, why = KNOWN_FAILURES[case]
    return pytest.param(case, marks=pytest.mark.xfail(strict=True, raises=error, reason=why))


@pytest.mark.parametrize("case", [_known(c) if c in KNOWN_FAILURES else c for c in LATERAL])
def test_lateral_peer(replayer, car, tyre_params, folder, case):
    hidden, expected, _ = LATERAL[case]
    seed = _lat_seed(case)
    paths = lateral.write_runs(folder / case, car, n=7, seed=seed, **hidden)
    res = run(Options(VEHICLE, paths, folder / f"{case}_report", accel_frame=lateral.ACCEL_FRAME), replayer=replayer)
    _show(case, res)
    assert res.bench.lateral and res.accel_frame == "level"
    terms = {}
    if "stiffness_scale" in hidden:
        terms[("tyre_slip_stiffness", None)] = lateral.equivalent_slip_stiffness(car, tyre_params,
                                                                                hidden["stiffness_scale"])
        print(f"  the peer's stiffness scale {hidden['stiffness_scale']} in the model's terms: {terms}")
    if "sensor" in hidden and isinstance(expected, list):
        clean = lateral.write_runs(folder / f"{case}_without", car, n=7, seed=seed,
                                   **{k: v for k, v in hidden.items() if k != "sensor"})
        terms.update(_sensor_terms(replayer, res, expected, clean))
    _check(res, expected, terms)
    # the structural report: every compared channel has a status; accel_y's roll-induced gain is
    # structural whenever no tyre effect was added to explain it
    assert set(res.channels) == set(res.bench.compared)
    if case == "none":
        # compared in the level frame the peer declares, the body's roll gain is gone: in steady cornering
        # the model's accel_y matches the peer's within 2 % (6-7 % in the body frame); what is left is a
        # lag of the model's lateral response, reported as structural with the lag the time shift that
        # best aligns the model's accel_y with the peer's has (found by shifting and interpolating: a
        # different measure), within 30 %
        m, d = res.after["accel_y"], res.bench.bands["accel_y"].mean
        hold = np.abs(d) > 2.0
        assert abs(float(m[hold] @ d[hold] / (d[hold] @ d[hold])) - 1.0) < 0.02
        ay = res.channels["accel_y"]
        assert ay["status"] == "structural" and ay["signature"]["kind"] == "lag", ay
        t = res.bench.t
        best = -_best_delay(t, m, d, -np.arange(0.0, 0.06, 0.001))
        assert abs(ay["signature"]["value"] - best) < 0.3 * best, (ay, best)
        for c in WHEELS:
            assert res.channels[c]["status"] == "inside the band", (c, res.channels[c])
        # gyro_z: inside the band, or (runs aligned closely enough for the band to resolve it) structural
        # with the lag of the model's yaw response behind the peer's, about 10 ms (module docstring)
        gz = res.channels["gyro_z"]
        assert gz["status"] == "inside the band" or (
            gz["status"] == "structural" and gz["signature"]["kind"] == "lag"
            and 0.005 < gz["signature"]["value"] < 0.015), gz
        assert res.nuisance and all(abs(v) > 0 for v, _ in res.nuisance.values())
        report.write(res, folder / "html")
        html = (folder / "html" / "report.html").read_text()
        assert "Per channel, after the named effects and the nuisance adjustments" in html
        assert "structural, not a catalogue effect; shape lag: the model lags" in html and "Nuisance adjustments" in html
        assert "Accelerations compared in the level frame" in html
        assert json.loads((folder / "html" / "summary.json").read_text())["accel_frame"] == "level"
    if case == "two_at_once":
        assert res.correlations and all(abs(r) < 0.9 for _, _, r in res.correlations), res.correlations
