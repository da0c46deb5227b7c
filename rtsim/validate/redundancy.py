"""Model-free checks of a sensor's gain and lag (analytical redundancy): what other measured channels say
of a channel, whatever the model's structure.

A structural mismatch of the model can have the signature of a sensor effect on one channel: a car whose
yaw response is 3 % stronger than the model's reads, against the model, as a gyro_z gain of 1.03, and a
sluggish yaw response as a gyro_z delay. Cross-validation across repetitions cannot tell them apart (the
mismatch is in every run alike). Other sensors can: the rear wheels' speed difference is the yaw rate
times the track over the rolling radius, whatever the tyres and the inertia do, so a gyro that reads 3 %
high reads 3 % high against the wheels too, where a model mismatch leaves the two sensors in agreement.

A vehicle declares its relations in its validation profile (rtsim.vehicle.validation.Relation): the
checked channel, a reference computed from other channels (proportional to what the channel measures, in
any units) and offset regressors (quantities that may add to the reading: an axle's rolling-radius
difference reads as a yaw rate proportional to speed; a body-frame accelerometer's g sin(roll)).

The check (`check`), on the runs' mean and on the model's replay alike, on the samples where the
reference varies:
- gain: least squares of the channel on [reference, 1, offsets]; the sensor's gain in model-free terms is
  the data's coefficient over the model's, g = a_data / a_model (what the model's own kinematics and
  second-order terms put in the coefficient cancels);
- lag: the delay d of the reference that fits the channel best (grid of `LAG_STEP` s over the
  search range, refined by a parabola; both smoothed first), d = d_data - d_model.
The estimate is made on the mean of the runs (its noise is what limits a lag); the n jackknife
pseudo-values (n x the estimate on all runs - (n - 1) x the estimate leaving run i out) give its mean and
a 95 % Student-t interval, whatever the scatter's correlation in time. The check confirms a candidate when its
interval excludes the neutral value (gain 1, lag 0) on the candidate's side and the check sees at least
`SHARE` of the candidate's deviation from neutral; otherwise the candidate's value is what the model's
structure asks for, and the workflow turns it down with the check's numbers.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from .signals import box_average
from .stats import parabolic_minimum, t_critical

SHARE = 0.5                  # share of the candidate's deviation from neutral the check must see
LAG_STEP = 0.002             # s, the lag grid's step
SMOOTH = 0.1                 # s, the moving average applied before the lag search
LIVE = 0.2                   # a sample counts where |reference - its median| exceeds this share of its largest


@dataclass
class Check:
    """A model-free estimate of a sensor effect's value: per-run values, their mean and 95 % interval."""
    channel: str
    kind: str                # "scale" or "delay"
    says: str                # what the reference is (the relation's words)
    values: np.ndarray
    neutral: float

    @property
    def value(self) -> float:
        return float(self.values.mean())

    @property
    def half_width(self) -> float:
        n = self.values.size
        if n < 2:
            return float("inf")
        return float(t_critical(n) * self.values.std(ddof=1) / np.sqrt(n))

    def confirms(self, candidate: float) -> bool:
        """The interval excludes neutral on the candidate's side and covers at least SHARE of its deviation."""
        dev = candidate - self.neutral
        seen = self.value - self.neutral
        if dev == 0.0 or seen * dev <= 0.0:
            return False
        return abs(seen) > self.half_width and abs(seen) >= SHARE * abs(dev)

    def sentence(self, candidate: float) -> str:
        what = "gain" if self.kind == "scale" else "lag"
        unit = "" if self.kind == "scale" else " s"
        return (f"against {self.says}, {self.channel} shows a {what} of {self.value:.4g}{unit} "
                f"+- {self.half_width:.2g} (model-free, {self.values.size} runs), not the {candidate:.4g}{unit} "
                f"the model asks for: the difference is the model's own response, not the sensor")


def _design(ref: np.ndarray, offsets: list[np.ndarray]) -> np.ndarray:
    return np.column_stack([ref, np.ones_like(ref), *offsets])


def _live(ref: np.ndarray) -> np.ndarray:
    dev = np.abs(ref - np.median(ref))
    top = float(dev.max()) if dev.size else 0.0
    return dev > LIVE * top if top > 0 else np.zeros(ref.shape, bool)


def _fit(y: np.ndarray, ref: np.ndarray, offsets: list[np.ndarray], mask: np.ndarray) -> tuple[float, float]:
    """(coefficient of the reference, residual sum of squares) on the masked samples."""
    A = _design(ref, offsets)[mask]
    coef, *_ = np.linalg.lstsq(A, y[mask], rcond=None)
    r = y[mask] - A @ coef
    return float(coef[0]), float(r @ r)


def gain(y: np.ndarray, ref: np.ndarray, offsets: list[np.ndarray]) -> float:
    """The channel's coefficient on the reference (module docstring); nan where the reference never varies."""
    mask = _live(ref)
    if mask.sum() < 10:
        return float("nan")
    return _fit(y, ref, offsets, mask)[0]


def smooth(x: np.ndarray, dt: float) -> np.ndarray:
    """A centred moving average over `SMOOTH` s: no lag, and the noise that a fractional shift's interpolation
    would average (making whole-sample shifts look better than they are) is gone before the search."""
    t = np.arange(x.size) * dt
    return box_average(t, x, SMOOTH)


def shifted(x: np.ndarray, dt: float, d: float) -> np.ndarray:
    """x(t - d) on the same grid (linear interpolation, the end values held), d of either sign."""
    t = np.arange(x.size) * dt
    return np.interp(t - d, t, x)


def lag(y: np.ndarray, ref: np.ndarray, offsets: list[np.ndarray], dt: float, lo: float, hi: float) -> float:
    """The delay of the reference (s, within [lo, hi], either sign) that fits the channel best (module
    docstring)."""
    mask = _live(ref)
    if mask.sum() < 10:
        return float("nan")
    y, ref, offsets = smooth(y, dt), smooth(ref, dt), [smooth(o, dt) for o in offsets]
    grid = np.arange(lo, hi + 0.5 * LAG_STEP, LAG_STEP)
    return parabolic_minimum(grid, [_fit(y, shifted(ref, dt, float(d)), offsets, mask)[1] for d in grid])


#: estimates already made: digest of (relation, kind, grid step, range, the channels it reads) -> value;
#: a workflow checks the same runs again for every candidate and iteration (and the same replay for
#: every candidate of an iteration), so each estimate is made once (`_estimate`)
_MADE: dict = {}
_MADE_MAX = 512


def _estimate(rel, kind: str, channels: dict, dt: float, lo: float, hi: float) -> float:
    """`_estimated`, made once per relation, kind, step, range and channel values (`_MADE`)."""
    h = hashlib.sha1(repr((rel.channel, rel.needs, kind, float(dt), float(lo), float(hi))).encode())
    h.update(repr(id(rel)).encode())
    for c in (rel.channel, *rel.needs):
        x = np.ascontiguousarray(channels[c], dtype=np.float64)
        h.update(repr(x.shape).encode() + x.tobytes())
    key = (rel, h.hexdigest())
    if key not in _MADE:
        if len(_MADE) >= _MADE_MAX:
            _MADE.clear()
        _MADE[key] = _estimated(rel, kind, channels, dt, lo, hi)
    return _MADE[key]


def _estimated(rel, kind: str, channels: dict, dt: float, lo: float, hi: float) -> float:
    y = channels[rel.channel]
    ref = rel.reference(channels)
    offs = rel.offsets(channels)
    if kind == "scale":
        return gain(y, ref, offs)
    return lag(y, ref, offs, dt, lo, hi)


def check(rel, kind: str, runs: list[dict], model: dict, dt: float, lo: float = -0.15,
          hi: float = 0.3) -> Check | None:
    """The model-free estimate of a `kind` ("scale" or "delay") effect on rel.channel from each run's
    channels (`runs`: one dict per run, on a grid of step dt s) against the model's replay (`model`); None
    when a run or the model lacks a channel the relation reads, or the reference never varies. lo, hi:
    the range (s) searched for the lag of the data and of the model alike."""
    need = (rel.channel, *rel.needs)
    if not runs or any(c not in model for c in need) or any(c not in r for r in runs for c in need):
        return None
    m = _estimate(rel, kind, model, dt, lo, hi)
    if not np.isfinite(m) or (kind == "scale" and m == 0.0):
        return None
    n = len(runs)
    total = {c: np.sum([r[c] for r in runs], axis=0) for c in need}
    full = _estimate(rel, kind, {c: total[c] / n for c in need}, dt, lo, hi)
    if n >= 3:      # jackknife pseudo-values of the estimate on the runs' mean
        loo = np.array([_estimate(rel, kind, {c: (total[c] - r[c]) / (n - 1) for c in need}, dt, lo, hi)
                        for r in runs])
        vals = n * full - (n - 1) * loo
    else:
        vals = np.array([full])
    vals = vals / m if kind == "scale" else vals - m
    neutral = 1.0 if kind == "scale" else 0.0
    if vals is None or not np.all(np.isfinite(vals)):
        return None
    return Check(rel.channel, kind, rel.says, vals, neutral)
