"""The validation benchmark (issue 30): independent field-data simulators (rtsim.validate.fieldbench),
their physics against analytic references, the seeded split, and a reduced benchmark of the workflow
with truth from the generator only."""
from __future__ import annotations

import pytest

from rtsim.validate.fieldbench import cases

#: the sets' digests, fixed when each was drawn (the held-out set before the method was changed again): a
#: change of the drawing code or of a case shows here. The first held-out set (73 of the seed-30 cases,
#: digest bb2143d3...) was retired after it had been read while diagnosing; so was the second (seed 3030,
#: digest ad102f69...) after it had judged one change and its misses were read, and so were the third (seed 3031,
#: digest 79a5a754...), the fourth (seed 3032, digest 2cb90061...), the fifth (seed 3033, digest
#: c68aa770..., after it had judged the separability rule), the sixth (seed 3034, digest a0e85267..., after
#: it had judged the 5 ms fit step), the seventh (seed 3035, digest 38581287..., after it had judged the
#: sensor candidates' own-readings folds) and the eighth (seed 3036, digest c1e77af6..., after it had judged
#: the folds' plausible range); all are part of "tuning".
DIGESTS = {
    "tuning": "766ea36770345e4c57b87d31de8a2bf9826f5c66c9af8d6b21186d4b8e9aaa15",
    "heldout": "93f34bbb1c8131ca0de10c57cd229ef284afbcc0d79f7dcad964add248e8a4fe",
    "issue": "31c1a086c1bdc272a33010ac06bc0f902c902d57a6e5738c34527f53c38c26ad",
}


def test_split_is_fixed_and_disjoint():
    s = cases.sets()
    assert {k: cases.digest(v) for k, v in s.items()} == DIGESTS
    assert cases.sets() == s                                   # deterministic
    tuning, held = {c["id"] for c in s["tuning"]}, {c["id"] for c in s["heldout"]}
    assert not tuning & held and len(tuning) == cases.N_CASES + sum(n for n, _ in cases.RETIRED_SEEDS.values()) and len(held) == cases.N_HELDOUT >= 60
    # the held-out draw is new data, not a relabelling: no case's data seed or hidden set is shared
    assert not {c["seed"] for c in s["tuning"]} & {c["seed"] for c in s["heldout"]}
    for kind, _ in cases.KINDS:                                # every kind in both sets
        assert any(c["kind"] == kind for c in s["tuning"]) and any(c["kind"] == kind for c in s["heldout"])


def test_cases_are_well_formed():
    from rtsim.vehicle.car.effects import EFFECTS
    for c in [*cases.sets()["tuning"], *cases.sets()["heldout"], *cases.ISSUE]:
        fam = cases.family(c["sim"])
        assert c["tyre"] in cases.TYRES
        n = {"none": 0, "one": 1, "two": 2, "outside": 0}[c["kind"]]
        assert len(c["hidden"]) == n and len(c["outside"]) == (c["kind"] == "outside")
        channels = [h.get("channel") for h in c["hidden"] if "channel" in h]
        assert len(channels) == len(set(channels))
        for h in c["hidden"]:
            spec = EFFECTS[h["effect"]]
            (param, value), = [(k, v) for k, v in h.items() if k not in ("effect", "channel")]
            assert (h["effect"], h.get("channel")) in cases.APPLICABLE[fam]
            if h["effect"] != "sensor_bias":
                lo, hi = spec.bounds(param)
            else:
                lo, hi = spec.bounds(param, h["channel"])
            assert lo <= value <= hi and value != spec.param(param).neutral
        for o in c["outside"]:
            assert o["name"] in cases.OUTSIDE[fam] and o["name"] not in EFFECTS
    assert [c["id"] for c in cases.ISSUE] == ["issue_gyro_z_bias", "issue_accel_y_scale", "issue_tyre_stiffness",
                                             "issue_gyro_z_delay", "issue_mass", "issue_brake_friction"]


# ------------------------------------------------------------------------- the generator's independence
def test_fieldbench_shares_no_model_code():
    """The simulators import nothing of rtsim but their own package: no vehicle model, no multibody code,
    no validation workflow (they read only the config's and `rtsim describe`'s numbers)."""
    import ast
    from pathlib import Path

    import rtsim.validate.fieldbench as fb
    folder = Path(fb.__file__).parent
    allowed_external = {"numpy", "scipy", "numba", "math", "json", "hashlib", "os", "tempfile", "tomllib",
                        "pathlib", "shutil", "__future__"}
    files = sorted(folder.glob("*.py"))
    assert len(files) >= 6
    for path in files:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    assert node.level == 1, (path.name, node.module)      # only this package
                    continue
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            else:
                continue
            for name in names:
                assert name.split(".")[0] in allowed_external, (path.name, name)


# ------------------------------------------------------------------------------ physics of the generator
@pytest.fixture(scope="module")
def car():
    """The simulators' numbers of the test car, from `rtsim describe` and its config."""
    from rtsim.validate.bench import VEHICLE
    from rtsim.validate.fieldbench import vehicle
    from rtsim.validate.replay import Replayer
    from rtsim.vehicle.car.describe import describe
    from rtsim.vehicle.car.sim import VehicleSim
    rp = Replayer(VEHICLE)
    return vehicle.numbers(describe(rp.model, VehicleSim(rp.model, rp.road, 1e-3)), VEHICLE)


def _steady(car, sim, tyre, steer, speed=15.0, **kw):
    """A constant steering-wheel angle held 8 s: the last second's means of the lateral outputs."""
    import numpy as np

    from rtsim.validate.fieldbench import sims
    n = int(round(8.0 / sims.DT))
    out = sims.lateral(sims.lateral_params(car, sim == "roll", tyre, **kw), np.full(n, steer), speed, 0)
    return out[-int(sims.RATE):].mean(axis=0)


@pytest.mark.parametrize("sim, tyre", [("planar", "tanh"), ("planar", "brush"), ("roll", "tanh"), ("roll", "brush")])
def test_steady_turn_linear_range(car, sim, tyre):
    """In the linear range the steady yaw rate is the single-track model's (Milliken & Milliken, ch. 5):
    r = v delta / (L + K v^2), understeer K = m (b / C_f - a / C_r) / L with the axles' cornering
    stiffnesses (two tyres each); the lateral acceleration is v r. The load transfer changes the axle
    stiffness only to second order (both laws are linear at small slip)."""
    from rtsim.validate.fieldbench import sims
    v, sw = 15.0, 0.1
    o = _steady(car, sim, tyre, sw, v)
    a, b = car["a"], car["b"]
    L = a + b
    K = car["mass"] * (b / (2 * car["cy_front"]) - a / (2 * car["cy_rear"])) / L
    r = v * (sw / car["steering_ratio"]) / (L + K * v * v)
    assert o[sims.O_GZ] == pytest.approx(r, rel=0.01)
    assert o[sims.O_AYG] == pytest.approx(v * r, rel=0.01)


def test_steady_roll_angle(car):
    """The roll simulator's steady roll angle: m_s h' a_y / (K_f + K_r - m_s g h') (gravity's moment on the
    rolled sprung mass), its accelerometer the body-frame a_y cos(phi) + g sin(phi)."""
    import math

    from rtsim.validate.fieldbench import sims
    o = _steady(car, "roll", "tanh", 0.5)
    p = sims.lateral_params(car, True, "tanh")
    ay = o[sims.O_AYG]
    phi = p[sims.L_MS] * p[sims.L_HP] * ay / (p[sims.L_KRF] + p[sims.L_KRR] - p[sims.L_MS] * sims.G * p[sims.L_HP])
    assert ay > 2.0 and o[sims.O_ROLL] == pytest.approx(phi, rel=0.02)
    assert o[sims.O_AY] == pytest.approx(ay * math.cos(o[sims.O_ROLL]) + sims.G * math.sin(o[sims.O_ROLL]), rel=0.01)


def test_stiffness_and_mass_effects(car):
    """The hidden tyre stiffness scales the understeer term (a softer tyre, a lower yaw gain, by the
    single-track formula), an added mass at the centre of mass raises it in proportion to the mass."""
    from rtsim.validate.fieldbench import sims
    v, sw = 15.0, 0.1
    a, b = car["a"], car["b"]
    L = a + b
    for kw, m, s in (({"stiffness_scale": 0.6}, car["mass"], 0.6), ({"added_mass": 200.0}, car["mass"] + 200.0, 1.0)):
        K = m * (b / (2 * s * car["cy_front"]) - a / (2 * s * car["cy_rear"])) / L
        r = v * (sw / car["steering_ratio"]) / (L + K * v * v)
        assert _steady(car, "planar", "tanh", sw, v, **kw)[sims.O_GZ] == pytest.approx(r, rel=0.015), kw


@pytest.mark.parametrize("grade", [0.0, 0.04])
def test_pitch_standstill_on_grade(car, grade):
    """Held on the brake on a grade: the body at rest, the accelerometer reads gravity's component along
    the road, g sin(atan(grade)), the wheels do not turn."""
    import math

    import numpy as np

    from rtsim.validate.fieldbench import sims
    n = int(round(3.0 / sims.DT))
    out = sims.pitch(sims.pitch_params(car, "tanh", grade=grade), np.full(n, 2500.0), np.zeros(n), 0)
    rest = out[int(sims.RATE):]
    assert np.mean(rest[:, 0]) == pytest.approx(sims.G * math.sin(math.atan(grade)), abs=0.01)
    assert np.ptp(rest[:, 1]) < 1e-6 and np.ptp(rest[:, 2]) < 1e-6


def test_pitch_drive_and_coast(car):
    """A constant drive torque T per rear wheel on the level: once the transients settle, the car
    accelerates at (2 T / r - rolling resistance - drag) / (m + 2 (J_f + J_r) / r^2), r the loaded radius
    (the wheels' spin inertia accelerates with the car), within 2 %."""
    import numpy as np

    from rtsim.validate.fieldbench import sims
    n = int(round(4.0 / sims.DT))
    T = 200.0
    out = sims.pitch(sims.pitch_params(car, "brush"), np.zeros(n), np.full(n, T), 0)
    k0, k1 = int(2.0 * sims.RATE), int(3.0 * sims.RATE)
    v = out[k0:k1, 8]
    acc = (v[-1] - v[0]) / ((k1 - k0 - 1) / sims.RATE)
    fz_rear = car["fz_rear"]
    r_l = car["unloaded_radius"] - fz_rear / car["tyre_vertical"]
    drag = 0.5 * car["air_density"] * car["drag_area"] * np.mean(v) ** 2
    m_eq = car["mass"] + 2 * (car["j_front"] + car["j_rear"]) / r_l ** 2
    expected = (2 * T / r_l - car["rolling_resistance"] * car["mass"] * sims.G - drag) / m_eq
    assert acc == pytest.approx(expected, rel=0.02)


# ------------------------------------------------------------------------------------- scatter and logger
def test_coloured_noise_statistics():
    """The logger noise's AR(1) part has the stated deviation and step correlation (a long series)."""
    import numpy as np

    from rtsim.validate.fieldbench import scatter
    x = scatter.ar1(np.random.default_rng(1), 400_000, 0.06, 0.98)
    assert np.std(x) == pytest.approx(0.06, rel=0.03)
    assert np.corrcoef(x[1:], x[:-1])[0, 1] == pytest.approx(0.98, abs=0.003)


def test_driver_scatter_statistics():
    """Run to run, the input gain varies by GAIN_SD in its constant part and wanders by at most GAIN_WANDER
    within a run (together about +-2 %); node times shift by SHIFT_SD and stay increasing."""
    import numpy as np

    from rtsim.validate.fieldbench import scatter
    rng = np.random.default_rng(2)
    t = np.linspace(0.0, 12.0, 1201)
    draws = [scatter.Scatter(rng) for _ in range(4000)]
    a = np.array([d.a for d in draws])
    assert np.std(a) == pytest.approx(scatter.GAIN_SD, rel=0.05)
    g = np.array([d.gain(t) for d in draws[:500]])
    assert np.all(np.abs(g - 1.0 - a[:500, None]) <= scatter.GAIN_WANDER + 1e-12)
    assert 0.015 < np.percentile(np.abs(g - 1.0), 95) < 0.03
    nodes = np.array([d.nodes((1.0, 1.6, 4.6)) for d in draws])
    assert np.all(np.diff(nodes, axis=1) > 0)
    assert np.std(nodes[:, 0] - 1.0 * np.array([d.stretch for d in draws])) == pytest.approx(scatter.SHIFT_SD, rel=0.05)


def test_runs_are_quantised_and_readable(car, tmp_path):
    """A case's CSV runs: every channel a whole number of its quantisation steps, noise on every channel
    (no two runs alike), and rtsim validate's loader reads them with the declared frame."""
    import numpy as np

    from rtsim.validate.data import load_runs
    from rtsim.validate.fieldbench import generate, scatter
    case = cases.ISSUE[0]
    paths = generate.write_runs(case, car, tmp_path / "runs", n=2)
    runs, rejected = load_runs(paths)
    assert len(runs) == 2 and not rejected
    for c in generate.channels(case):
        lsb = scatter.NOISE[c][3]
        x = runs[0].channels[c] / lsb
        assert np.max(np.abs(x - np.round(x))) < 1e-3, c
        assert not np.array_equal(runs[0].channels[c][:100], runs[1].channels[c][:100]), c
    assert all(r.accel_frame == "level" for r in runs)


# ------------------------------------------------------------------------------------------------ scoring
def _truth(*effects, separable: bool = True, reproducible: bool = True):
    out = [dict(zip(("effect", "channel", "param", "model_terms", "kind", "larger", "ratio"), e)) for e in effects]
    for e in out:
        e["separable"] = e["larger"] and separable
        e["reproducible"] = reproducible or e["kind"] == "sensor"
    return {"effects": out, "larger": all(e[5] for e in effects),
            "separable": all(e["separable"] for e in out), "reproducible": all(e["reproducible"] for e in out)}


def test_scoring():
    """Outcomes against a truth: the exact set within tolerance is right (10 % sensor, 20 % model, of the
    value in the model's terms), an extra effect is a false naming, a value outside its tolerance is off,
    a smaller-than-structural, inseparable or irreproducible effect may go unnamed, a workflow error is never
    right; the rates count them (named right among the larger separable reproducible cases, among the larger
    separable ones, and among all larger ones)."""
    from rtsim.validate.bench_score import acceptable, confusion, outcome, rates
    bias = ("sensor_bias", "gyro_z", "bias", 0.03, "sensor", True, 5.0)
    tyre = ("tyre_slip_stiffness", None, "scale", 0.55, "model", True, 9.0)
    small = ("mass", None, "added_mass", 100.0, "model", False, 0.5)
    one = {"id": "a", "kind": "one", "sim": "planar", "tyre": "tanh"}
    named = lambda *n: [{"effect": e, "channel": c, "params": {p: v}} for e, c, p, v in n]   # noqa: E731
    r1 = outcome(one, _truth(bias), named(("sensor_bias", "gyro_z", "bias", 0.0327)), "")
    assert r1["status"] == "right" and acceptable(r1, _truth(bias))[0]
    r2 = outcome(one, _truth(bias), named(("sensor_bias", "gyro_z", "bias", 0.0334)), "")
    assert r2["status"] == "value off" and not acceptable(r2, _truth(bias))[0]
    r3 = outcome(one, _truth(tyre), named(("tyre_slip_stiffness", None, "scale", 0.65),
                                          ("mass", None, "added_mass", 12.8)), "")
    assert r3["status"] == "false" and r3["extra"] == ["mass"] and not acceptable(r3, _truth(tyre))[0]
    r4 = outcome(one, _truth(small), [], "... cannot be told apart ...")
    assert r4["status"] == "missed" and r4["told_apart"] and acceptable(r4, _truth(small))[0]
    r5 = outcome(one, _truth(tyre), [], "")
    assert not acceptable(r5, _truth(tyre))[0]
    none = {"id": "n", "kind": "none", "sim": "pitch", "tyre": "tanh"}
    r6 = outcome(none, _truth(), named(("road_grade", None, "grade", 0.01)), "")
    r7 = outcome(none, _truth(), [], "no catalogue effect")
    assert (r6["status"], r7["status"]) == ("false", "right")
    r8 = outcome(none, _truth(), [], "", error="ConvergenceError: the replay stopped")
    assert r8["status"] == "error" and not acceptable(r8, _truth())[0]     # never right by naming nothing
    drag = ("rolling_resistance", None, "coefficient", 0.012, "model", True, 16.0)
    alike = _truth(drag, separable=False)          # a bearing drag reproduces it within the structural mismatch
    r9 = outcome(one, alike, [], "... cannot be told apart ...")
    assert r9["status"] == "missed" and not r9["separable"] and acceptable(r9, alike)[0]
    r10 = outcome(one, alike, named(("bearing_drag", None, "torque", 6.6)), "")
    assert r10["status"] == "false" and not acceptable(r10, alike)[0]
    heavy = ("mass", None, "added_mass", 216.0, "model", True, 3.7)
    foreign = _truth(heavy, reproducible=False)    # the model's own 216 kg changes the runs otherwise
    r11 = outcome(one, foreign, [], "... cannot be told apart ...")
    assert r11["status"] == "missed" and not r11["reproducible"] and acceptable(r11, foreign)[0]
    r12 = outcome(one, foreign, named(("mass", None, "added_mass", 30.0)), "")
    assert r12["status"] == "value off" and not acceptable(r12, foreign)[0]
    rt = rates([r1, r2, r3, r4, r5, r6, r7, r9, r11])
    assert rt["named_right"]["count"] == 1 and rt["named_right"]["of"] == 4       # r1 of r1 r2 r3 r5
    assert rt["named_right_separable"]["count"] == 1 and rt["named_right_separable"]["of"] == 5      # and r11
    assert rt["named_right_larger"]["count"] == 1 and rt["named_right_larger"]["of"] == 6      # and r9
    assert rt["inseparable_told_apart"] == {"share": 1.0, "count": 1, "of": 1}
    assert rt["false_naming"]["count"] == 2 and rt["none_cases_named"] == {"share": 0.5, "count": 1, "of": 2}
    assert rt["cannot_be_told_apart"]["count"] == 3
    conf = confusion([r1, r3, r6, r7])
    assert conf["sensor_bias[gyro_z]"]["sensor_bias[gyro_z]"] == 1 and conf["tyre_slip_stiffness"]["mass"] == 1
    assert conf["none"] == {"road_grade": 1, "nothing": 1}


def test_rival_fit_finds_a_mimic_and_respects_its_range():
    """bench_truth.rivals on a replayer whose effects are known in closed form: a rival whose change is the
    hidden change at 3 times its first trial is found at that value (ratio ~0: inseparable); one whose
    change has another shape, or whose range stops short of the value it needs, leaves at least RATIO."""
    from types import SimpleNamespace

    import numpy as np

    from rtsim.validate import bench_truth
    from rtsim.vehicle.car.effects import EffectSpec, ParamSpec
    t = np.linspace(0.0, 10.0, 1001)
    f, g = np.sin(t), np.tanh(t - 5.0)
    change = {"a": 0.3 * f, "b": 0.1 * g}
    shapes = {"alike": lambda v: {"a": 0.1 * v * f, "b": v * 0.1 / 3.0 * g},
              "other": lambda v: {"a": 0.1 * v * v * np.cos(t), "b": 0.0 * g}}

    def spec(name, hi):
        return EffectSpec(name, "model", (ParamSpec("p", "1", 1.0, 0.0, hi, "", 0.0),), "", "")

    class Fake:
        wheel_radius = 0.3
        model = SimpleNamespace(channels=SimpleNamespace(sensor_names=()))

        def __init__(self, catalogue):
            self.profile = SimpleNamespace(effects=catalogue)

        def inputs(self, bench):
            return None

        def simulate(self, inp, effects, fit=False, dt=None):
            out = {"a": np.zeros_like(t), "b": np.zeros_like(t)}
            for e in effects:
                for c, x in shapes[e.name](e.params["p"]).items():
                    out[c] = out[c] + x
            return out

        def reported(self, raw, tg, effects):
            return raw

    scale = {"a": 0.01, "b": 0.01}
    args = (SimpleNamespace(t=t), ("hidden", None), scale, {}, t, np.zeros(t.size, bool))
    best = bench_truth.rivals(change, Fake({"alike": spec("alike", 5.0), "other": spec("other", 5.0)}), *args)
    assert best["effect"] == "alike" and best["value"] == pytest.approx(3.0, rel=1e-6) and best["ratio"] < 1e-6
    best = bench_truth.rivals(change, Fake({"other": spec("other", 5.0)}), *args)
    assert best["effect"] == "other" and best["ratio"] >= bench_truth.RATIO
    # the model's own version of the hidden effect: at 3 it gives the hidden change (reproducible), at 1 it
    # leaves two thirds of it (20 times the scale on "a"), and an effect of another shape leaves it all
    from rtsim.validate.effectset import Effect
    own = (SimpleNamespace(t=t), scale, {}, t, np.zeros(t.size, bool))
    fake = Fake({})
    assert bench_truth.reproduced(change, fake, own[0], Effect("alike", {"p": 3.0}), *own[1:]) < 1e-6
    assert bench_truth.reproduced(change, fake, own[0], Effect("alike", {"p": 1.0}), *own[1:]) == pytest.approx(
        20.0 * np.sqrt(np.mean(f * f)), rel=1e-3)
    assert bench_truth.reproduced(change, fake, own[0], Effect("other", {"p": 1.0}), *own[1:]) >= bench_truth.RATIO
    best = bench_truth.rivals(change, Fake({"alike": spec("alike", 2.0)}), *args)    # needs 3, may reach 2
    assert best["value"] == 2.0 and best["ratio"] >= bench_truth.RATIO


# ------------------------------------------------------------------------------------ reduced benchmark
#: THE one list of the reduced benchmark's cases that fail with today's method, each with its reason (what
#: the bar check said). A case here is a strict expected failure: when the method is changed and it
#: passes, the test fails until it is taken off this list.
EXPECTED_FAILURES: dict[str, str] = {
    "c016": "a 2.1 % scale of one wheel angle (fl 0.979) beside a gyro_z scale: gyro_z named right (0.8996, "
            "0.8949 in the model's terms), then the axle's one relative scale taken on the other wheel (fr 1.018: "
            "with the axle's rolling radius adjusted the two wheels differ only by that radius's prior): "
            "sensor_scale[wheel_angle_fr] named, not hidden",
}


def _reduced():
    from rtsim.validate.bench import select
    out = []
    for c in select("tuning", reduced=True):
        marks = [pytest.mark.xfail(strict=True, raises=BarMissed, reason=EXPECTED_FAILURES[c["id"]])] \
            if c["id"] in EXPECTED_FAILURES else []
        out.append(pytest.param(c, id=c["id"], marks=marks))
    return out


class BarMissed(AssertionError):
    """The workflow's answer on a benchmark case does not meet the bar (bench_score.acceptable)."""


@pytest.fixture(scope="module")
def bench():
    from rtsim.validate.bench import Bench
    return Bench()


@pytest.mark.parametrize("case", _reduced())
def test_reduced_benchmark(bench, tmp_path_factory, case):
    """The workflow on a benchmark case (a few tuning cases and the issue's six), judged against the
    generator's truth with fixed tolerances (sensor effects 10 %, model effects 20 % of the value in the
    model's terms; bench_truth, bench_score): nothing named that was not hidden, every effect larger than
    the structural mismatch, separable and reproducible named; on the issue's six, every larger effect."""
    from rtsim.validate.bench_score import acceptable
    rec = bench.run(case, tmp_path_factory.mktemp("bench"), workers=2)
    print(f"\n[{case['id']}] {rec['label']}: named {rec['found']}; truth {rec['truth']['effects']}; "
          f"{rec['seconds']}\n  verdict: {rec['verdict'][:400]}")
    assert rec["error"] is None, rec["error"]
    truth = rec["truth"]
    if case["id"].startswith("issue_"):
        # the issue's six must be named whatever the model's own version of each does (bench_truth, "Reproducible")
        truth = {**truth, "effects": [{**e, "reproducible": True} for e in truth["effects"]]}
    ok, why = acceptable(rec, truth)
    if not ok:
        raise BarMissed(why)
