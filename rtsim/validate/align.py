"""Time alignment of repetitions: where each run's manoeuvre starts, so that the runs can be laid on
one grid.

Two methods (the one used is reported):
- ``xcorr`` (default): cross-correlation of the model inputs (brake pressure, wheel torques, throttle,
  steering-wheel angle: those that vary). Every run's inputs are resampled at `XCORR_RATE` from its own
  start and divided by their sample noise (median over the runs; at least `NOISE_FLOOR` of the spread), so
  each input weighs by its signal-to-noise ratio: the driver's command, recorded clean, decides, and a
  feedback input that differs between repetitions (a speed controller's torque) weighs little; for every pair of runs the lag maximising
  the Pearson correlation of the inputs over the runs' overlap is found (all lags at once with FFTs
  and cumulative sums; refined to a fraction of a sample by a parabola through the peak). The
  reference is the run that correlates best with the others (highest median correlation); each run's
  offset is its lag to the reference.
- ``event:<channel>[:<fraction>]``: the first time the named channel crosses `fraction` (default 0.5)
  of the way from its initial value (median of the first 0.2 s) to its extreme value (largest
  deviation from the initial value), linearly interpolated between samples.

Offsets are returned as the run time at which the aligned time is zero.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from rtsim.errors import ConfigError

from .data import Run
from .signals import box_average

XCORR_RATE = 100.0          # Hz
NOISE_FLOOR = 1e-3          # an input's weight scale is at least this share of its spread (noise-free inputs)


@dataclass
class Alignment:
    method: str                       # text saying how the runs were aligned
    offsets: list[float]              # run time (s) at aligned time 0, per run
    correlation: list[float] = field(default_factory=list)   # input correlation with the reference (xcorr)
    reference: int = 0


@functools.cache
def default_profile():
    """The default vehicle's validation profile (rtsim.vehicle.registry.DEFAULT_VEHICLE), for a caller
    that names none (the workflow always passes its vehicle's)."""
    from rtsim.vehicle.registry import open_vehicle
    return open_vehicle(None).validation


def sample_noise(x: np.ndarray) -> float:
    """The white noise of a sampled signal, from its second differences (robust: median absolute
    deviation; a smooth signal's second differences are near zero, white noise of sd s gives sd s sqrt(6))."""
    d2 = np.diff(x, 2)
    return float(np.median(np.abs(d2 - np.median(d2)))) / 0.6745 / np.sqrt(6.0) if d2.size else 0.0


def varying_inputs(runs: list[Run], profile=None) -> list[str]:
    """Inputs present in every run that vary across the manoeuvre: the range of the signal smoothed
    over 0.1 s exceeds the vehicle profile's min_range and ten times the sample noise (estimated from
    second differences), in every run. A channel that only carries noise would make the correlation meaningless.
    `profile`: the vehicle's validation profile (rtsim.vehicle.validation; None: the default vehicle's)."""
    out = []
    prof = profile or default_profile()
    for name in prof.inputs:
        if not all(name in r.channels for r in runs):
            continue
        ok = True
        for r in runs:
            x = r.channels[name]
            sm = box_average(r.time, x, 0.1)
            if float(np.ptp(sm)) <= max(prof.min_range.get(name, 0.0), 10.0 * sample_noise(x)):
                ok = False
                break
        if ok:
            out.append(name)
    return out


def _uniform(run: Run, names: list[str], scales: dict[str, float], fs: float) -> np.ndarray:
    """(len(names), m) standardised inputs of a run on the grid start + k / fs."""
    m = int(np.floor(run.duration * fs)) + 1
    g = run.time[0] + np.arange(m) / fs
    return np.stack([np.interp(g, run.time, run.channels[n]) / scales[n] for n in names])


def _best_lag(a: np.ndarray, b: np.ndarray, max_lag: int) -> tuple[float, float]:
    """Lag L (samples, fractional) with b[k + L] ~ a[k], maximising the Pearson correlation of the
    channels over the overlap (computed for every lag with FFTs and cumulative sums, so the changing
    overlap does not bias the result), and that correlation."""
    na, nb = a.shape[1], b.shape[1]
    nfft = 1 << (na + nb - 1).bit_length()
    lags = np.arange(-max_lag, max_lag + 1)
    k0 = np.maximum(0, -lags)
    k1 = np.minimum(na, nb - lags)
    n = (k1 - k0).astype(float)
    ok = n >= 0.5 * min(na, nb)
    k1 = np.maximum(k1, k0)
    cov = np.zeros(lags.size)
    va = np.zeros(lags.size)
    vb = np.zeros(lags.size)
    for x, y in zip(a, b):
        sab = np.fft.irfft(np.fft.rfft(y, nfft) * np.conj(np.fft.rfft(x, nfft)), nfft)[lags % nfft]
        ca, cb = np.concatenate([[0.0], np.cumsum(x)]), np.concatenate([[0.0], np.cumsum(y)])
        ca2, cb2 = np.concatenate([[0.0], np.cumsum(x * x)]), np.concatenate([[0.0], np.cumsum(y * y)])
        sa, sb = ca[k1] - ca[k0], cb[k1 + lags] - cb[k0 + lags]
        saa, sbb = ca2[k1] - ca2[k0], cb2[k1 + lags] - cb2[k0 + lags]
        nn = np.maximum(n, 1.0)
        cov += sab - sa * sb / nn
        va += saa - sa * sa / nn
        vb += sbb - sb * sb / nn
    den = np.sqrt(np.maximum(va, 0.0) * np.maximum(vb, 0.0))
    r = np.where(ok & (den > 0.0), cov / np.where(den > 0.0, den, 1.0), -1.0)
    k = int(np.argmax(r))
    lag = float(lags[k])
    if 0 < k < r.size - 1 and r[k - 1] > -1.0 and r[k + 1] > -1.0:
        y0, y1, y2 = r[k - 1], r[k], r[k + 1]
        d = y0 - 2.0 * y1 + y2
        if d < 0.0:
            lag += 0.5 * (y0 - y2) / d
    return lag, float(r[k])


def align_xcorr(runs: list[Run], names: list[str], fs: float = XCORR_RATE, profile=None) -> Alignment:
    """Offsets by cross-correlation of the varying inputs `names` (see the module docstring)."""
    if not names:
        raise ConfigError("cannot align the runs by cross-correlation: no input channel varies "
                          f"(looked for {', '.join((profile or default_profile()).inputs)}); use --align "
                          "event:<channel>")
    scales = {}
    for n in names:
        allv = np.concatenate([r.channels[n] for r in runs])
        spread = float(np.std(allv)) or 1.0
        noise = float(np.median([sample_noise(r.channels[n]) for r in runs]))
        scales[n] = max(noise, NOISE_FLOOR * spread)
    sig = [_uniform(r, names, scales, fs) for r in runs]
    nr = len(runs)
    if nr == 1:
        return Alignment(f"single run (no alignment needed); inputs {', '.join(names)}", [float(runs[0].time[0])],
                         [1.0], 0)
    shortest = min(s.shape[1] for s in sig)
    max_lag = max(1, min(shortest // 2, int(10.0 * fs)))
    lag = np.zeros((nr, nr))
    cor = np.eye(nr)
    for i in range(nr):
        for j in range(i + 1, nr):
            lag[i, j], cor[i, j] = _best_lag(sig[i], sig[j], max_lag)
            lag[j, i], cor[j, i] = -lag[i, j], cor[i, j]
    med = [float(np.median(np.delete(cor[i], i))) for i in range(nr)]
    ref = int(np.argmax(med))
    offsets = [float(runs[i].time[0] + lag[ref, i] / fs) for i in range(nr)]
    return Alignment(f"cross-correlation of the inputs {', '.join(names)} at {fs:g} Hz, reference run "
                     f"{runs[ref].name}", offsets, [float(cor[ref, i]) for i in range(nr)], ref)


def event_time(run: Run, channel: str, fraction: float = 0.5, profile=None) -> float:
    """First time the channel crosses `fraction` of the way from its initial to its extreme value."""
    if channel not in run.channels:
        raise ConfigError(f"{run.path}: alignment event channel {channel!r} missing")
    t, x = run.time, run.channels[channel]
    x0 = float(np.median(x[t <= t[0] + 0.2]))
    k = int(np.argmax(np.abs(x - x0)))
    ext = float(x[k])
    if abs(ext - x0) < (profile or default_profile()).min_range.get(channel, 1e-9):
        raise ConfigError(f"{run.path}: alignment event channel {channel!r} does not change "
                          f"(initial {x0:.6g}, extreme {ext:.6g})")
    level = x0 + fraction * (ext - x0)
    s = np.sign(ext - x0)
    above = s * (x - level) >= 0.0
    i = int(np.argmax(above))
    if i == 0:
        return float(t[0])
    x1, x2 = x[i - 1], x[i]
    return float(t[i - 1] + (level - x1) / (x2 - x1) * (t[i] - t[i - 1]))


def align_event(runs: list[Run], channel: str, fraction: float = 0.5, profile=None) -> Alignment:
    times = [event_time(r, channel, fraction, profile) for r in runs]
    return Alignment(f"input event: {channel} crossing {fraction:g} of its initial-to-extreme change",
                     times, [], 0)


def align(runs: list[Run], method: str = "xcorr", profile=None) -> Alignment:
    """Alignment by `method`: "xcorr" or "event:<channel>[:<fraction>]"; `profile`: the vehicle's
    validation profile (its inputs and their least ranges; None: the default vehicle's)."""
    if method == "xcorr":
        return align_xcorr(runs, varying_inputs(runs, profile), profile=profile)
    if method.startswith("event:"):
        parts = method.split(":")
        try:
            frac = float(parts[2]) if len(parts) > 2 else 0.5
        except ValueError:
            raise ConfigError(f"--align {method!r}: fraction {parts[2]!r} is not a number") from None
        if not 0.0 < frac < 1.0:
            raise ConfigError(f"--align {method!r}: fraction must be between 0 and 1")
        return align_event(runs, parts[1], frac, profile)
    raise ConfigError(f"--align {method!r}: expected 'xcorr' or 'event:<channel>[:<fraction>]'")
