"""Small kernels shared by the by-wire subsystems (brake pressure, throttle plate, steering motor), and
the config plumbing those subsystems share.

A *lag block* is the standard actuator element here: an optional transport delay of a whole number of
steps, then a first-order lag discretised exactly for a held input (zero-order hold), then a rate limit,
with the command and the output saturated to [min, max]. It lives inside the owner's arrays:

- parameters: ``LAG_NPAR`` floats at an offset ``ip`` of the owner's parameter array
  (``LAG_TAU`` time constant s, ``LAG_RATE`` rate limit in output units per s, ``LAG_LO``/``LAG_HI``
  output bounds, ``LAG_DELAY`` transport delay s, used only to size the state);
- state: ``3 + nbuf`` floats at an offset ``is_`` of the owner's state array (``LAG_Y`` output,
  ``LAG_HEAD`` ring-buffer read/write position, ``LAG_NBUF`` delay in steps, then the ring buffer).

The delay in steps is fixed when the state is built, as ``round(delay / dt)``; a block with no delay has
a 3-float state. Because the buffer has variable length, an owner keeps at most one delayed block, at
the end of its state array.

Step response of the lag alone: y_k = 1 - exp(-k dt / tau), so the output reaches 63.2 % of a step
exactly at t = tau whatever dt is. A zero time constant makes the lag a pass-through.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import MISSING, dataclass, fields, is_dataclass

import numpy as np
from pydantic import ConfigDict, TypeAdapter

from rtsim.configfile import NonNegative, Range, bad, check_declared_ranges, validate
from rtsim.errors import ConfigError
from rtsim.jit import inline_kernel, kernel

# Lag block, parameter slots (relative to the block's offset in the owner's parameter array).
LAG_TAU = 0
LAG_RATE = 1
LAG_LO = 2
LAG_HI = 3
LAG_DELAY = 4
LAG_NPAR = 5

# Lag block, state slots (relative to the block's offset in the owner's state array).
LAG_Y = 0
LAG_HEAD = 1
LAG_NBUF = 2
LAG_BUF = 3


# ----------------------------------------------------------------------------------------- kernels
@inline_kernel
def saturate(x, lo, hi):
    """x clipped to [lo, hi]."""
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@inline_kernel
def rate_limit(y, target, rate, dt):
    """Move from y towards target by at most rate * dt (rate may be inf)."""
    step = rate * dt
    d = target - y
    if d > step:
        return y + step
    if d < -step:
        return y - step
    return target


@inline_kernel
def lag_alpha(tau, dt):
    """Exact zero-order-hold gain of a first-order lag over one step: 1 - exp(-dt / tau)."""
    if tau <= 0.0:
        return 1.0
    return 1.0 - math.exp(-dt / tau)


@kernel
def delay_push(s, is_, u):
    """Write u into the block's ring buffer and return the value written nbuf steps ago (u itself when
    the block has no delay)."""
    n = int(s[is_ + LAG_NBUF])
    if n <= 0:
        return u
    h = int(s[is_ + LAG_HEAD])
    out = s[is_ + LAG_BUF + h]
    s[is_ + LAG_BUF + h] = u
    h += 1
    if h >= n:
        h = 0
    s[is_ + LAG_HEAD] = h
    return out


@kernel
def lag_step(p, ip, s, is_, u, dt):
    """Advance the lag block (parameters at p[ip:], state at s[is_:]) by one step with command u;
    return the new output."""
    lo = p[ip + LAG_LO]
    hi = p[ip + LAG_HI]
    ud = delay_push(s, is_, saturate(u, lo, hi))
    y = s[is_ + LAG_Y]
    target = y + (ud - y) * lag_alpha(p[ip + LAG_TAU], dt)
    y = saturate(rate_limit(y, target, p[ip + LAG_RATE], dt), lo, hi)
    s[is_ + LAG_Y] = y
    return y


# ------------------------------------------------------------------------------------ python side
def delay_steps(delay: float, dt: float) -> int:
    """The transport delay in whole steps: round(delay / dt)."""
    if dt <= 0.0:
        raise ValueError(f"time step must be positive, got {dt}")
    return int(round(max(delay, 0.0) / dt))


def lag_params(tau: float = 0.0, rate: float = math.inf, lo: float = -math.inf,
               hi: float = math.inf, delay: float = 0.0) -> np.ndarray:
    """A standalone lag-block parameter array (LAG_NPAR floats)."""
    p = np.empty(LAG_NPAR)
    p[LAG_TAU], p[LAG_RATE], p[LAG_LO], p[LAG_HI], p[LAG_DELAY] = tau, rate, lo, hi, delay
    return p


def lag_state_size(p: np.ndarray, ip: int, dt: float) -> int:
    """Number of state floats of the lag block whose parameters sit at p[ip:], for step dt."""
    return LAG_BUF + delay_steps(float(p[ip + LAG_DELAY]), dt)


def lag_init(p: np.ndarray, ip: int, s: np.ndarray, is_: int, dt: float, y0: float) -> None:
    """Initialise the block's state at rest at output y0 (buffer filled with y0)."""
    n = delay_steps(float(p[ip + LAG_DELAY]), dt)
    if s.shape[0] < is_ + LAG_BUF + n:
        raise ValueError(f"state array too short for a lag block with {n} delay steps")
    y0 = min(max(y0, float(p[ip + LAG_LO])), float(p[ip + LAG_HI]))
    s[is_ + LAG_Y] = y0
    s[is_ + LAG_HEAD] = 0.0
    s[is_ + LAG_NBUF] = float(n)
    s[is_ + LAG_BUF:is_ + LAG_BUF + n] = y0


def lag_state(p: np.ndarray, dt: float, y0: float = 0.0) -> np.ndarray:
    """A standalone lag-block state array for the parameters p (from lag_params)."""
    s = np.zeros(lag_state_size(p, 0, dt))
    lag_init(p, 0, s, 0, dt, y0)
    return s


# ------------------------------------------------------------------------------------------ config
def check(ok: bool, key: str, value, allowed: str) -> None:
    """In a config dataclass's __post_init__: unless ok, the error about `key` (rtsim.configfile formats
    it with the file and the section's full key)."""
    if not ok:
        raise bad(key, value, allowed)


@functools.cache
def _adapter(cls) -> TypeAdapter:
    return TypeAdapter(cls)


def over_defaults(cls, data: Mapping) -> dict:
    """A partial table of a section overrides that section's default (the owner's, which may differ
    from the section class's own), key by key, at every depth."""
    out = dict(data)
    for f in fields(cls):
        if f.default_factory is not MISSING and is_dataclass(default := f.default_factory()) \
                and isinstance(out.get(f.name), Mapping):
            merged = {g.name: getattr(default, g.name) for g in fields(default)}
            merged.update(over_defaults(type(default), out[f.name]))
            out[f.name] = merged
    return out


def part_config(cls, data, where: str):
    """The config dataclass `cls` of a part from a mapping (a TOML table), an instance (as is), or None
    (the defaults), validated by pydantic (rtsim.configfile: one mechanism, one error format naming
    ``where.key``, the value and what is allowed)."""
    if isinstance(data, cls):
        return data
    if data is not None and not isinstance(data, Mapping):
        raise ConfigError(f"{where} = {data!r}: must be a table (a [section] or {{key = value, ...}})")
    return validate(_adapter(cls), over_defaults(cls, data or {}), "", prefix=where)


def pydantic_config(cls):
    """Make a config dataclass strict for pydantic: unknown keys are errors."""
    cls.__pydantic_config__ = ConfigDict(extra="forbid")
    return cls


@pydantic_config
@dataclass(frozen=True)
class LagConfig:
    """A by-wire actuator as a lag block. Units are those of the actuated quantity (kPa for brake
    pressure, rad for the throttle plate, N*m for a motor torque)."""
    time_constant: NonNegative("s") = 0.0                             # first-order lag (0: none)
    rate_limit: Range(0.0, math.inf, "units/s (inf: none)", lo_open=True) = math.inf   # largest output rate
    delay: Range(0.0, 1.0, "s") = 0.0                                 # pure transport delay, whole steps
    min: Range(-math.inf, math.inf, "units") = -math.inf              # lower bound of command and output
    max: Range(-math.inf, math.inf, "units") = math.inf               # upper bound of command and output

    def __post_init__(self) -> None:
        check_declared_ranges(self)
        check(self.min < self.max, "max", self.max, f"expected max > min ({self.min})")

    def params(self) -> np.ndarray:
        return lag_params(self.time_constant, self.rate_limit, self.min, self.max, self.delay)
