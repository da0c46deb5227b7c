"""A sensor effect's leave-one-run-out test takes each run's own replay with the effect (crossval,
`cand_deviations`; identify.sensor_deviations), not the effect's change on the mean added to every run.

Synthetic truth: seven runs of a stop whose onset differs from run to run (-40 ... +40 ms, the driver's
timing; each run's own replay has the same onset, as the model replaying that run's brake pressure does),
read by an accelerometer that lags 50 ms, plus white noise. The model without the lag predicts each run
from its own replay; the lag must predict every left-out run better, and significantly. Carrying the
lag's change on the mean into every run puts the lagged onset at the mean's time in every run: a run
that brakes 40 ms early is then predicted worse than without the lag, which is what left accel_x delays
of 0.04-0.09 s on the benchmark's braking simulator unnamed."""
from __future__ import annotations

import numpy as np

from rtsim.validate.crossval import ALPHA, leave_one_run_out
from rtsim.validate.objective import Objective

T = np.arange(0.0, 6.0, 0.01)
ONSETS = 2.0 + np.array([-0.040, -0.025, -0.010, 0.0, 0.012, 0.026, 0.037])
LAG = 0.05
NOISE = 0.05                                       # m/s^2, per sample


def _stop(onset: float) -> np.ndarray:
    """accel_x of a stop: -6 m/s^2 reached over 0.1 s from `onset`, released at 4 s."""
    return -6.0 * np.clip((T - onset) / 0.1, 0.0, 1.0) * (T < 4.0)


def _lagged(x: np.ndarray) -> np.ndarray:
    return np.interp(T - LAG, T, x, left=x[0])


def test_a_sensor_lag_is_judged_on_each_runs_own_readings():
    rng = np.random.default_rng(3)
    model_runs = [_stop(t0) for t0 in ONSETS]                    # the model replaying each run's inputs
    data = np.array([_lagged(m) + NOISE * rng.standard_normal(T.size) for m in model_runs])
    se = NOISE / np.sqrt(len(ONSETS))
    obj = Objective(["accel_x"], {"accel_x": se}, {"accel_x": data.mean(axis=0)}, {"accel_x": data},
                    {"accel_x": float(T.size)}, 1.0)
    model_mean = np.mean(model_runs, axis=0)
    m0 = model_mean / se
    m1 = np.mean([_lagged(m) for m in model_runs], axis=0) / se
    dev0 = [(m - model_mean) / se for m in model_runs]
    lagged_mean = np.mean([_lagged(m) for m in model_runs], axis=0)
    dev1 = [(_lagged(m) - lagged_mean) / se for m in model_runs]

    own = leave_one_run_out(obj, m0, m1, None, dev0, dev1)
    assert own.p_better < ALPHA and own.gain > 0.9
    assert np.all(own.cand.sum(axis=1) < own.base.sum(axis=1))   # every left-out run predicted better

    carried = leave_one_run_out(obj, m0, m1, None, dev0)         # the change on the mean, in every run
    assert carried.gain < own.gain
    early, late = int(np.argmin(ONSETS)), int(np.argmax(ONSETS))  # the runs farthest from the mean's onset
    for f in (early, late):
        assert carried.cand[f].sum() > 10.0 * own.cand[f].sum()


def test_the_folds_keep_a_fitted_value_in_its_plausible_range():
    """A delay cannot be negative. Where the car's signal leads the model's (a structural lag of the model,
    20 ms here), the fit on all runs stops at 0 s and the candidate adds nothing; re-fitted freely, each fold
    would take a negative delay that absorbs the lead and predict every left-out run better (p about 0).
    Held in the range, as the fit on all runs is, the folds stay at 0 s and show no improvement."""
    rng = np.random.default_rng(5)
    se = NOISE / np.sqrt(len(ONSETS))
    model = np.sin(2.0 * np.pi * 0.5 * T)                          # the model's replay (no run scatter)
    data = np.array([(1.0 + 0.01 * rng.standard_normal()) * np.sin(2.0 * np.pi * 0.5 * (T + 0.020))
                     + NOISE * rng.standard_normal(T.size) for _ in ONSETS])
    obj = Objective(["accel_y"], {"accel_y": se}, {"accel_y": data.mean(axis=0)}, {"accel_y": data},
                    {"accel_y": float(T.size)}, 1.0)
    m0 = model / se
    J = -np.gradient(model, T) / se                                # d residual / d delay at 0 s
    free = leave_one_run_out(obj, m0, m0, J)
    assert free.p_better < ALPHA and free.gain > 0.3             # what a negative delay would do
    held = leave_one_run_out(obj, m0, m0, J, span=(0.0, 0.2))     # delay in [0, 0.2] s, fitted at 0
    assert held.p_better >= 0.5 and held.gain <= 0.0
