"""Open-loop input profiles: a value per channel as a function of time, for scripted manoeuvres.

Building blocks (Python objects, built once from a scenario or by hand; times in s, values in the
channel's unit, see `drivers.base`):

    constant(v)                         v at all times
    table(time, value, hold=False)      piecewise linear through the nodes (hold=True: zero-order hold,
                                        each value kept until the next node); before the first node the
                                        first value, after the last node the last value
    step(t0, after, before=0, ramp=0)   `before` until t0, then `after`; with ramp > 0 a straight line
                                        from `before` at t0 to `after` at t0 + ramp
    ramp(t0, t1, v0, v1)                v0 until t0, linear to v1 at t1, v1 afterwards
    ramp(t0, v0=.., rate=..)            v0 until t0, then v0 + rate (t - t0) without end
    pulse(t0, value, rise, width, fall) trapezoid on a base (default 0): up over `rise` from t0, level
                                        for `width`, down over `fall`
    sine(amplitude, frequency, phase=0, t0=0, offset=0, fade_cycles=0)
                                        `offset` until t0, then offset + amplitude w(t) sin(2 pi f (t - t0)
                                        + phase); w rises from 0 to 1 over the first `fade_cycles`
                                        periods as a half cosine, 1/2 (1 - cos(pi (t - t0) / T_fade)),
                                        so that with phase 0 value and rate start smoothly; no fade: w = 1
    a + b, total([a, b, ...])           sum of profiles
    sequence([(d0, a), (d1, b), ...])   a for d0 seconds, then b for d1 seconds, ...; each part runs
                                        in its own time, starting at 0 when its segment starts; the
                                        last duration may be None (for ever). Segments start at t = 0.

Evaluation. `pack({channel: profile})` flattens every profile into *terms*: an elementary function
(constant, ramp, slope, table, uniform table, sine) with a time window [t_on, t_off) and a time shift; a
channel's value is the sum of its active terms evaluated at t - shift. Sums concatenate terms and
sequences window and shift them, so any nesting flattens to one array of terms per channel. The
packed arrays (`Packed`) are what the kernels read: `eval_profiles(p, t, out)` writes all channels at
time t without allocating (a table costs a binary search, a uniform table O(1)); `sample_profiles`
evaluates a whole time vector (validation, plots, tests).
"""
from __future__ import annotations

import math
from collections import namedtuple
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from rtsim.jit import inline_kernel, kernel

from .base import INPUT_INDEX, NINPUT

# Term kinds and their parameters par[0..3].
K_CONST = 0    # value
K_RAMP = 1     # t0, t1, v0, v1: v0 before t0, linear to v1 at t1 (t1 == t0: a step), v1 after
K_SLOPE = 2    # t0, rate, v0: v0 before t0, v0 + rate (t - t0) after
K_TABLE = 3    # hold flag (1: zero-order hold); nodes tab_t/tab_v[start:start + n]
K_UNIFORM = 4  # t_first, dt, hold flag; values tab_v[start:start + n] at t_first + k dt
K_SINE = 5     # amplitude, angular frequency (rad/s), phase (rad), fade-in time (s); its own time
               # starts at 0 at the sine's t0 (the term's window opens there and its shift is t0)
KIND_NAMES = ("constant", "ramp", "slope", "table", "uniform", "sine")

#: Zero-order hold switches to a node's value when t is within this many seconds of the node (times
#: built as k*dt may land a rounding error below it).
HOLD_EPS = 1e-9

#: The packed profiles of all channels. Terms of channel c are rows ch_first[c] .. ch_first[c+1]-1.
Packed = namedtuple("Packed", [
    "ch_first",  # int64[nch + 1]
    "kind",      # int64[nterm]
    "win",       # float64[nterm, 3]: t_on, t_off, shift
    "par",       # float64[nterm, 4]
    "tab",       # int64[nterm, 2]: first node, node count (tables only)
    "tab_t",     # float64[ntab]: table node times
    "tab_v",     # float64[ntab]: table node values
])


# --------------------------------------------------------------------------------------------------
# Kernels


@inline_kernel
def _table(tt, tv, s, n, tau, hold):
    last = s + n - 1
    if tau <= tt[s]:
        return tv[s]
    if tau >= tt[last]:
        return tv[last]
    if hold != 0.0:
        tau = tau + HOLD_EPS
    lo = s
    hi = last
    while hi - lo > 1:
        mid = (lo + hi) >> 1
        if tt[mid] <= tau:
            lo = mid
        else:
            hi = mid
    if hold != 0.0:
        return tv[lo]
    return tv[lo] + (tv[hi] - tv[lo]) * ((tau - tt[lo]) / (tt[hi] - tt[lo]))


@inline_kernel
def _uniform(tv, s, n, tau, t_first, dt, hold):
    u = (tau - t_first) / dt
    if u <= 0.0:
        return tv[s]
    if hold != 0.0:
        i = int(math.floor(u + 1e-6))
        if i >= n - 1:
            return tv[s + n - 1]
        return tv[s + i]
    i = int(math.floor(u))
    if i >= n - 1:
        return tv[s + n - 1]
    f = u - i
    return tv[s + i] + f * (tv[s + i + 1] - tv[s + i])


@inline_kernel
def _sine(tau, amp, omega, phase, fade):
    """amp w(tau) sin(omega tau + phase), tau >= 0 (s since the sine's start); w: a half-cosine rise
    from 0 to 1 over `fade` s (1 without fade)."""
    w = 1.0
    if tau < fade:
        w = 0.5 * (1.0 - math.cos(math.pi * tau / fade))
    return amp * w * math.sin(omega * tau + phase)


@kernel
def eval_channel(p, c, t):
    """Value of channel c of the packed profiles `p` at time t (0 for a channel without terms)."""
    val = 0.0
    for k in range(p.ch_first[c], p.ch_first[c + 1]):
        if t < p.win[k, 0] or t >= p.win[k, 1]:
            continue
        tau = t - p.win[k, 2]
        kind = p.kind[k]
        a = p.par[k, 0]
        b = p.par[k, 1]
        c2 = p.par[k, 2]
        d = p.par[k, 3]
        if kind == K_CONST:
            val += a
        elif kind == K_RAMP:
            if tau < a:
                val += c2
            elif tau >= b:
                val += d
            else:
                val += c2 + (d - c2) * ((tau - a) / (b - a))
        elif kind == K_SLOPE:
            if tau < a:
                val += c2
            else:
                val += c2 + b * (tau - a)
        elif kind == K_TABLE:
            val += _table(p.tab_t, p.tab_v, p.tab[k, 0], p.tab[k, 1], tau, a)
        elif kind == K_UNIFORM:
            val += _uniform(p.tab_v, p.tab[k, 0], p.tab[k, 1], tau, a, b, c2)
        else:  # K_SINE
            val += _sine(tau, a, b, c2, d)
    return val


@kernel
def eval_profiles(p, t, out):
    """out[c] = value of channel c at time t, for every packed channel."""
    for c in range(p.ch_first.shape[0] - 1):
        out[c] = eval_channel(p, c, t)


@kernel
def sample_profiles(p, times, out):
    """out[i, c] = value of channel c at times[i]."""
    for i in range(times.shape[0]):
        for c in range(p.ch_first.shape[0] - 1):
            out[i, c] = eval_channel(p, c, times[i])


# --------------------------------------------------------------------------------------------------
# Profile objects

# A flattened term: (kind, t_on, t_off, shift, (p0, p1, p2, p3), tab_t or None, tab_v or None).


def _finite(name: str, x: float) -> float:
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


class Profile:
    """Base class: a value as a function of time. Combine with `+` or `sequence`."""

    def terms(self) -> list[tuple]:
        raise NotImplementedError

    def __add__(self, other: "Profile") -> "Sum":
        if not isinstance(other, Profile):
            return NotImplemented
        return Sum((self, other))

    def sample(self, times) -> np.ndarray:
        """Values at the given times (packs this profile alone; not for per-step use)."""
        p = pack({0: self}, nch=1)
        times = np.ascontiguousarray(times, dtype=np.float64).reshape(-1)
        out = np.empty((times.shape[0], 1))
        sample_profiles(p, times, out)
        return out[:, 0]


@dataclass(frozen=True)
class Constant(Profile):
    value: float

    def __post_init__(self):
        _finite("value", self.value)

    def terms(self):
        return [(K_CONST, -math.inf, math.inf, 0.0, (float(self.value), 0.0, 0.0, 0.0), None, None)]


@dataclass(frozen=True)
class Ramp(Profile):
    """v0 before t0, straight line to v1 at t1, v1 after (t1 == t0 is a step at t0)."""
    t0: float
    t1: float
    v0: float
    v1: float

    def __post_init__(self):
        for n in ("t0", "t1", "v0", "v1"):
            _finite(n, getattr(self, n))
        if self.t1 < self.t0:
            raise ValueError(f"ramp end t1 = {self.t1} s is before its start t0 = {self.t0} s")

    def terms(self):
        return [(K_RAMP, -math.inf, math.inf, 0.0,
                 (float(self.t0), float(self.t1), float(self.v0), float(self.v1)), None, None)]


@dataclass(frozen=True)
class Slope(Profile):
    """v0 before t0, then v0 + rate (t - t0) without end."""
    t0: float
    rate: float
    v0: float = 0.0

    def __post_init__(self):
        for n in ("t0", "rate", "v0"):
            _finite(n, getattr(self, n))

    def terms(self):
        return [(K_SLOPE, -math.inf, math.inf, 0.0,
                 (float(self.t0), float(self.rate), float(self.v0), 0.0), None, None)]


class Table(Profile):
    """Piecewise-linear (or zero-order hold) interpolation of nodes; the end values are held."""

    def __init__(self, time, value, hold: bool = False):
        t = np.array(time, dtype=np.float64).reshape(-1)
        v = np.array(value, dtype=np.float64).reshape(-1)
        if t.shape != v.shape:
            raise ValueError(f"table has {t.size} times but {v.size} values")
        if t.size == 0:
            raise ValueError("table is empty")
        if not np.all(np.isfinite(t)):
            raise ValueError(f"table time[{int(np.argmin(np.isfinite(t)))}] is not finite")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"table value[{int(np.argmin(np.isfinite(v)))}] is not finite")
        bad = np.nonzero(np.diff(t) <= 0.0)[0]
        if bad.size:
            i = int(bad[0]) + 1
            raise ValueError(f"table time[{i}] = {t[i]} s does not increase (time[{i - 1}] = {t[i - 1]} s)")
        self.time = t
        self.value = v
        self.hold = bool(hold)

    def terms(self):
        return [(K_TABLE, -math.inf, math.inf, 0.0, (1.0 if self.hold else 0.0, 0.0, 0.0, 0.0),
                 self.time, self.value)]

    def __repr__(self):
        return f"Table(n={self.time.size}, t=[{self.time[0]}..{self.time[-1]}], hold={self.hold})"


class Uniform(Profile):
    """Values on a uniform time grid t_first + k dt (a resampled recording): O(1) evaluation."""

    def __init__(self, t_first: float, dt: float, values, hold: bool = False):
        v = np.array(values, dtype=np.float64).reshape(-1)
        if v.size == 0:
            raise ValueError("uniform table is empty")
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ValueError(f"uniform table step dt = {dt} must be > 0")
        if not np.all(np.isfinite(v)):
            raise ValueError(f"uniform table value[{int(np.argmin(np.isfinite(v)))}] is not finite")
        self.t_first = _finite("t_first", t_first)
        self.dt = float(dt)
        self.values = v
        self.hold = bool(hold)

    def terms(self):
        return [(K_UNIFORM, -math.inf, math.inf, 0.0,
                 (self.t_first, self.dt, 1.0 if self.hold else 0.0, 0.0), None, self.values)]

    def __repr__(self):
        return f"Uniform(t_first={self.t_first}, dt={self.dt}, n={self.values.size}, hold={self.hold})"


@dataclass(frozen=True)
class Sine(Profile):
    """0 before t0, then amplitude w(t) sin(2 pi frequency (t - t0) + phase), w rising over
    fade_cycles periods (see `sine`)."""
    amplitude: float
    frequency: float
    phase: float = 0.0
    t0: float = 0.0
    fade_cycles: float = 0.0

    def __post_init__(self):
        for n in ("amplitude", "frequency", "phase", "t0", "fade_cycles"):
            _finite(n, getattr(self, n))
        if not self.frequency > 0.0:
            raise ValueError(f"sine frequency = {self.frequency} Hz must be > 0")
        if not self.fade_cycles >= 0.0:
            raise ValueError(f"sine fade_cycles = {self.fade_cycles} must be >= 0")

    def terms(self):
        t0 = float(self.t0)
        return [(K_SINE, t0, math.inf, t0, (float(self.amplitude), 2.0 * math.pi * self.frequency,
                                            float(self.phase), self.fade_cycles / self.frequency), None, None)]


@dataclass(frozen=True)
class Sum(Profile):
    parts: tuple

    def terms(self):
        return [term for part in self.parts for term in part.terms()]


@dataclass(frozen=True)
class SequenceProfile(Profile):
    """Parts one after the other, each on its own clock starting when its segment starts."""
    segments: tuple  # ((duration or inf, profile), ...)

    def terms(self):
        out = []
        start = 0.0
        for duration, part in self.segments:
            end = start + duration
            for kind, on, off, shift, par, tt, tv in part.terms():
                on2 = max(on + start, start)
                off2 = min(off + start, end)
                if on2 < off2:
                    out.append((kind, on2, off2, shift + start, par, tt, tv))
            start = end
        return out


# --------------------------------------------------------------------------------------------------
# Constructors


def constant(value: float) -> Constant:
    return Constant(float(value))


def table(time, value, hold: bool = False) -> Table:
    return Table(time, value, hold)


def step(t0: float, after: float, before: float = 0.0, ramp: float = 0.0) -> Ramp:
    """`before` until t0, then `after` (reached linearly over `ramp` seconds if ramp > 0)."""
    if not ramp >= 0.0:
        raise ValueError(f"step ramp = {ramp} s must be >= 0")
    return Ramp(float(t0), float(t0) + float(ramp), float(before), float(after))


def ramp(t0: float, t1: float | None = None, v0: float = 0.0, v1: float | None = None,
         rate: float | None = None) -> Profile:
    """Either ramp(t0, t1, v0, v1) (from v0 at t0 to v1 at t1, held after) or ramp(t0, v0=, rate=)
    (unbounded). Given t1 and rate, v1 = v0 + rate (t1 - t0)."""
    if t1 is None:
        if rate is None or v1 is not None:
            raise ValueError("a ramp without end time t1 needs a rate and no end value v1")
        return Slope(float(t0), float(rate), float(v0))
    if v1 is None:
        if rate is None:
            raise ValueError("a ramp needs an end value v1 or a rate")
        v1 = v0 + rate * (t1 - t0)
    elif rate is not None:
        raise ValueError("give a ramp either an end value v1 or a rate, not both")
    return Ramp(float(t0), float(t1), float(v0), float(v1))


def pulse(t0: float, value: float, rise: float, width: float, fall: float, base: float = 0.0) -> Sum:
    """Trapezoid: `base` until t0, up to `value` over `rise` s, level for `width` s, back down to
    `base` over `fall` s."""
    for n, x in (("rise", rise), ("width", width), ("fall", fall)):
        if not x >= 0.0:
            raise ValueError(f"pulse {n} = {x} s must be >= 0")
    t_down = t0 + rise + width
    return Sum((Constant(float(base)),
                Ramp(float(t0), float(t0 + rise), 0.0, float(value - base)),
                Ramp(float(t_down), float(t_down + fall), 0.0, float(base - value))))


def sine(amplitude: float, frequency: float, phase: float = 0.0, t0: float = 0.0, offset: float = 0.0,
         fade_cycles: float = 0.0) -> Profile:
    """`offset` until t0, then offset + amplitude w sin(2 pi frequency (t - t0) + phase) for ever
    (frequency in Hz, phase in rad); w rises from 0 to 1 over the first `fade_cycles` periods as a half
    cosine (0: no fade, the sine starts at full amplitude)."""
    s = Sine(float(amplitude), float(frequency), float(phase), float(t0), float(fade_cycles))
    return s if offset == 0.0 else Sum((Constant(float(offset)), s))


def total(parts: Iterable[Profile]) -> Sum:
    return Sum(tuple(parts))


def sequence(segments: Iterable[tuple[float | None, Profile]]) -> SequenceProfile:
    """[(duration, profile), ...]: each part for its duration on its own clock; None = for ever
    (allowed for the last segment only). After a finite last segment the channel is 0."""
    segs = []
    items = list(segments)
    for i, (duration, part) in enumerate(items):
        if duration is None:
            if i != len(items) - 1:
                raise ValueError(f"sequence segment {i}: only the last segment may last for ever")
            duration = math.inf
        if not duration > 0.0:
            raise ValueError(f"sequence segment {i}: duration = {duration} s must be > 0")
        segs.append((float(duration), part))
    return SequenceProfile(tuple(segs))


# --------------------------------------------------------------------------------------------------
# Packing


def pack(profiles: Mapping[int | str, Profile], nch: int = NINPUT) -> Packed:
    """Flatten the profiles of channels (index or input name) into the arrays the kernels read.
    Channels without a profile evaluate to 0."""
    by_ch: list[list[tuple]] = [[] for _ in range(nch)]
    for key, prof in profiles.items():
        c = INPUT_INDEX[key] if isinstance(key, str) else int(key)
        if not 0 <= c < nch:
            raise ValueError(f"channel {key!r} out of range 0..{nch - 1}")
        by_ch[c].extend(prof.terms())
    rows = [t for ch in by_ch for t in ch]
    n = len(rows)
    ch_first = np.zeros(nch + 1, dtype=np.int64)
    ch_first[1:] = np.cumsum([len(ch) for ch in by_ch])
    kind = np.zeros(n, dtype=np.int64)
    win = np.zeros((n, 3))
    par = np.zeros((n, 4))
    tab = np.zeros((n, 2), dtype=np.int64)
    tt_parts: list[np.ndarray] = []
    tv_parts: list[np.ndarray] = []
    ntab = 0
    for k, (knd, on, off, shift, pr, tt, tv) in enumerate(rows):
        kind[k] = knd
        win[k] = (on, off, shift)
        par[k] = pr
        if tv is not None:
            tab[k] = (ntab, tv.size)
            tv_parts.append(tv)
            tt_parts.append(tt if tt is not None else np.zeros(tv.size))
            ntab += tv.size
    tab_t = np.concatenate(tt_parts) if tt_parts else np.zeros(1)
    tab_v = np.concatenate(tv_parts) if tv_parts else np.zeros(1)
    return Packed(ch_first, kind, win, par, tab, np.ascontiguousarray(tab_t), np.ascontiguousarray(tab_v))


def sample(p: Packed, times: Sequence[float] | np.ndarray) -> np.ndarray:
    """Values of all packed channels at the given times: array [len(times), nch]."""
    times = np.ascontiguousarray(times, dtype=np.float64).reshape(-1)
    out = np.empty((times.shape[0], p.ch_first.shape[0] - 1))
    sample_profiles(p, times, out)
    return out
