"""Signal helpers shared by the data and the model side, so both go through exactly the same
processing: resampling onto a uniform grid and wheel speeds derived from wheel angles.

Wheel speed (rad/s) from a cumulative wheel angle (rad): the angle is unwrapped (a logger that wraps
at 2 pi is accepted), resampled onto the uniform grid, and differentiated by a Savitzky-Golay filter
(local least-squares quadratic over a centred window of `WHEEL_SPEED_WINDOW` s, i.e. a smoothed central
difference: no phase lag, exact for angles up to quadratic in time, white angle noise of std s gives
speed noise of about s * sqrt(12 / (N^3 dt^2)) for N window samples). The ends use the filter's
polynomial fit of the first/last window.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

from rtsim.channels import WHEELS

#: Centred smoothing window of the wheel-speed derivative, s.
WHEEL_SPEED_WINDOW = 0.05
WHEEL_ANGLES = tuple(f"wheel_angle_{w}" for w in WHEELS)
WHEEL_SPEEDS = tuple(f"wheel_speed_{w}" for w in WHEELS)
#: derived channel -> the sensor channel it comes from
DERIVED = dict(zip(WHEEL_SPEEDS, WHEEL_ANGLES))


def unwrap_angle(angle: np.ndarray) -> np.ndarray:
    """A cumulative angle from one that may wrap at +-pi or 0..2 pi (jumps larger than pi removed)."""
    return np.unwrap(angle)


def box_average(t: np.ndarray, x: np.ndarray, width: float) -> np.ndarray:
    """Centred moving average of x over `width` seconds (x sampled at the roughly uniform times t):
    the anti-alias filter applied before decimating onto a coarser grid. Near the edges the window
    shrinks symmetrically (the first and last samples are kept as they are): a one-sided window would
    move the sample's time, by up to half the width, where the signal ramps (a wheel angle at speed
    when a recording starts or ends in motion; its derivative at the end would be off by about
    speed x width / (4 dt_grid))."""
    dt = float(np.median(np.diff(t)))
    k = int(round(width / dt))
    if k < 2:
        return x
    if k % 2 == 0:
        k += 1
    c = np.concatenate([[0.0], np.cumsum(x)])
    i = np.arange(x.size)
    h = np.minimum(np.minimum(i, x.size - 1 - i), k // 2)
    lo = i - h
    hi = i + h + 1
    return (c[hi] - c[lo]) / (hi - lo)


def resample(t: np.ndarray, x: np.ndarray, grid: np.ndarray, filter_width: float | None = None) -> np.ndarray:
    """x(t) on `grid` by linear interpolation, after a centred box average of `filter_width` s when
    given (use the grid step when decimating: it removes what the coarser grid cannot represent)."""
    if filter_width:
        x = box_average(t, x, filter_width)
    return np.interp(grid, t, x)


def wheel_speed(angle: np.ndarray, dt: float, window: float = WHEEL_SPEED_WINDOW) -> np.ndarray:
    """Wheel speed (rad/s) from a cumulative wheel angle (rad) sampled every dt seconds (see module)."""
    n = int(round(window / dt))
    n = max(n + (1 - n % 2), 5)          # odd, at least 5 samples
    if angle.size < n:
        return np.gradient(angle, dt) if angle.size > 1 else np.zeros_like(angle)
    return savgol_filter(angle, n, 2, deriv=1, delta=dt, mode="interp")


def derive_wheel_speeds(channels: dict[str, np.ndarray], dt: float) -> dict[str, np.ndarray]:
    """The wheel_speed_* channels for every wheel_angle_* present (channels on a uniform grid)."""
    return {s: wheel_speed(channels[a], dt) for s, a in DERIVED.items() if a in channels}
