"""Sensor effects applied to the model's outputs after the simulation (a re-simulation is not needed
for them: they change what the sensor reports, not the vehicle's motion). In sensor-chain order per
channel: delay (the value `delay` s earlier, linear interpolation, the first value held before the
start), then scale, then bias. A wheel-angle channel's effect carries over to the wheel speed derived
from it (delay and scale; a constant angle bias does not show in a speed)."""
from __future__ import annotations

import numpy as np

from .effectset import Effect
from .signals import DERIVED, derive_wheel_speeds


def delayed(t: np.ndarray, x: np.ndarray, delay: float) -> np.ndarray:
    return np.interp(t - delay, t, x) if delay else x


def apply(outputs: dict[str, np.ndarray], t: np.ndarray, effects: list[Effect]) -> dict[str, np.ndarray]:
    """A copy of `outputs` with the sensor effects of `effects` applied (model effects ignored)."""
    sens = [e for e in effects if e.kind == "sensor"]
    if not sens:
        return outputs
    out = dict(outputs)
    touched = set()
    for name in ("sensor_delay", "sensor_scale", "sensor_bias"):
        for e in sens:
            if e.name != name:
                continue
            c = e.channel
            if c not in out:
                continue
            x = out[c]
            if name == "sensor_delay":
                x = delayed(t, x, float(e.params["delay"]))
            elif name == "sensor_scale":
                x = x * float(e.params["scale"])
            else:
                x = x + float(e.params["bias"])
            out[c] = x
            touched.add(c)
    angles = {a: out[a] for s, a in DERIVED.items() if a in touched and s not in touched}
    if angles:
        out.update(derive_wheel_speeds(angles, float(t[1] - t[0])))
    return out
