"""The sensor model: what a sensor reports of the physical value it senses, per channel, in sensor-chain
order:

    y = quantise(scale * x(t - delay) + bias + noise)

- delay (s): the physical value `delay` earlier, linear between the samples of a history ring that the
  owner records at its own cadence (every vehicle step; for a time series, every sample); before the
  first recorded sample the first value is held;
- scale (1) and bias (channel unit): a gain and an offset error;
- noise: white, Gaussian, of standard deviation `noise` (channel unit), drawn in channel order from the
  model's own generator, whose state is part of the model's state array (SplitMix64, Box-Muller): the
  same seed (`seed_noise`, `sensor_state(seed=)`) gives the same noise, whichever thread runs the
  model and whatever else draws random numbers;
- quantise: rounding to the nearest multiple of `quantum` (0: none).

One implementation for every user: the vehicle's sensor stage (offline runs and the service's compiled
loop call the same kernel) and the validation workflow (`apply_to_series` on a model's sampled outputs).
Its parameters come from two sources, combined in `sensor_params` into one array: the vehicle config's
``[sensors.channels.<name>]`` (bias, scale, noise_std, quantum, delay_s) and the switchable sensor
effects of the catalogue (sensor_bias, sensor_scale, sensor_delay): the effects' biases and delays add
to the config's, their scales multiply the config's (noise and quantum come from the config only).
Generic in the number of channels: the arrays are sized by the channel names given, and a name is
resolved to its index when the parameters are built.

Arrays: parameters (nch, NSM) float64; state `SensorState.HEADER + slots * nch` float64: the header (head slot,
number of slots, a flag that any parameter is not neutral, the noise generator's 64-bit state as two
32-bit halves), then the ring of the last `slots` recorded rows. A model with every channel neutral
(scale 1, all else 0) reports x exactly (bit for bit).
"""
from __future__ import annotations

from collections.abc import Mapping
from enum import IntEnum
from math import cos, floor, log, sqrt

import numpy as np

from rtsim.jit import kernel

from .layout import offsets

(SM_SCALE,       # 1
 SM_BIAS,        # channel unit
 SM_NOISE,       # channel unit, standard deviation
 SM_QUANTUM,     # channel unit, 0: no rounding
 SM_DELAY,       # recorded rows (float: linear between rows)
 NSM) = offsets(1, 1, 1, 1, 1)



class SensorState(IntEnum):
    """The header of the sensor model's state array (the recorded rows follow it)."""
    (HEAD,           # ring slot of the latest recorded row
     SLOTS,          # rows in the ring (0: no delay anywhere, nothing recorded)
     ON,             # 1.0: some channel is not neutral
     RNG,            # [2] noise generator state: high and low 32 bits of a uint64 (exact in float64)
     HEADER) = offsets(1, 1, 1, 2)


_LOW32 = np.uint64(0xFFFFFFFF)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)      # SplitMix64 increment and mixing constants
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_TWO_PI = 6.283185307179586


def neutral_params(nch: int) -> np.ndarray:
    """Every channel reports its physical value exactly."""
    p = np.zeros((nch, NSM))
    p[:, SM_SCALE] = 1.0
    return p


def sensor_params(names, step: float, channels: Mapping | None = None, effects: Mapping | None = None) -> np.ndarray:
    """Parameters for the channels `names`, recorded every `step` seconds, from the config's per-channel
    specs (`channels`: name -> an object or mapping with bias, scale, noise_std, quantum, delay_s) and the
    canonical sensor effects (`effects`: {"sensor_bias": [{"channel", "bias"}], "sensor_scale":
    [{"channel", "scale"}], "sensor_delay": [{"channel", "delay"}]}). Unknown channel: ValueError."""
    names = list(names)
    p = neutral_params(len(names))

    def index(name):
        if name not in names:
            raise ValueError(f"unknown sensor channel {name!r}; channels are {', '.join(names)}")
        return names.index(name)

    for name, spec in (channels or {}).items():
        get = spec.get if isinstance(spec, Mapping) else (lambda k, d=None, s=spec: getattr(s, k, d))
        c = index(name)
        p[c, SM_SCALE] *= float(get("scale", 1.0))
        p[c, SM_BIAS] += float(get("bias", 0.0))
        p[c, SM_NOISE] = float(get("noise_std", 0.0))
        p[c, SM_QUANTUM] = float(get("quantum", 0.0))
        p[c, SM_DELAY] += float(get("delay_s", 0.0)) / step
    for row in (effects or {}).get("sensor_bias", ()):
        p[index(row["channel"]), SM_BIAS] += float(row["bias"])
    for row in (effects or {}).get("sensor_scale", ()):
        p[index(row["channel"]), SM_SCALE] *= float(row["scale"])
    for row in (effects or {}).get("sensor_delay", ()):
        p[index(row["channel"]), SM_DELAY] += float(row["delay"]) / step
    whole = np.round(p[:, SM_DELAY])
    near = np.abs(p[:, SM_DELAY] - whole) < 1e-9
    p[near, SM_DELAY] = whole[near]          # a delay of whole steps is exactly that many rows
    return p


def ring_slots(params: np.ndarray) -> int:
    """Rows the ring needs for the longest delay (0 when there is none)."""
    longest = float(params[:, SM_DELAY].max()) if params.size else 0.0
    return int(floor(longest)) + 2 if longest > 0.0 else 0


def sensor_state(params: np.ndarray, seed: int = 0) -> np.ndarray:
    """A state for `params`: an empty ring of the length its delays need, the noise generator at `seed`."""
    nch = params.shape[0]
    slots = ring_slots(params)
    s = np.zeros(SensorState.HEADER + slots * nch)
    s[SensorState.SLOTS] = slots
    s[SensorState.ON] = 0.0 if np.array_equal(params, neutral_params(nch)) else 1.0
    seed_noise(s, seed)
    return s


def seed_noise(state: np.ndarray, seed: int) -> None:
    """Put the model's noise generator (in `state`) at `seed` (an integer, 0 <= seed < 2**64)."""
    seed = int(seed)
    if not 0 <= seed < 1 << 64:
        raise ValueError(f"noise seed must be in 0 .. 2**64 - 1, got {seed}")
    state[SensorState.RNG] = float(seed >> 32)
    state[SensorState.RNG + 1] = float(seed & 0xFFFFFFFF)


def copy_noise_state(src: np.ndarray, dst: np.ndarray) -> None:
    """Carry the noise generator's state over to another state array (e.g. a longer ring)."""
    dst[SensorState.RNG:SensorState.RNG + 2] = src[SensorState.RNG:SensorState.RNG + 2]


@kernel
def _uniform(state):
    """The next uniform number in [0, 1) of the generator in `state` (SplitMix64, 53 bits)."""
    s = (np.uint64(state[SensorState.RNG]) << np.uint64(32)) | np.uint64(state[SensorState.RNG + 1])
    s = s + _GOLDEN
    state[SensorState.RNG] = float(s >> np.uint64(32))
    state[SensorState.RNG + 1] = float(s & _LOW32)
    z = (s ^ (s >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    z = z ^ (z >> np.uint64(31))
    return float(z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@kernel
def standard_normal(state):
    """A standard normal draw from the generator in `state` (Box-Muller on two uniforms)."""
    u1 = 1.0 - _uniform(state)          # (0, 1]: the logarithm is finite
    u2 = _uniform(state)
    return sqrt(-2.0 * log(u1)) * cos(_TWO_PI * u2)


@kernel
def sensor_record(state, x):
    """Append the physical values x (one per channel) to the ring (no-op without delays)."""
    slots = int(state[SensorState.SLOTS])
    if slots == 0:
        return
    nch = x.shape[0]
    head = (int(state[SensorState.HEAD]) + 1) % slots
    state[SensorState.HEAD] = head
    o = SensorState.HEADER + head * nch
    for c in range(nch):
        state[o + c] = x[c]


@kernel
def sensor_next_row(state, nch):
    """Advance the ring's head and return the offset in `state` of its row (nch floats), for the caller
    to write the latest physical values into (there must be a ring: SensorState.SLOTS > 0)."""
    slots = int(state[SensorState.SLOTS])
    head = (int(state[SensorState.HEAD]) + 1) % slots
    state[SensorState.HEAD] = head
    return SensorState.HEADER + head * nch


@kernel
def sensor_fill(state, x):
    """Fill the whole ring with x (nothing older is known: the value is held)."""
    slots = int(state[SensorState.SLOTS])
    nch = x.shape[0]
    for k in range(slots):
        for c in range(nch):
            state[SensorState.HEADER + k * nch + c] = x[c]
    state[SensorState.HEAD] = 0.0


@kernel
def sensor_apply(params, state, x, out):
    """out = what the sensors report of the physical values x, whose latest row the ring holds already
    when there are delays (x and out may be the same array)."""
    nch = x.shape[0]
    if state[SensorState.ON] < 0.5:
        for c in range(nch):
            out[c] = x[c]
        return
    slots = int(state[SensorState.SLOTS])
    head = int(state[SensorState.HEAD])
    for c in range(nch):
        v = x[c]
        lag = params[c, SM_DELAY]
        if lag > 0.0 and slots > 0:
            n = int(lag)
            frac = lag - n
            a = state[SensorState.HEADER + ((head - n) % slots) * nch + c]
            b = state[SensorState.HEADER + ((head - n - 1) % slots) * nch + c]
            v = a + frac * (b - a)
        v = params[c, SM_SCALE] * v + params[c, SM_BIAS]
        if params[c, SM_NOISE] > 0.0:
            v += params[c, SM_NOISE] * standard_normal(state)
        qn = params[c, SM_QUANTUM]
        if qn > 0.0:
            v = qn * floor(v / qn + 0.5)
        out[c] = v


@kernel
def _apply_rows(params, state, x, out):
    for k in range(x.shape[0]):
        if k == 0:
            sensor_fill(state, x[0])
        else:
            sensor_record(state, x[k])
        sensor_apply(params, state, x[k], out[k])


def apply_to_series(params: np.ndarray, x: np.ndarray, seed: int = 0) -> np.ndarray:
    """The model on a sampled series x (n samples, nch channels; the parameters' delays in samples, i.e.
    built with the series' sample interval as `step`), its noise from `seed`; returns a new array."""
    x = np.ascontiguousarray(x, dtype=float)
    if not x.flags.writeable:       # read-only (a replay a Ray task returned): numba would type it apart and
        x = x.copy()                # compile the kernels again for it
    out = np.empty_like(x)
    if x.shape[0]:
        _apply_rows(params, sensor_state(params, seed), x, out)
    return out


def delayed(x: np.ndarray, step: float, delay: float) -> np.ndarray:
    """x(t - delay) of a series x sampled every `step` s (the model with that delay alone; the first
    value held before the start)."""
    x = np.asarray(x, dtype=float)
    if not delay:
        return x
    p = sensor_params(["x"], step, effects={"sensor_delay": [{"channel": "x", "delay": delay}]})
    return apply_to_series(p, x[:, None])[:, 0]
