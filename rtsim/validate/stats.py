"""The benchmark statistics of the seed paper's eq. (6): per channel and time sample, the sample mean
of the n repetitions and the 95 % confidence interval of the mean with Student's t at n - 1 degrees of
freedom,  x_mean +- t_(1 - alpha/2, n - 1) * S / sqrt(n),  S^2 = sum (x_i - x_mean)^2 / (n - 1).
With one run there is no interval: the half-width is NaN and comparisons report no band."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import t as student_t

ALPHA = 0.05


@dataclass
class Band:
    mean: np.ndarray      # sample mean per time sample
    std: np.ndarray       # sample standard deviation S (NaN for n = 1)
    half: np.ndarray      # half-width t * S / sqrt(n) of the confidence interval (NaN for n = 1)
    n: int                # repetitions
    t_crit: float         # t_(1 - alpha/2, n - 1) (NaN for n = 1)

    @property
    def has_band(self) -> bool:
        return self.n >= 2

    @property
    def lower(self) -> np.ndarray:
        return self.mean - self.half

    @property
    def upper(self) -> np.ndarray:
        return self.mean + self.half

    @property
    def se(self) -> np.ndarray:
        """Standard error of the mean, S / sqrt(n)."""
        return self.std / np.sqrt(self.n)


def t_critical(n: int, alpha: float = ALPHA) -> float:
    """Upper (1 - alpha/2) critical value of Student's t with n - 1 degrees of freedom."""
    return float(student_t.ppf(1.0 - alpha / 2.0, n - 1)) if n >= 2 else float("nan")


def band(samples: np.ndarray, alpha: float = ALPHA) -> Band:
    """Eq. (6) for samples of shape (n_runs, n_times)."""
    x = np.atleast_2d(np.asarray(samples, dtype=float))
    n = x.shape[0]
    mean = x.mean(axis=0)
    if n < 2:
        nan = np.full_like(mean, np.nan)
        return Band(mean, nan, nan, n, float("nan"))
    std = x.std(axis=0, ddof=1)
    tc = t_critical(n, alpha)
    return Band(mean, std, tc * std / np.sqrt(n), n, tc)


def inside_fraction(model: np.ndarray, b: Band) -> float | None:
    """Share (0..1) of samples where the model lies inside the band (None without a band). A sample
    whose band has zero width (every run identical, e.g. at standstill) counts as inside when the model
    matches the mean to within 1e-9 of the channel's scale."""
    if not b.has_band:
        return None
    tol = 1e-9 * max(1.0, float(np.max(np.abs(b.mean))))
    return float(np.mean(np.abs(model - b.mean) <= b.half + tol))


def error_metrics(model: np.ndarray, b: Band) -> dict:
    """RMS and max of the model's error against the mean, and the share inside the band."""
    r = model - b.mean
    return {"rms": float(np.sqrt(np.mean(r * r))), "max": float(np.max(np.abs(r))),
            "inside_band": inside_fraction(model, b)}


def parabolic_minimum(grid: np.ndarray, costs) -> float:
    """The minimum of a cost sampled on an evenly spaced grid: the best grid point, refined by the parabola
    through it and its two neighbours (when it is inside the grid and the parabola opens upwards)."""
    costs = np.asarray(costs, float)
    k = int(np.argmin(costs))
    x = float(grid[k])
    if 0 < k < grid.size - 1:
        c0, c1, c2 = costs[k - 1], costs[k], costs[k + 1]
        den = c0 - 2 * c1 + c2
        if den > 0:
            x += 0.5 * (c0 - c2) / den * float(grid[1] - grid[0])
    return x
