"""Where the model and the benchmark disagree: per channel the residual (model - mean), the share of
samples outside the 95 % band, and in which phase of the manoeuvre and which operating regime the
excess (the part of |residual| beyond the band's half-width; the whole |residual| without a band)
concentrates.

Regimes, from the benchmark means (one label per sample): `standstill` (speed below 0.1 m/s, speed =
mean wheel speed x the model's rolling radius), else `braking` (line pressure above 5 % of its peak and
50 kPa), `acceleration` (drive torque or throttle above 5 % of its peak), or `coasting`; steering
(|steering-wheel angle| > `STEER_ANGLE`) is flagged on top. Phases are the manoeuvre's successive
regimes, a steered stretch being its own phase ("coasting + steering"; stretches shorter than 0.3 s,
e.g. the steering wheel passing through zero in a lane change, merged into the one before). Speed: the
excess-weighted mean speed and the correlation of |residual| with speed say whether the gap grows with
speed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .benchmark import Benchmark
from .signals import WHEEL_SPEEDS

STANDSTILL_SPEED = 0.1       # m/s
STEER_ANGLE = 0.05           # rad of steering-wheel angle
MIN_PHASE = 0.3              # s
REGIMES = ("standstill", "acceleration", "coasting", "braking")


@dataclass
class Phase:
    index: int
    regime: str
    start: float
    end: float

    def label(self) -> str:
        return f"phase {self.index} ({self.regime}, {self.start:.1f}-{self.end:.1f} s)"


@dataclass
class Regimes:
    labels: np.ndarray          # regime name per sample
    steering: np.ndarray        # bool per sample
    speed: np.ndarray           # m/s
    phases: list[Phase]


def regimes(bench: Benchmark, wheel_radius: float) -> Regimes:
    n = bench.t.size
    ws = [bench.mean(c) for c in WHEEL_SPEEDS if c in bench.bands]
    speed = np.mean(ws, axis=0) * wheel_radius if ws else np.zeros(n)
    lab = np.full(n, "coasting", dtype=object)

    def active(c, floor):
        if c not in bench.bands:
            return np.zeros(n, bool)
        x = bench.mean(c)
        return x > max(floor, 0.05 * float(np.max(x)))

    drive = active("wheel_torque_rl", 2.0) | active("wheel_torque_rr", 2.0) | active("throttle_angle", 0.005)
    brake = active("brake_pressure", 50.0)
    lab[drive] = "acceleration"
    lab[brake] = "braking"
    lab[np.abs(speed) < STANDSTILL_SPEED] = "standstill"
    steer = (np.abs(bench.mean("steering_wheel_angle")) > STEER_ANGLE if "steering_wheel_angle" in bench.bands
             else np.zeros(n, bool))
    # phases: runs of equal labels (steering on top), short ones merged into the previous
    phase_lab = np.array([f"{x} + steering" if s else x for x, s in zip(lab, steer)], dtype=object)
    t = bench.t
    segs = []
    start = 0
    for i in range(1, n + 1):
        if i == n or phase_lab[i] != phase_lab[start]:
            segs.append([phase_lab[start], start, i])
            start = i
    merged: list[list] = []
    for s in segs:
        if merged and (t[min(s[2], n - 1)] - t[s[1]] < MIN_PHASE or merged[-1][0] == s[0]):
            merged[-1][2] = s[2]
        else:
            merged.append(s)
    phases = [Phase(k + 1, s[0], float(t[s[1]]), float(t[min(s[2], n - 1)])) for k, s in enumerate(merged)]
    return Regimes(lab, steer, speed, phases)


def excess(model: np.ndarray, bench: Benchmark, channel: str) -> np.ndarray:
    b = bench.bands[channel]
    r = np.abs(model - b.mean)
    return np.maximum(r - b.half, 0.0) if b.has_band else r


def locate(bench: Benchmark, outputs: dict, reg: Regimes) -> dict:
    """Per compared channel: outside share, excess shares by regime and phase, speed dependence."""
    res = {}
    t = bench.t
    for c in bench.compared:
        e = excess(outputs[c], bench, c)
        e2 = e * e
        tot = float(e2.sum())
        by_reg = {}
        for r in REGIMES:
            m = reg.labels == r
            if m.any():
                by_reg[r] = {"excess_share": float(e2[m].sum() / tot) if tot > 0 else 0.0,
                             "time_share": float(m.mean())}
        if reg.steering.any():
            by_reg["steering"] = {"excess_share": float(e2[reg.steering].sum() / tot) if tot > 0 else 0.0,
                                  "time_share": float(reg.steering.mean())}
        by_phase = []
        for p in reg.phases:
            m = (t >= p.start) & (t <= p.end)
            by_phase.append({"phase": p.label(), "excess_share": float(e2[m].sum() / tot) if tot > 0 else 0.0})
        moving = np.abs(reg.speed) >= STANDSTILL_SPEED
        r = np.abs(outputs[c] - bench.mean(c))
        corr = (float(np.corrcoef(r[moving], np.abs(reg.speed[moving]))[0, 1])
                if moving.sum() > 10 and np.std(r[moving]) > 0 and np.std(reg.speed[moving]) > 0 else 0.0)
        res[c] = {"outside_band": float(np.mean(e > 0)) if bench.bands[c].has_band else None,
                  "regimes": by_reg, "phases": by_phase,
                  "speed_weighted": float(np.sum(e2 * np.abs(reg.speed)) / tot) if tot > 0 else 0.0,
                  "speed_correlation": corr}
    return res


def describe(loc: dict, top: int = 3) -> list[str]:
    """One line per channel: where its excess concentrates."""
    lines = []
    for c, d in loc.items():
        regs = sorted(d["regimes"].items(), key=lambda kv: -kv[1]["excess_share"])
        if not regs or regs[0][1]["excess_share"] == 0.0:
            lines.append(f"{c}: inside the band everywhere")
            continue
        rs = ", ".join(f"{k} {100 * v['excess_share']:.0f} % (of {100 * v['time_share']:.0f} % time)"
                       for k, v in regs[:top] if v["excess_share"] > 0.005)
        ph = max(d["phases"], key=lambda p: p["excess_share"])
        out = f"{100 * d['outside_band']:.0f} % of samples outside the band; " if d["outside_band"] is not None else ""
        trend = ""
        if abs(d["speed_correlation"]) > 0.5:
            trend = f"; |residual| {'grows' if d['speed_correlation'] > 0 else 'shrinks'} with speed " \
                    f"(r = {d['speed_correlation']:.2f})"
        lines.append(f"{c}: {out}excess in {rs}; mostly {ph['phase']} ({100 * ph['excess_share']:.0f} %){trend}")
    return lines
