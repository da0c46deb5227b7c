"""The selection rule's trade test (identify.made_worse) on synthetic repetitions whose truth is known.

Seven runs of two channels: `a`, which a hidden effect moves by many standard errors, and `b`, which the
effect moves a little and on which the model has a structural mismatch (in every run alike) lying partly
against the effect's change there. The true effect then predicts `b` worse in every left-out run, so the
paired fold test finds it worse however small the change is; the rule must not count that as a trade.
A wrong candidate that makes a mismatch of its own on a channel the model fitted within the noise must be
counted. Everything is in standard errors of the mean (scale 1)."""
from __future__ import annotations

import numpy as np

from rtsim.validate.crossval import leave_one_run_out, normalised
from rtsim.validate.identify import DISCREPANCY_Z, made_worse
from rtsim.validate.objective import Objective

N_RUNS = 7
T = np.linspace(0.0, 10.0, 501)


def _unit(x: np.ndarray) -> np.ndarray:
    """x scaled to an RMS of 1."""
    return x / np.sqrt(np.mean(x * x))


def _objective(mean: dict, seed: int = 1) -> Objective:
    """Runs around `mean`: per run a smooth deviation (an amplitude that varies from run to run) and white
    noise, sized so that the standard error of the mean is about 1."""
    rng = np.random.default_rng(seed)
    runs = {}
    for c, m in mean.items():
        smooth = _unit(np.sin(0.7 * T + (1.0 if c == "a" else 2.0)))
        rows = [m + np.sqrt(N_RUNS) * (0.3 * rng.standard_normal() * smooth + 0.9 * rng.standard_normal(T.size))
                for _ in range(N_RUNS)]
        runs[c] = np.array(rows) - np.mean(rows, axis=0) + m        # the runs' mean is exactly `mean`
    return Objective(list(mean), {c: 1.0 for c in mean}, dict(mean), runs, {c: 50.0 for c in mean}, 10.0)


def _by(obj: Objective, before: dict, after: dict) -> dict:
    """channel -> (cost before, cost with it, moved by), as identify.channel_evidence keeps them."""
    ra, rb = obj.channel_residual(after), obj.channel_residual(before)
    return {c: (float(np.mean(rb[c] ** 2)), float(np.mean(ra[c] ** 2)), float(np.sqrt(np.mean((ra[c] - rb[c]) ** 2))))
            for c in obj.channels}


def _judge(obj: Objective, before: dict, after: dict, direction: dict):
    J = normalised(obj, direction)
    cv = leave_one_run_out(obj, normalised(obj, before), normalised(obj, after), J)
    return cv, _by(obj, before, after)


def test_a_true_effect_moving_along_a_structural_mismatch_is_not_a_trade():
    shape_a = _unit(np.sin(1.3 * T) + 0.5 * T / T[-1])
    shape_b = _unit(np.cos(0.9 * T))
    other_b = _unit(np.sin(2.9 * T) - np.mean(np.sin(2.9 * T)))
    other_b = _unit(other_b - shape_b * np.mean(other_b * shape_b))
    effect = {"a": 8.0 * shape_a, "b": 1.0 * shape_b}
    # the structural mismatch on b: RMS about 6, its component along the effect's change there -2 (a true
    # effect makes b worse when that component is below -1/2 of its change)
    structure_b = -2.0 * shape_b + 5.7 * other_b
    model = {"a": np.zeros(T.size), "b": np.zeros(T.size)}
    obj = _objective({"a": model["a"] + effect["a"], "b": model["b"] + effect["b"] + structure_b})
    true = {c: model[c] + effect[c] for c in model}
    cv, by = _judge(obj, model, true, effect)
    assert cv.better                                  # it predicts the left-out runs better overall
    assert cv.worsens("b")                            # the fold test reads the structure as "worse" on b
    assert by["b"][2] < DISCREPANCY_Z * np.sqrt(by["b"][0])
    assert made_worse(cv, by, obj.channels) == []     # ... which the rule does not count as a trade


def test_a_candidate_that_makes_a_mismatch_of_its_own_is_a_trade():
    shape_a = _unit(np.sin(1.3 * T) + 0.5 * T / T[-1])
    shape_b = _unit(np.cos(0.9 * T))
    model = {"a": np.zeros(T.size), "b": np.zeros(T.size)}
    obj = _objective({"a": model["a"] + 8.0 * shape_a, "b": model["b"]})      # b: the model fits within noise
    wrong = {"a": 8.0 * shape_a, "b": 4.0 * shape_b}                          # explains a, spoils b
    cv, by = _judge(obj, model, wrong, wrong)
    assert cv.better
    assert made_worse(cv, by, obj.channels) == ["b"]


def _gain_case():
    """A hidden scale of 1.15 on channel `g` and a model effect (true value 1) that moves `a` and `g`; the
    model as it stands read the scale without the model effect (1.25: it took part of the effect's change
    on `g`, which lies partly along the signal itself)."""
    y_g = 10.0 * _unit(np.sin(0.8 * T) + 0.3)                     # the model's g before the effect
    d_a = 2.0 * _unit(np.sin(1.3 * T) + 0.5 * T / T[-1])          # the effect's change per unit value
    d_g = 3.0 * _unit(np.sin(0.8 * T) + 0.2 * np.cos(2.1 * T))
    truth = {"a": d_a, "g": 1.15 * (y_g + d_g)}
    obj = _objective(truth)
    return obj, y_g, d_a, d_g


def _outputs(scale: float, value: float, y_g, d_a, d_g) -> dict:
    return {"a": value * d_a, "g": scale * (y_g + value * d_g)}


def test_a_named_sensor_scale_refitted_lets_the_model_effect_take_its_value():
    obj, y_g, d_a, d_g = _gain_case()
    named = 1.25
    base = _outputs(named, 0.0, y_g, d_a, d_g)

    def fitted(o: Objective) -> float:
        """The model effect's least-squares value (one Gauss-Newton step from 0, exact here to first order)
        seen through the objective's adjustments."""
        r0 = o.residual(base)
        Jp = o.residual(_outputs(named, 1.0, y_g, d_a, d_g)) - r0
        return -float(Jp @ r0) / float(Jp @ Jp)

    held = fitted(obj)
    col = normalised(obj, _outputs(named + 0.01, 0.0, y_g, d_a, d_g)) - normalised(obj, base)
    refit = obj.refitting(["sensor_scale[g]"], [col / 0.01], [0.5 - named], [2.0 - named])
    free = fitted(refit)
    assert abs(held - 1.0) > 0.15                   # the scale held at its value fights the effect on g
    assert abs(free - 1.0) < 0.05                   # re-fitted beside it, the effect takes its true value
    # the model effect added, the scale re-fitted on the model as it now stands comes back to the hidden one
    at = _outputs(named, free, y_g, d_a, d_g)
    col = normalised(obj, _outputs(named + 0.01, free, y_g, d_a, d_g)) - normalised(obj, at)
    again = obj.refitting(["sensor_scale[g]"], [col / 0.01], [0.5 - named], [2.0 - named])
    assert abs(named + again.nuisance.refit_values(again.raw_residual(at))[0] - 1.15) < 0.01
    assert again.nuisance_values(at) == {}          # a named effect re-fitted is no nuisance adjustment
