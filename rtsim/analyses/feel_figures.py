"""Figures of the steering-feel report (rtsim.analyses.feel), PNG by matplotlib's Agg renderer:

    feel_torque_vs_ay.png   the steering-wheel torque (N m) against the lateral acceleration (g): the
                            loop of the analysed window over the whole run's trace, with the local
                            gradients' lines at 0 g and +-a
    feel_motor.png          the motor's current (A), voltage (V), electrical power V i and converted
                            mechanical power (W) against time (s), the analysed window shaded
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from .feel import TORQUE, Feel, mechanical_power
from .figures import DPI, G, SIZE


def write_feel_figures(columns, data, feel: Feel, out_dir: str | Path, title: str) -> list[Path]:
    """Write the two figures into `out_dir` (created if needed); returns the files written."""
    col = {c: np.asarray(data, dtype=float)[:, i] for i, c in enumerate(columns)}
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, draw in (("feel_torque_vs_ay", _loop), ("feel_motor", _motor)):
        fig = draw(col, feel, title)
        if fig is None:
            continue
        path = out_dir / f"{stem}.png"
        fig.savefig(path, dpi=DPI)
        written.append(path)
    return written


def _window(col, feel):
    t = col["time"]
    return (t >= feel.window_s[0]) & (t <= feel.window_s[1])


def _loop(col, feel: Feel, title: str) -> Figure:
    fig = Figure(figsize=(6.0, 5.0), layout="constrained")
    ax = fig.add_subplot()
    ay, trq = col["accel_y"] / G, col[TORQUE]
    sel = _window(col, feel)
    ax.plot(ay, trq, lw=0.6, color="0.75", label="whole run")
    ax.plot(ay[sel], trq[sel], lw=1.0, color="tab:blue", label="analysed window")
    for a, g in ((0.0, feel.torque_gradient_0g), (feel.at_g, feel.torque_gradient_at)):
        if not np.isfinite(g):
            continue
        for x0 in ((a, -a) if a > 0.0 else (a,)):
            near = sel & (np.abs(ay - x0) <= 0.02)
            if np.any(near):
                y0 = float(np.mean(trq[near]))
                xs = np.array([x0 - 0.04, x0 + 0.04])
                ax.plot(xs, y0 + g * (xs - x0), lw=1.4, color="tab:red")
    ax.axhline(0.0, lw=0.4, color="k")
    ax.axvline(0.0, lw=0.4, color="k")
    ax.set_xlabel("lateral acceleration [g]")
    ax.set_ylabel("steering-wheel torque [N m]")
    ax.grid(True, lw=0.4)
    ax.legend(loc="upper left", fontsize=8)
    hyst = "-" if feel.torque_hysteresis_nm is None else f"{feel.torque_hysteresis_nm:.2f} N m"
    fig.suptitle(f"{title}: {feel.torque_gradient_at:.1f} N m/g at {feel.at_g:g} g, "
                 f"{feel.torque_gradient_0g:.1f} at 0 g, hysteresis {hyst}", fontsize=10)
    return fig


def _motor(col, feel: Feel, title: str) -> Figure | None:
    have = [n for n in ("motor_current", "motor_voltage", "motor_power") if n in col]
    if not have:
        return None
    t = col["time"]
    fig = Figure(figsize=(SIZE[0], SIZE[1] * 1.6), layout="constrained")
    axes = fig.subplots(len(have), 1, sharex=True, squeeze=False)[:, 0]
    labels = {"motor_current": "current [A]", "motor_voltage": "voltage [V]", "motor_power": "power [W]"}
    for ax, name in zip(axes, have):
        ax.plot(t, col[name], lw=0.8, label="electrical V i" if name == "motor_power" else None)
        if name == "motor_power":
            p_mech = mechanical_power(col)
            if p_mech is not None:
                ax.plot(0.5 * (t[1:] + t[:-1]), p_mech, lw=0.8, label="mechanical Kt i w")
            ax.legend(loc="upper right", fontsize=8)
        ax.axvspan(*feel.window_s, color="0.92", zorder=0)
        ax.set_ylabel(labels[name])
        ax.grid(True, lw=0.4)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{title}: steering motor", fontsize=10)
    return fig
