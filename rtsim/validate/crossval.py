"""Leave-one-run-out cross-validation of a candidate effect (the selection rule, issue 30).

The question a candidate must answer is whether it predicts a repetition it was not fitted on better than
the model without it. For each run f of the n repetitions (a fold), the candidate's value is re-fitted on
the mean of the other n - 1 runs and both models, the nuisance adjustments re-fitted on those runs too,
predict run f; the fold's loss is the mean squared normalised error of that prediction per channel. No
fold costs a simulation: the candidate's response is linearised at its fit on all runs, theta_f =
theta* - (J . r_f) / (J . J), r_f the candidate's residual against the training mean (the sensitivity J
and the residuals are the objective's: normalised, nuisance adjustments applied), and theta_f is held in
the candidate's plausible range as the fit on all runs was (a delay fitted at 0 s is not judged with a
negative delay in the folds).

What a held-out run adds beyond the training mean is its own run-to-run scatter, whatever its correlation
in time (a smooth amplitude variation of the driver makes a whole run deviate together; the folds see it
as it is, no effective sample count is estimated); the differences of the two models' fold losses carry
it. An improvement is significant when the corrected resampled t-test (Nadeau and Bengio 2003: paired
over the folds, the variance inflated by 1/n + n_test/n_train = 1/n + 1/(n - 1) for the folds' shared
training runs) rejects "no improvement" one-sided at `ALPHA`; a channel is made worse when the same test
rejects "not worse" at `ALPHA`.

What cross-validation across repetitions cannot tell is a structural mismatch: it is in every run alike,
so an effect that absorbs part of it predicts every held-out run better. That is judged separately
(identify.channel_evidence, Candidate.outweighs_structure).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import t as student_t

ALPHA = 0.05                 # one-sided level of the fold test


@dataclass
class CrossValidation:
    """Fold losses of the model without (`base`) and with the candidate (`cand`), shape (folds, channels),
    and what the test says (channel order: `channels`)."""
    channels: list[str]
    base: np.ndarray
    cand: np.ndarray
    p_better: float = 1.0                               # p-value of "no improvement" (all channels)
    t_better: float = 0.0                               # its t statistic (negative: the candidate is better)
    p_by_channel: dict = field(default_factory=dict)    # channel -> (p better, p worse)

    @property
    def gain(self) -> float:
        """Share of the held-out loss (all channels) the candidate removes, averaged over the folds."""
        b = float(self.base.sum(axis=1).mean())
        return 1.0 - float(self.cand.sum(axis=1).mean()) / b if b > 0 else 0.0

    def channel_gain(self, c: str) -> float:
        k = self.channels.index(c)
        b = float(self.base[:, k].mean())
        return 1.0 - float(self.cand[:, k].mean()) / b if b > 0 else 0.0

    @property
    def better(self) -> bool:
        return self.p_better < ALPHA

    def improves(self, c: str) -> bool:
        return self.p_by_channel.get(c, (1.0, 1.0))[0] < ALPHA

    def worsens(self, c: str) -> bool:
        return self.p_by_channel.get(c, (1.0, 1.0))[1] < ALPHA

    def summary(self) -> dict:
        return {"folds": int(self.base.shape[0]), "gain": self.gain, "p_better": self.p_better,
                "by_channel": {c: {"gain": self.channel_gain(c), "p_better": p[0], "p_worse": p[1]}
                               for c, p in self.p_by_channel.items()}}


def t_statistic(diff: np.ndarray) -> float:
    """The corrected resampled t statistic over leave-one-out folds (module docstring); diff: candidate
    minus base loss per fold."""
    n = diff.size
    mean = float(diff.mean()) if n else 0.0
    var = float(diff.var(ddof=1)) * (1.0 / n + 1.0 / (n - 1)) if n >= 2 else 0.0
    if var <= 0.0:
        return -math.inf if mean < 0 else math.inf if mean > 0 else 0.0
    return mean / math.sqrt(var)


def corrected_t(diff: np.ndarray) -> tuple[float, float]:
    """One-sided p-values (improvement: diff < 0, worsening: diff > 0) of the corrected resampled t-test."""
    n = diff.size
    if n < 2:
        return 1.0, 1.0
    t = t_statistic(diff)
    return float(student_t.cdf(t, n - 1)), float(student_t.sf(t, n - 1))


def p_better_than(a: CrossValidation, b: CrossValidation) -> float:
    """One-sided p-value of "candidate a predicts the left-out runs no better than candidate b": the same
    corrected resampled t-test, paired over the same folds (both judged against the same model)."""
    return corrected_t(a.cand.sum(axis=1) - b.cand.sum(axis=1))[0]


def _normalised_runs(obj) -> list[np.ndarray]:
    """Each run's channels normalised like the objective's residuals, concatenated (the mean where a run
    lacks a channel)."""
    n = len(next(iter(obj.runs.values())))
    out = []
    for i in range(n):
        out.append(np.concatenate([(obj.runs[c][i] if i < obj.runs[c].shape[0] else obj.mean[c]) / obj.scale[c]
                                   for c in obj.channels]))
    return out


def normalised(obj, out: dict) -> np.ndarray:
    """Model outputs normalised like the objective's residuals, concatenated."""
    return np.concatenate([out[c] / obj.scale[c] for c in obj.channels])


def leave_one_run_out(obj, m0: np.ndarray, m1: np.ndarray, J: np.ndarray | None,
                      deviations: list | None = None, cand_deviations: list | None = None,
                      span: tuple[float, float] = (-math.inf, math.inf)) -> CrossValidation | None:
    """The cross-validation of the model `m1` (normalised outputs at the candidate's fit, `normalised`; J
    its sensitivity, d residual / d theta, None: nothing re-fitted per fold) against `m0`; None with fewer
    than 3 runs. `deviations`: per run, the model's own response to that run's inputs minus its mean over
    the runs (normalised; the current model's per-run replays): a run is then predicted from its own
    inputs, and the scatter the inputs explain (a driver steering 2 % more in one run) leaves the
    comparison. `cand_deviations`: the same with the candidate (a sensor effect on each run's readings,
    identify.sensor_deviations); without them the candidate's change is taken as the same in every run.
    `span`: the change of theta a fold may make, (lo - theta*, hi - theta*) of the plausible range."""
    runs = _normalised_runs(obj)
    n = len(runs)
    if n < 3:
        return None
    runs1 = runs
    if deviations is not None and len(deviations) == n:
        runs = [y - d for y, d in zip(runs, deviations)]
        runs1 = runs
        if cand_deviations is not None and len(cand_deviations) == n:
            runs1 = [y - d for y, d in zip(_normalised_runs(obj), cand_deviations)]
    nch = len(obj.channels)
    total, total1 = np.sum(runs, axis=0), np.sum(runs1, axis=0)
    nu = obj.nuisance
    jj = float(J @ J) if J is not None else 0.0
    L0 = np.zeros((n, nch))
    L1 = np.zeros((n, nch))
    for f in range(n):
        r0 = m0 - (total - runs[f]) / (n - 1)
        r1 = m1 - (total1 - runs1[f]) / (n - 1)
        e0, e1 = m0 - runs[f], m1 - runs1[f]
        if nu is not None:
            e0 = e0 + nu.D @ nu.values(r0)
            e1 = e1 + nu.D @ nu.values(r1)
            r1 = nu.project(r1)
        if jj > 0.0:
            e1 = e1 + J * min(max(-float(J @ r1) / jj, span[0]), span[1])
        L0[f] = (e0 * e0).reshape(nch, -1).mean(axis=1)
        L1[f] = (e1 * e1).reshape(nch, -1).mean(axis=1)
    cv = CrossValidation(list(obj.channels), L0, L1)
    cv.p_better = corrected_t(L1.sum(axis=1) - L0.sum(axis=1))[0]
    cv.t_better = t_statistic(L1.sum(axis=1) - L0.sum(axis=1))
    cv.p_by_channel = {c: corrected_t(L1[:, k] - L0[:, k]) for k, c in enumerate(obj.channels)}
    return cv
