"""Ground truth of a field-benchmark case (rtsim.validate.fieldbench), from the generator and, where a
hidden value means something else in rtsim's model, from the model replayed without any effect; never
from the validation workflow's fits.

Values in the model's terms (what a right fit finds):
- tyre_slip_stiffness: the scale s of rtsim's Magic Formula tyre (slip angles fed as atan(s tan alpha))
  whose lateral forces match the simulator's, least squares over the four tyres' operating points (load,
  slip angle, lateral force) of the noise-free run with the effect, every 50 ms where |tan alpha| >
  0.002: a tyre-level fit of the two tyre laws, no vehicle fit;
- sensor effects: the hidden value composed with what the model, replayed without any effect on the
  noise-free nominal run, reads on the channel: a bias plus the mean offset (simulator - model; on
  accel_x less the part a resistance offset within +-0.03 m/s^2 takes), a scale
  times the least-squares gain of the simulator's channel on the model's, a delay plus the time shift
  (+-0.1 s, 0.5 ms steps) that best aligns the model's channel with the simulator's (the model's own lag
  reads as part of a delay); a wheel angle's scale as hidden (the other wheel of its axle is the
  reference);
- every other model effect: the hidden value (the simulators implement the catalogue's definitions).

"Larger than the structural mismatch" (decided before the method changed). On the noise-free nominal run (no
scatter, no noise) on the workflow's 100 Hz grid, per compared channel c: the structural mismatch S_c =
RMS(model without effect - simulator without effect), the effect's size E_c = RMS of the change it makes to
that difference (simulator with the effect alone minus the model replaying that run's inputs, minus the same
without the effect: a model effect's change of the recorded inputs, e.g. the speed controller's torques, is
replayed; a sensor effect changes the reading alone), both after removing by least squares what a field
validation must allow for anyway (wheel speeds, per axle: one scale of both wheels, a rolling radius within
+-1.5 %, and one drift growing linearly with the time moved, a resistance offset within +-0.03 m/s^2; accel_x:
that offset while moving; bounded least squares), and the floor F_c = the channel's noise left in the mean of
the seven runs (sd / sqrt(7)). An effect is larger iff max over c of E_c / max(S_c, F_c) >= `RATIO`; a case is
larger iff every hidden effect is.

"Separable" (decided before the seed-3033 draw was run). A larger effect may still change the runs as some other
catalogue effect would (a rolling resistance and a bearing drag both retard a straight run by a constant total
force); then no method can tell which of the two it is, and "cannot be told apart" is the right verdict. For
each larger hidden effect, every other effect of the vehicle's catalogue (each model effect; each sensor effect
on each compared channel and wheel angle) is fitted to the hidden effect's change on the same inputs, with the
model itself: the rival's change of the model's readings (the model replaying the run with the hidden effect
at `RIVAL_DT`, 2 ms, the rival switched on, minus the same without it) scaled to match the hidden
effect's change E (weighted least squares, channels in units of max(S_c, F_c), within the rival's
plausible range; the change taken linear in the value, through neutral and the first trial, then through the
last two replays), replayed at the value found, up to `RIVAL_REPLAYS` replays; the lowest ratio is kept
(an upper bound of the best a rival can do: never calls a separable effect inseparable). The rival's
ratio is max over c of the left-over of E minus its change, over max(S_c, F_c); the effect is separable iff
every rival's ratio is at least `RATIO` (the same level as "larger"); a case is separable iff every hidden
effect is. A rival whose neutral value is at an infinite parameter (driveline_compliance: an infinitely stiff
driveline) is not tried: its change is not a slope through neutral; the benchmark's manoeuvres drive smooth
torques, which its signature says it leaves almost unchanged.

"Reproducible" (decided after the seed-3036 draw had been read, before the seed-3037 draw was made). A model
effect's value in the model's terms is the hidden value (above) on the premise that the model's version of the
effect changes the runs as the simulator's does. Where the change passes through a part the two do not share, it
need not: an added mass loads the tyres, and the brush tyre's cornering stiffness grows as load^0.7 where the
model's Magic Formula tyre has its own load sensitivity: in case r039 (planar simulator, brush tyres) 216 kg
changes the yaw rate by 3.7 times the structural mismatch and the model's 216 kg by 9.5 times, nearly the other
way (their difference: 11.8 times). Such an effect has no value in the model's terms: what the runs show is the
effect plus a structural difference it brings out. For each larger hidden model effect the model replays the
run's inputs with the effect at its value in the model's terms (at `RIVAL_DT`), and the left-over of the
simulator's change minus the model's (as for a rival) is taken, max over the channels, in units of max(S_c, F_c)
(`own_ratio`); the effect is reproducible iff it is below `RATIO`. A sensor effect is reproducible (it changes
the readings alone, the same way in both). The bar's denominator is the larger, separable and reproducible
cases; the rates before this rule are reported beside it.
"""
from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path

import numpy as np

from rtsim.sources import sources_digest

from .fieldbench import generate, scatter

RATIO = 2.0
RIVAL_REPLAYS = 3            # replays per model rival, at most (module docstring)
RIVAL_DT = 2e-3              # s, the rivals' replay step: fixed here, apart from the workflow's fit step
RADIUS_RANGE = 0.015         # an axle's rolling radius, relative
OFFSET_RANGE = 0.03          # m/s^2, a resistance offset
WHEEL_SPEED_FLOOR = 0.05     # rad/s: a wheel speed's noise left in the mean (quantised angles derived)
TOL = {"sensor": 0.10, "model": 0.20}


def _floor(channel: str) -> float:
    if channel.startswith("wheel_speed_"):
        return WHEEL_SPEED_FLOOR
    sd, _, white, _ = scatter.NOISE.get(channel, (0.0, 0.0, 0.0, 0.0))
    return math.hypot(sd, white) / math.sqrt(generate.N_RUNS)


def _bench(case, t, ch, folder: Path, name: str, sensor_names, profile):
    from .benchmark import build_benchmark
    from .data import load_runs
    names = generate.channels(case)
    p = generate.write_csv(folder / f"{name}.csv", t + 10.0, ch, names, generate.accel_frame(case))
    runs, rejected = load_runs([p], sensor_names)
    return build_benchmark(runs, rejected, profile=profile)


def _left_over(diff: dict, data0: dict, t: np.ndarray, moving: np.ndarray, radius: float) -> dict:
    """Per channel, the RMS of `diff` (channel -> difference on the grid) after removing by bounded least
    squares what a field validation must allow for (module docstring): per axle, one scale of both wheel
    speeds within +-`RADIUS_RANGE` (a rolling radius) and one drift growing with the time moved, a
    resistance offset within +-`OFFSET_RANGE` m/s^2 (divided by the wheel radius); accel_x, that offset
    while moving."""
    from scipy.optimize import lsq_linear
    out = {}
    drift = np.cumsum(moving) * (t[1] - t[0])
    for axle in ("f", "r"):
        pair = [c for c in (f"wheel_speed_{axle}l", f"wheel_speed_{axle}r") if c in diff]
        if pair:
            basis = np.vstack([np.column_stack([data0[c], drift]) for c in pair])
            x = np.concatenate([diff[c] for c in pair])
            lim = np.array([RADIUS_RANGE, OFFSET_RANGE / radius])
            coef = lsq_linear(basis, x, bounds=(-lim, lim)).x
            rest = (x - basis @ coef).reshape(len(pair), -1)
            out.update({c: _rms(r) for c, r in zip(pair, rest)})
    for c, d in diff.items():
        if c in out:
            continue
        if c == "accel_x" and moving.any():
            d = d - moving * float(np.clip(d[moving].mean(), -OFFSET_RANGE, OFFSET_RANGE))
        out[c] = _rms(d)
    return out


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _best_shift(t, model, data) -> float:
    """d (s) with model(t - d) closest to data (least squares, +-0.1 s in 0.5 ms steps)."""
    ds = np.arange(-0.1, 0.1 + 1e-9, 5e-4)
    return float(ds[np.argmin([np.mean((np.interp(t - d, t, model) - data) ** 2) for d in ds])])


def _first_trial(pspec, hi: float) -> float:
    """A rival parameter's first trial value: its typical value, or a tenth of the way to its upper bound
    where the typical value is the neutral one (a sensor bias)."""
    n = pspec.neutral
    return pspec.default if pspec.default != n else n + 0.1 * (hi - n)


class _Replays:
    """The model replaying the inputs of `bench1` at `RIVAL_DT`: its readings without any effect (`base`)
    and the change one effect makes to them on `channels` (`delta`; a sensor effect changes the readings of
    the same motion)."""

    def __init__(self, replayer, bench1, channels: list[str]):
        self.replayer, self.t, self.channels = replayer, bench1.t, channels
        self.inputs = replayer.inputs(bench1)
        self.raw = replayer.simulate(self.inputs, [], dt=RIVAL_DT)
        self.base = replayer.reported(self.raw, self.t, [])

    def delta(self, eff) -> dict:
        rp = self.replayer
        out = rp.reported(rp.simulate(self.inputs, [eff], dt=RIVAL_DT) if eff.kind == "model" else self.raw,
                          self.t, [eff])
        return {c: out[c] - self.base[c] for c in self.channels}


def _left_ratios(change: dict, d: dict, scale: dict, data0: dict, t: np.ndarray, moving: np.ndarray,
                 radius: float) -> np.ndarray:
    """Per channel of `d`, the left-over (`_left_over`) of `change` minus `d`, in units of `scale`."""
    rest = _left_over({c: change[c] - d[c] for c in d}, data0, t, moving, radius)
    return np.array([rest[c] / scale[c] for c in d])


def reproduced(change: dict, replayer, bench1, effect, scale: dict, data0: dict, t: np.ndarray,
               moving: np.ndarray) -> float:
    """How far the model's own version of a hidden model effect, `effect` at its value in the model's terms,
    falls short of the simulator's change `change` (module docstring, "Reproducible"): max over the channels
    of the left-over of change minus the model's change, in units of `scale` (max(S_c, F_c))."""
    channels = [c for c in change if c in scale]
    d = _Replays(replayer, bench1, channels).delta(effect)
    return float(_left_ratios(change, d, scale, data0, t, moving, replayer.wheel_radius).max())


def rivals(change: dict, replayer, bench1, hidden: tuple, scale: dict, data0: dict, t: np.ndarray,
           moving: np.ndarray) -> dict | None:
    """The catalogue effect other than `hidden` ((effect, channel)) that reproduces `change` (channel -> the
    hidden effect's change on the grid) best, as {"effect", "channel", "value", "ratio"}: the module
    docstring's separability fit, on the inputs of `bench1` (the runs with the hidden effect); `scale`:
    channel -> max(S_c, F_c). None when the catalogue has no rival to try."""

    from .effectset import Effect
    channels = [c for c in change if c in scale]
    rep = _Replays(replayer, bench1, channels)
    delta = rep.delta
    sensors = [c for c in rep.raw if c in replayer.model.channels.sensor_names
               and (c in channels or c.startswith("wheel_angle_"))]

    def left(d: dict) -> np.ndarray:
        return _left_ratios(change, d, scale, data0, t, moving, replayer.wheel_radius)

    best = None
    for name, spec in replayer.profile.effects.items():
        pspec = spec.params[0]
        n = pspec.neutral
        if n is None:
            continue
        for channel in ([None] if spec.kind == "model" else sensors):
            if (name, channel) == hidden:
                continue
            lo, hi = spec.bounds(pspec.name, channel)

            def effect(v: float) -> Effect:
                return Effect(name, {pspec.name: v} if channel is None else {"channel": channel, pspec.name: v})
            v, ratio, at = _first_trial(pspec, hi), math.inf, math.nan
            v_prev, d_prev = n, {c: 0.0 for c in channels}
            for k in range(RIVAL_REPLAYS):
                d = delta(effect(v))
                r = float(left(d).max())
                if r < ratio:
                    ratio, at = r, v
                if ratio < RATIO or k == RIVAL_REPLAYS - 1:
                    break
                slope = {c: (d[c] - d_prev[c]) / (v - v_prev) for c in channels}   # secant through the last two
                num = sum(float(np.dot(slope[c], change[c] - d[c])) / scale[c] ** 2 for c in channels)
                den = sum(float(np.dot(slope[c], slope[c])) / scale[c] ** 2 for c in channels)
                v_next = float(np.clip(v + num / den, lo, hi)) if den > 0.0 else v
                if v_next == v:
                    break
                v_prev, d_prev, v = v, d, v_next
            if best is None or ratio < best["ratio"]:
                best = {"effect": name, "channel": channel, "value": at, "ratio": ratio}
    return best


def tyre_equivalent(tyre_params, fz, tan_alpha, fy, speed: float) -> float:
    """The MF scale s reproducing the simulator's lateral forces (module docstring)."""
    from scipy.optimize import minimize_scalar

    from rtsim.vehicle.kit.tyre.magic_formula import mf52_forces
    pts = [(f, a, y) for f, a, y in zip(fz.ravel(), tan_alpha.ravel(), fy.ravel()) if abs(a) > 0.002]

    def cost(s):
        return sum((mf52_forces(tyre_params, f, 0.0, math.atan(s * a), 0.0, speed, 1.0)[1] - y) ** 2
                   for f, a, y in pts)
    return float(minimize_scalar(cost, bounds=(0.2, 3.0), method="bounded", options={"xatol": 1e-4}).x)


def truth(case: dict, car: dict, replayer, tyre_params) -> dict:
    """The case's ground truth (module docstring): per hidden effect its hidden value, its value in the
    model's terms, its size ratio and, when larger, the rival that reproduces it best (`rivals`), whether
    it is separable and (a model effect) how far the model's own version falls short (`reproduced`); per
    channel the structural mismatch; `larger`, `separable` and `reproducible` for the case."""
    from .effectset import Effect, kind
    frame = generate.accel_frame(case)
    old = replayer.accel_frame
    replayer.accel_frame = frame
    names = replayer.model.channels.sensor_names
    try:
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            t, ch0 = generate.simulate(case, car, None, {})
            b0 = _bench(case, t, ch0, folder, "clean", names, replayer.profile)
            model = replayer.reported(replayer.simulate(replayer.inputs(b0), []), b0.t, [])
            compared = list(b0.compared)
            tg = b0.t
            data0 = {c: b0.mean(c) for c in compared}
            moving = np.abs(data0.get("wheel_speed_rl", np.ones_like(tg))) > 0.5
            radius = replayer.wheel_radius
            structural = _left_over({c: model[c] - data0[c] for c in compared}, data0, tg, moving, radius)
            effects = []
            for h in case["hidden"]:
                alone = {"hidden": [h], "outside": []}
                t1, ch1 = generate.simulate(case, car, None, generate.sim_kwargs({**case, **alone}))
                for c, eff in generate.sensor_effects({**case, **alone}).items():
                    ch1[c] = scatter.sensor_effect(t1, ch1[c], **eff)
                b1 = _bench(case, t1, ch1, folder, f"with_{len(effects)}", names, replayer.profile)
                if kind(h["effect"]) == "model":      # the residual's change: inputs that feed back (the
                    # speed controller's torques) change the model's replay too
                    model1 = replayer.reported(replayer.simulate(replayer.inputs(b1), []), b1.t, [])
                    change = {c: (b1.mean(c) - model1[c]) - (data0[c] - model[c]) for c in compared if c in b1.bands}
                else:
                    change = {c: b1.mean(c) - data0[c] for c in compared if c in b1.bands}
                size = _left_over(change, data0, tg, moving, radius)
                ratio = {c: size[c] / max(structural[c], _floor(c)) for c in size}
                param, value = next((k, v) for k, v in h.items() if k not in ("effect", "channel"))
                channel = h.get("channel")
                terms = value
                if h["effect"] == "tyre_slip_stiffness":
                    terms = tyre_equivalent(tyre_params, ch1["_fz"][::25], ch1["_tan_alpha"][::25], ch1["_fy"][::25],
                                            case["speed"])
                elif channel is not None and not channel.startswith("wheel_angle_") and channel in data0:
                    m, d = model[channel], data0[channel]
                    if h["effect"] == "sensor_bias":
                        off = float(np.mean(d - m))
                        if channel == "accel_x":         # the resistance offset takes up to OFFSET_RANGE of it
                            off -= float(np.clip(off, -OFFSET_RANGE, OFFSET_RANGE))
                        terms = value + off
                    elif h["effect"] == "sensor_scale":
                        terms = value * float(m @ d / (m @ m))
                    elif h["effect"] == "sensor_delay":
                        terms = value + _best_shift(tg, m, d)
                best = max(ratio, key=ratio.get)
                larger = ratio[best] >= RATIO
                rival, own = None, None
                if larger:
                    scale = {c: max(structural[c], _floor(c)) for c in change}
                    rival = rivals(change, replayer, b1, (h["effect"], channel), scale, data0, tg, moving)
                    if kind(h["effect"]) == "model":
                        own = reproduced(change, replayer, b1, Effect(h["effect"], {param: terms}), scale, data0,
                                         tg, moving)
                effects.append({"effect": h["effect"], "channel": channel, "param": param, "hidden": value,
                                "model_terms": terms, "kind": kind(h["effect"]), "ratio": ratio[best],
                                "ratio_channel": best, "larger": larger, "rival": rival,
                                "separable": larger and (rival is None or rival["ratio"] >= RATIO),
                                "own_ratio": own, "reproducible": own is None or own < RATIO})
            nominal = None
            if case["sim"] != "pitch":
                nominal = tyre_equivalent(tyre_params, ch0["_fz"][::25], ch0["_tan_alpha"][::25], ch0["_fy"][::25],
                                          case["speed"])
    finally:
        replayer.accel_frame = old
    return {"id": case["id"], "effects": effects, "structural": structural,
            "larger": bool(effects) and all(e["larger"] for e in effects),
            "separable": bool(effects) and all(e["separable"] for e in effects),
            "reproducible": all(e["reproducible"] for e in effects), "tyre_nominal_in_model_terms": nominal}


def cached_truth(case: dict, car: dict, replayer, tyre_params, root: Path | None = None) -> dict:
    """`truth`, cached on disk beside the generated runs (keyed by the case, the car and all of rtsim's code:
    the truth replays the runs through the validation's model, rtsim.sources)."""
    root = Path(root or generate.cache_root())
    path = root / f"{case['id']}_{generate.key(case, car, 'truth-v5-' + sources_digest().hex())}.json"
    if path.exists():
        return json.loads(path.read_text())
    out = truth(case, car, replayer, tyre_params)
    root.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(out, indent=1))
    tmp.replace(path)
    return out
