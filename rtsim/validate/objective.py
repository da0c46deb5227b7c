"""The disagreement measure that fitting and ranking minimise, and its information criterion.

Per compared channel c, the residual r_c(t) = model_c(t) - mean_c(t) is divided by the channel's
typical standard error of the mean, s_c = RMS over time of S_c(t) / sqrt(n) (floored at 1e-3 of the
channel's range; with one run, s_c is the sample noise estimated from the run's second differences).
The cost is the mean of the squared normalised residuals over channels and samples: about 1 when the
model sits within the data's own uncertainty, and it counts each channel equally whatever its unit.

Information criterion (Bayesian form, channels as independent Gaussian measurements):
IC = sum_c N_c ln(cost_c) + k ln(sum_c N_c), k the number of fitted values (a sensor effect's channel
choice counts as one). Successive samples are not independent, so each channel counts N_c = N / tau_c
samples, tau_c the integrated autocorrelation time (in samples) of the runs' deviations from their
mean, summed up to the first negative lag and averaged over the runs (slow run-to-run differences
make few independent samples; white sensor noise makes many).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .benchmark import Benchmark


@dataclass
class Objective:
    channels: list[str]
    scale: dict[str, float]        # s_c
    mean: dict[str, np.ndarray]    # benchmark means
    runs: dict[str, np.ndarray]    # (k, n_t) run values
    n_eff: dict[str, float]        # N_c
    tau: float                     # mean tau_c (samples)

    @classmethod
    def from_benchmark(cls, bench: Benchmark) -> "Objective":
        scale, taus = {}, {}
        for c in bench.compared:
            b = bench.bands[c]
            rng = float(np.ptp(b.mean)) or 1.0
            if b.has_band:
                s = float(np.sqrt(np.mean(b.se ** 2)))
            else:
                d2 = np.diff(bench.values[c][0], 2)
                s = float(np.median(np.abs(d2 - np.median(d2))) / 0.6745 / np.sqrt(6.0))
            scale[c] = max(s, 1e-3 * rng)
            taus[c] = float(np.mean([_tau(row - b.mean) for row in bench.values[c]])) if b.has_band else 10.0
        n_eff = {c: max(bench.t.size / taus[c], 2.0) for c in taus}
        tau = float(np.mean(list(taus.values())))
        return cls(list(bench.compared), scale, {c: bench.bands[c].mean for c in bench.compared},
                   {c: bench.values[c] for c in bench.compared}, n_eff, tau)

    def residual(self, out: dict[str, np.ndarray]) -> np.ndarray:
        """Normalised residuals of all channels, concatenated."""
        return np.concatenate([(out[c] - self.mean[c]) / self.scale[c] for c in self.channels])

    def cost(self, out: dict[str, np.ndarray]) -> float:
        r = self.residual(out)
        return float(np.mean(r * r))

    def channel_cost(self, out: dict[str, np.ndarray]) -> dict[str, float]:
        return {c: float(np.mean(((out[c] - self.mean[c]) / self.scale[c]) ** 2)) for c in self.channels}

    def ic(self, out: dict[str, np.ndarray], k: int) -> float:
        cc = self.channel_cost(out)
        ntot = sum(self.n_eff.values())
        return float(sum(self.n_eff[c] * np.log(max(cc[c], 1e-300)) for c in self.channels) + k * np.log(ntot))

    def residual_to_run(self, out: dict[str, np.ndarray], i: int) -> np.ndarray:
        """Normalised residuals against run i alone (the mean where the run lacks a channel)."""
        return np.concatenate([(out[c] - (self.runs[c][i] if i < self.runs[c].shape[0] else self.mean[c]))
                               / self.scale[c] for c in self.channels])


def _tau(d: np.ndarray) -> float:
    """Integrated autocorrelation time (samples) of a deviation signal, up to the first negative lag."""
    d = d - d.mean()
    v = float(np.dot(d, d))
    if v == 0.0:
        return 1.0
    n = d.size
    f = np.fft.rfft(d, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:n] / v
    neg = np.nonzero(ac < 0.0)[0]
    m = int(neg[0]) if neg.size else n
    return float(max(1.0, 1.0 + 2.0 * np.sum(ac[1:m])))
