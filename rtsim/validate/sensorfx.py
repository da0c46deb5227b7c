"""Sensor effects on a model's sampled outputs, through the vehicle's one sensor model
(rtsim.vehicle.kit.sensor_model, compiled): a re-simulation is not needed for them, since they change
what the sensor reports, not the vehicle's motion. A wheel-angle channel's effect carries over to the
wheel speed derived from it (delay and scale; a constant angle bias does not show in a speed)."""
from __future__ import annotations

import numpy as np

from rtsim.vehicle.kit.sensor_model import apply_to_series, sensor_params

from .effectset import Effect
from .signals import DERIVED, derive_wheel_speeds

_PARAM = {"sensor_bias": "bias", "sensor_scale": "scale", "sensor_delay": "delay"}


def delayed(t: np.ndarray, x: np.ndarray, delay: float) -> np.ndarray:
    """x(t - delay) on the uniform grid t (the first value held before the start)."""
    if not delay:
        return x
    p = sensor_params(["x"], float(t[1] - t[0]), effects={"sensor_delay": [{"channel": "x", "delay": delay}]})
    return apply_to_series(p, np.asarray(x, dtype=float)[:, None])[:, 0]


def apply(outputs: dict[str, np.ndarray], t: np.ndarray, effects: list[Effect]) -> dict[str, np.ndarray]:
    """A copy of `outputs` (channel -> samples on the uniform grid t) with the sensor effects of
    `effects` applied (model effects ignored)."""
    sens = [e for e in effects if e.kind == "sensor" and e.channel in outputs]
    if not sens:
        return outputs
    names = sorted({e.channel for e in sens})
    mapping: dict[str, list] = {}
    for e in sens:
        key = _PARAM[e.name]
        mapping.setdefault(e.name, []).append({"channel": e.channel, key: float(e.params[key])})
    p = sensor_params(names, float(t[1] - t[0]), effects=mapping)
    y = apply_to_series(p, np.column_stack([outputs[n] for n in names]))
    out = dict(outputs)
    out.update({n: y[:, i] for i, n in enumerate(names)})
    angles = {a: out[a] for s, a in DERIVED.items() if a in names and s not in names}
    if angles:
        out.update(derive_wheel_speeds(angles, float(t[1] - t[0])))
    return out
