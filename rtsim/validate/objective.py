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

from dataclasses import dataclass, replace

import numpy as np

from .benchmark import Benchmark


RADIUS_RANGE = 0.015          # relative change of an axle's effective rolling radius
RESISTANCE_RANGE = 0.03       # m/s^2 of constant deceleration (about 0.003 g)
MOVING = 0.5                  # m/s: the resistance offset acts above this speed
PRIOR = 10.0                  # standard errors (see Nuisance.build)


@dataclass
class Nuisance:
    """The linear nuisance adjustments (module docstring): D (n_total, k) the normalised change of the
    concatenated residual per unit of each adjustment applied to the model, the least-squares solve
    (p = -(D'D)^-1 D' r minimises |r + D p|) and the clip ranges."""
    names: list[str]
    units: list[str]
    D: np.ndarray
    solve: np.ndarray          # (k, n_total): unconstrained least-squares values = solve @ r
    lo: np.ndarray
    hi: np.ndarray
    ridge: np.ndarray | None = None     # (k,): the prior's weight per adjustment (0: free)
    refits: int = 0            # the last `refits` columns: named sensor effects re-fitted (with_refits)

    def values(self, r: np.ndarray) -> np.ndarray:
        return np.clip(self.solve @ r, self.lo, self.hi)

    def project(self, r: np.ndarray) -> np.ndarray:
        """The residual with the adjustments applied to the model: r + D p."""
        return r + self.D @ self.values(r)

    def project_direction(self, d: np.ndarray) -> np.ndarray:
        """A change of the model's outputs (normalised, concatenated, e.g. a sensitivity) as the residual
        sees it with the adjustments re-fitted: the part of `d` they cannot absorb (inside their ranges)."""
        return d + self.D @ (self.solve @ d)

    def mimic(self, d: np.ndarray) -> tuple[float, str]:
        """How much of the change `d` (normalised, concatenated) an effect makes the adjustments reproduce,
        within their ranges and free of their prior: the share of |d|^2 they explain and the adjustment that
        carries most of it (identify.channel_evidence: what they do not reproduce must still predict
        left-out runs better, else the effect cannot be told from the mismatch they stand for)."""
        dd = float(d @ d)
        if dd <= 0.0:
            return 0.0, ""
        p = np.clip(np.linalg.lstsq(self.D, d, rcond=None)[0], self.lo, self.hi)
        fit = self.D @ p
        share = [float(np.linalg.norm(self.D[:, j] * p[j])) for j in range(p.size)]
        return 1.0 - float(np.sum((d - fit) ** 2)) / dd, self.names[int(np.argmax(share))]

    def with_refits(self, names: list[str], cols: list[np.ndarray], lo: list[float], hi: list[float]) -> "Nuisance":
        """These adjustments and the named sensor effects re-fitted beside them: `cols` the change of the
        residual per unit of each effect's value (normalised, concatenated), `lo`..`hi` the change of the
        value its plausible range allows; no prior on them (a named effect is fitted, not pulled to its
        value). The adjustments keep their prior."""
        ridge = np.concatenate([self.ridge if self.ridge is not None else np.zeros(len(self.names)),
                                np.zeros(len(cols))])
        D = np.column_stack([self.D, *cols])
        return Nuisance([*self.names, *names], [*self.units, *([""] * len(cols))], D, _solve(D, ridge),
                        np.concatenate([self.lo, lo]), np.concatenate([self.hi, hi]), ridge, self.refits + len(cols))

    @classmethod
    def refits_only(cls, names: list[str], cols: list[np.ndarray], lo: list[float], hi: list[float]) -> "Nuisance":
        """The named sensor effects re-fitted where no adjustment applies (with_refits)."""
        empty = cls([], [], np.zeros((cols[0].size, 0)), np.zeros((0, cols[0].size)), np.zeros(0), np.zeros(0),
                    np.zeros(0))
        return empty.with_refits(names, cols, lo, hi)

    def refit_values(self, r: np.ndarray) -> np.ndarray:
        """The re-fitted named sensor effects' changes of value at the residual `r` (with_refits)."""
        return self.values(r)[len(self.names) - self.refits:]

    @classmethod
    def build(cls, channels: list[str], scale: dict, mean: dict, t: np.ndarray, wheel_radius: float):
        n = t.size
        idx = {c: i for i, c in enumerate(channels)}
        wheels = {"front": [c for c in ("wheel_speed_fl", "wheel_speed_fr") if c in idx],
                  "rear": [c for c in ("wheel_speed_rl", "wheel_speed_rr") if c in idx]}
        cols, names, units, lo, hi = [], [], [], [], []
        speeds = [mean[c] for c in (*wheels["front"], *wheels["rear"])]
        if not speeds:
            return None
        v = np.mean(speeds, axis=0) * wheel_radius
        moving = np.abs(v) > MOVING
        if moving.mean() < 0.2:
            return None
        for axle, cs in wheels.items():
            if not cs:
                continue
            d = np.zeros(n * len(channels))
            for c in cs:      # a radius larger by e: the model's wheel turns slower by the factor 1 / (1 + e)
                d[idx[c] * n:(idx[c] + 1) * n] = -mean[c] / scale[c]
            cols.append(d)
            names.append(f"effective rolling radius, {axle} axle")
            units.append("relative")
            lo.append(-RADIUS_RANGE)
            hi.append(RADIUS_RANGE)
        d = np.zeros(n * len(channels))
        drift = np.concatenate([[0.0], np.cumsum(moving[1:] * np.diff(t))])
        for c in (*wheels["front"], *wheels["rear"]):
            d[idx[c] * n:(idx[c] + 1) * n] = -drift / wheel_radius / scale[c]     # more resistance: slower
        if "accel_x" in idx:
            d[idx["accel_x"] * n:(idx["accel_x"] + 1) * n] = -moving.astype(float) / scale["accel_x"]
        cols.append(d)
        names.append("resistance offset (positive: the car has more resistance than the model)")
        units.append("m/s^2")
        lo.append(-RESISTANCE_RANGE)
        hi.append(RESISTANCE_RANGE)
        D = np.column_stack(cols)
        # a prior towards no adjustment: at its range an adjustment costs as much as one channel
        # `PRIOR` standard errors off everywhere, small against a real structural gap (the wheel speeds
        # drifting apart by tens of standard errors), but where an effect and an adjustment would explain
        # the same thing (a hidden mass against the rolling radii) the effect takes it
        ridge = PRIOR ** 2 * n / np.array(hi) ** 2
        return cls(names, units, D, _solve(D, ridge), np.array(lo), np.array(hi), ridge)


def _solve(D: np.ndarray, ridge: np.ndarray) -> np.ndarray:
    """-(D'D + diag(ridge))^-1 D': the adjustments' values at a residual r are solve @ r (a tiny floor on
    the diagonal keeps a column without effect, a scale of a channel at zero, from making it singular)."""
    A = D.T @ D + np.diag(ridge)
    A += np.eye(A.shape[0]) * 1e-12 * max(float(np.trace(A)), 1.0)
    return -np.linalg.solve(A, D.T)


@dataclass
class Objective:
    channels: list[str]
    scale: dict[str, float]        # s_c
    mean: dict[str, np.ndarray]    # benchmark means
    runs: dict[str, np.ndarray]    # (k, n_t) run values
    n_eff: dict[str, float]        # N_c
    tau: float                     # mean tau_c (samples)
    nuisance: Nuisance | None = None

    @classmethod
    def from_benchmark(cls, bench: Benchmark, wheel_radius: float | None = None) -> "Objective":
        """The objective of `bench`; with the model's rolling radius, the nuisance adjustments too."""
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
        mean = {c: bench.bands[c].mean for c in bench.compared}
        nuis = (Nuisance.build(list(bench.compared), scale, mean, bench.t, wheel_radius)
                if wheel_radius and bench.n >= 2 else None)
        return cls(list(bench.compared), scale, mean, {c: bench.values[c] for c in bench.compared}, n_eff, tau,
                   nuis)

    def raw_residual(self, out: dict[str, np.ndarray]) -> np.ndarray:
        """Normalised residuals of all channels, concatenated, before the nuisance adjustments."""
        return np.concatenate([(out[c] - self.mean[c]) / self.scale[c] for c in self.channels])

    def residual(self, out: dict[str, np.ndarray]) -> np.ndarray:
        """Normalised residuals of all channels, concatenated, with the nuisance adjustments fitted."""
        r = self.raw_residual(out)
        return self.nuisance.project(r) if self.nuisance is not None else r

    def nuisance_values(self, out: dict[str, np.ndarray]) -> dict[str, tuple[float, str]]:
        """The nuisance adjustments fitted to `out`: name -> (value, unit) (named sensor effects re-fitted
        beside them not included)."""
        if self.nuisance is None:
            return {}
        nu = self.nuisance
        p = nu.values(self.raw_residual(out))
        k = len(nu.names) - nu.refits
        return {n: (float(v), u) for n, v, u in zip(nu.names[:k], p[:k], nu.units[:k])}

    def refitting(self, names: list[str], cols: list[np.ndarray], lo: list[float], hi: list[float]) -> "Objective":
        """This objective with the named sensor effects `names` re-fitted beside the nuisance adjustments at
        every residual (Nuisance.with_refits); itself when there are none."""
        if not cols:
            return self
        nu = (self.nuisance.with_refits(names, cols, lo, hi) if self.nuisance is not None
              else Nuisance.refits_only(names, cols, lo, hi))
        return replace(self, nuisance=nu)

    def adjusted(self, out: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """`out` with the nuisance adjustments applied (what the residual measures)."""
        if self.nuisance is None:
            return out
        r = self.residual(out)
        n = self.mean[self.channels[0]].size
        res = dict(out)
        for i, c in enumerate(self.channels):
            res[c] = self.mean[c] + r[i * n:(i + 1) * n] * self.scale[c]
        return res

    def channel_residual(self, out: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        r = self.residual(out)
        n = self.mean[self.channels[0]].size
        return {c: r[i * n:(i + 1) * n] for i, c in enumerate(self.channels)}

    def cost(self, out: dict[str, np.ndarray]) -> float:
        r = self.residual(out)
        return float(np.mean(r * r))

    def channel_cost(self, out: dict[str, np.ndarray]) -> dict[str, float]:
        return {c: float(np.mean(r * r)) for c, r in self.channel_residual(out).items()}

    def ic(self, out: dict[str, np.ndarray], k: int) -> float:
        cc = self.channel_cost(out)
        ntot = sum(self.n_eff.values())
        return float(sum(self.n_eff[c] * np.log(max(cc[c], 1e-300)) for c in self.channels) + k * np.log(ntot))

    def residual_to_run(self, out: dict[str, np.ndarray], i: int) -> np.ndarray:
        """Normalised residuals against run i alone (the mean where the run lacks a channel), with the
        nuisance adjustments fitted."""
        r = np.concatenate([(out[c] - (self.runs[c][i] if i < self.runs[c].shape[0] else self.mean[c]))
                            / self.scale[c] for c in self.channels])
        return self.nuisance.project(r) if self.nuisance is not None else r


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
