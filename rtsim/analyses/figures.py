"""Figures of a run, after Figure 7 of the bond-graph vehicle study: (a) the lateral acceleration in g,
(b) the four vertical tyre forces in N, and (c) the steering: steering-wheel angle in deg and
steering-column torque in N m, each against time in s. PNG files drawn by matplotlib's Agg renderer
(headless: no display and no pyplot state). A figure is drawn from the columns the run has and left
out when it has none of them.

The table is an offline run's (rtsim.vehicle.offline.RunResult: columns and data) or a recording's,
read from CSV or MCAP by bridge.run_files.read_recorded (the outside world's formats are the bridge's).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from rtsim.errors import ConfigError
from rtsim.mbs.model import EARTH_GRAVITY

G = EARTH_GRAVITY           # m/s^2 per g
DPI = 100
SIZE = (8.0, 4.5)           # in
WHEELS = {"fl": "front left", "fr": "front right", "rl": "rear left", "rr": "rear right"}

#: file stem -> the columns it draws (any of them suffices)
FIGURES = {
    "lateral_acceleration": ("accel_y",),
    "tyre_vertical_forces": tuple(f"tyre_fz_{w}" for w in WHEELS),
    "steering": ("steering_wheel_angle", "steering_torque"),
}


def default_dir(path: str | Path) -> Path:
    """`<stem>_plots/` beside a run's output or recording file."""
    path = Path(path)
    return path.with_name(f"{path.stem}_plots")


def write_run_figures(columns: tuple[str, ...], data: np.ndarray, out_dir: str | Path, title: str) -> list[Path]:
    """Write the figures of a run (`columns`: its column names, `time` in s among them; `data`: its
    (n, len(columns)) values in SI units) into `out_dir` (created if needed) as PNG, each titled with
    `title`; returns the files written, in the order (a), (b), (c)."""
    columns = tuple(columns)
    data = np.asarray(data, dtype=float)
    if data.ndim != 2 or data.shape[1] != len(columns):
        raise ValueError(f"data of shape {data.shape} does not match {len(columns)} columns")
    if "time" not in columns:
        raise ConfigError(f"{title}: no time column (columns: {', '.join(columns) or 'none'})")
    col = {c: data[:, i] for i, c in enumerate(columns)}
    t = col["time"]
    out_dir = Path(out_dir)
    written = []
    for stem, names in FIGURES.items():
        have = [n for n in names if n in col]
        if not have:
            continue
        fig = _DRAW[stem](t, col, have, title)
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / f"{stem}.png"
        fig.savefig(path, dpi=DPI)
        written.append(path)
    return written


def _lateral(t, col, _have, title) -> Figure:
    fig = Figure(figsize=SIZE, layout="constrained")
    ax = fig.add_subplot()
    ax.plot(t, col["accel_y"] / G, lw=1.0)
    _finish(ax, "lateral acceleration [g]")
    fig.suptitle(f"{title}: lateral acceleration")
    return fig


def _tyre_forces(t, col, have, title) -> Figure:
    fig = Figure(figsize=SIZE, layout="constrained")
    ax = fig.add_subplot()
    for name in have:
        ax.plot(t, col[name], lw=1.0, label=WHEELS[name.rsplit("_", 1)[1]])
    _finish(ax, "vertical tyre force [N]")
    ax.legend(loc="best", fontsize=8)
    fig.suptitle(f"{title}: vertical tyre forces")
    return fig


def _steering(t, col, have, title) -> Figure:
    fig = Figure(figsize=(SIZE[0], SIZE[1] * (1.0 if len(have) == 1 else 1.4)), layout="constrained")
    axes = fig.subplots(len(have), 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, have):
        if name == "steering_wheel_angle":
            ax.plot(t, np.degrees(col[name]), lw=1.0)
            ax.set_ylabel("steering-wheel angle [deg]")
        else:
            ax.plot(t, col[name], lw=1.0, color="tab:red")
            ax.set_ylabel("steering torque [N m]")
        ax.grid(True, lw=0.4)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"{title}: steering")
    return fig


def _finish(ax, ylabel: str) -> None:
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.grid(True, lw=0.4)


_DRAW = {"lateral_acceleration": _lateral, "tyre_vertical_forces": _tyre_forces, "steering": _steering}
