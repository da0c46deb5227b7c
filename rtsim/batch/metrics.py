"""The library of named metrics a batch computes per run, over the run's logged columns (the channel
names and SI units of rtsim.channels: ISO 8855 axes, positive yaw rate turning left). A metric whose
channels the run lacks, or whose manoeuvre did not happen (no braking: no stopping distance), is NaN
-- never a made-up number. Cars and the motorcycle share the names where the quantity is the same."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

NAN = float("nan")
STOPPED_M_S = 0.5          # m/s: below this speed the vehicle counts as stopped
BRAKE_ON_KPA = 50.0        # kPa: brake line pressure above this counts as braking


class Columns:
    """A run's rows by column name; `get` is None for a column the run does not have."""

    def __init__(self, names, data: np.ndarray):
        self.index = {n: i for i, n in enumerate(names)}
        self.data = data

    def get(self, name: str) -> np.ndarray | None:
        i = self.index.get(name)
        return None if i is None or self.data.shape[0] == 0 else self.data[:, i]


@dataclass(frozen=True)
class Metric:
    name: str
    unit: str
    doc: str
    fn: Callable[[Columns], float]


def _distance(c: Columns, i0: int = 0, i1: int | None = None) -> float:
    x, y = c.get("pos_x"), c.get("pos_y")
    sl = slice(i0, None if i1 is None else i1 + 1)
    return float(np.sum(np.hypot(np.diff(x[sl]), np.diff(y[sl]))))


def _lateral_acceleration(c: Columns) -> np.ndarray | None:
    u, r = c.get("speed"), c.get("yaw_rate")
    return None if u is None or r is None else u * r


def stopping_distance(c: Columns) -> float:
    t, v = c.get("time"), c.get("speed")
    p = c.get("brake_pressure")
    if p is None and c.get("brake_pressure_front") is not None:
        p = c.get("brake_pressure_front") + c.get("brake_pressure_rear")
    if t is None or v is None or p is None or c.get("pos_x") is None:
        return NAN
    on = np.nonzero(p > BRAKE_ON_KPA)[0]
    if on.size == 0:
        return NAN
    i0 = int(on[0])
    stop = np.nonzero(v[i0:] < STOPPED_M_S)[0]
    if stop.size == 0:
        return NAN
    return _distance(c, i0, i0 + int(stop[0]))


def peak_lateral_acceleration(c: Columns) -> float:
    ay = _lateral_acceleration(c)
    return NAN if ay is None else float(np.max(np.abs(ay)))


def yaw_rate_overshoot(c: Columns) -> float:
    r = c.get("yaw_rate")
    if r is None or r.size < 10:
        return NAN
    steady = float(np.mean(r[-max(2, r.size // 5):]))
    if abs(steady) < 1e-3:
        return NAN
    peak = float(np.max(r * math.copysign(1.0, steady)))
    return peak / abs(steady) - 1.0


def path_error_rms(c: Columns) -> float:
    t, n = c.get("time"), c.get("path_offset")
    if t is None or n is None:
        return NAN
    n = n[t > 1.0]
    return NAN if n.size == 0 else float(np.sqrt(np.mean(n ** 2)))


def max_constraint_violation(c: Columns) -> float:
    v = c.get("constraint_violation")
    return NAN if v is None else float(np.max(np.abs(v)))


def energy_residual_max(c: Columns) -> float:
    e = c.get("energy_residual")
    return NAN if e is None else float(np.max(np.abs(e)))


def steering_torque_gradient(c: Columns) -> float:
    tau, ay = c.get("steering_torque"), _lateral_acceleration(c)
    if tau is None or ay is None:
        return NAN
    keep = np.abs(ay) < 4.0            # the linear range of the tyres
    if keep.sum() < 10 or np.ptp(ay[keep]) < 0.5:
        return NAN
    return float(np.polyfit(ay[keep], tau[keep], 1)[0])


def peak_roll(c: Columns) -> float:
    phi = c.get("roll_angle")
    return NAN if phi is None else float(np.max(np.abs(phi)))


def final_speed(c: Columns) -> float:
    v = c.get("speed")
    return NAN if v is None else float(v[-1])


def distance(c: Columns) -> float:
    return NAN if c.get("pos_x") is None else _distance(c)


def _m(fn, unit, doc):
    return Metric(fn.__name__, unit, doc, fn)


METRICS: dict[str, Metric] = {m.name: m for m in (
    _m(stopping_distance, "m", "path length from the first brake pressure above 50 kPa (car: brake_pressure; "
       "motorcycle: front + rear) to the first speed below 0.5 m/s; NaN without braking or without a stop"),
    _m(peak_lateral_acceleration, "m/s^2", "max |speed x yaw_rate| (the centripetal acceleration of the path)"),
    _m(yaw_rate_overshoot, "1", "max yaw rate (in the sense of the final one) over the mean of the last "
       "fifth of the run, minus 1; NaN when the final yaw rate is below 1e-3 rad/s"),
    _m(path_error_rms, "m", "RMS of path_offset (the rider's lateral error to its path) after t = 1 s"),
    _m(max_constraint_violation, "1", "max |constraint_violation| (the multibody constraints' residual norm)"),
    _m(energy_residual_max, "J", "max |energy_residual| of the car's power audit (stored change minus net "
       "work: the integrator's energy error)"),
    _m(steering_torque_gradient, "N*m/(m/s^2)", "slope of the least-squares line of steering_torque against "
       "speed x yaw_rate over the rows below 4 m/s^2; NaN when that range spans less than 0.5 m/s^2"),
    _m(peak_roll, "rad", "max |roll_angle|"),
    _m(final_speed, "m/s", "speed in the last row"),
    _m(distance, "m", "path length of the centre of mass over the run"),
)}


def compute(names, columns, data: np.ndarray) -> dict[str, float]:
    """The named metrics of one run; a metric that fails on odd data is NaN (the row says why)."""
    c = Columns(columns, data)
    out = {}
    for n in names:
        try:
            out[n] = float(METRICS[n].fn(c))
        except (ValueError, FloatingPointError, IndexError, np.linalg.LinAlgError):
            out[n] = NAN
    return out
