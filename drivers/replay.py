"""Replay of recorded inputs: a CSV table of time histories played back as open-loop profiles.

File format. Plain CSV (comma separated), one header row, then one row per sample:

    time,brake_pressure,throttle_angle,wheel_torque_rl,wheel_torque_rr
    0.000,2480.5,0.0,12.1,11.8
    0.002,2479.9,0.0,12.3,11.9
    ...

- `time` in s, strictly increasing (the seed's data logger samples at 500 Hz, but any increasing
  times are accepted);
- the input channels in their SI units (`drivers.base`), each named either as the command channel
  (`throttle_angle_cmd`, `brake_pressure_cmd`, `steering_wheel_angle_cmd`), as the sensor measuring it
  (`throttle_angle`, `brake_pressure`, `steering_wheel_angle`), or `wheel_torque_rl` /
  `wheel_torque_rr` for torque mode;
- other columns (the rest of a sensor recording) are ignored and need not be numeric;
- blank lines and lines starting with `#` are skipped.

Validation raises `ConfigError` naming the file, the column and the row (data row counted from 1
after the header, with the file line): a missing `time` or requested column, an empty or non-numeric
cell, NaN or infinity, a time that does not increase, a value outside the channel's range, fewer than
two samples.

Playback. `replay_profiles` resamples each used column once, at load, onto the integrator's grid
t = k dt (linear interpolation, or zero-order hold: the last sample at or before each grid time), and
returns `Uniform` profiles that the profile kernel evaluates in O(1). Recording time `start` (default:
the first sample) plays at scenario time 0; before it the first value and after the end the last
value are held.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtsim.configfile import note_read
from rtsim.errors import ConfigError

from .base import INPUT_INDEX, INPUT_UNITS, LIMITS, SENSOR_ALIASES, input_name
from .profiles import Uniform

#: Tolerance (fraction of a step) when deciding that a sample time is at or before a grid time.
GRID_EPS = 1e-6


@dataclass
class Recording:
    """A validated recording: the time vector and the numeric columns that were asked for."""
    path: Path
    time: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    header: tuple[str, ...] = ()

    @property
    def rate(self) -> float:
        """Median sampling rate, Hz."""
        return 1.0 / float(np.median(np.diff(self.time)))

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])

    def input_columns(self) -> dict[str, str]:
        """Input channel -> column name for every column of the header that feeds an input."""
        out: dict[str, str] = {}
        for col in self.header:
            ch = input_name(col)
            if ch is not None and ch not in out:
                out[ch] = col
        return out


def _column_for(path: Path, header: tuple[str, ...], channel: str) -> str:
    """The column that feeds `channel`: the channel's own name, else its sensor alias."""
    if channel in header:
        return channel
    for sensor, ch in SENSOR_ALIASES.items():
        if ch == channel and sensor in header:
            return sensor
    names = [channel] + [s for s, ch in SENSOR_ALIASES.items() if ch == channel]
    raise ConfigError(f"{path}: no column for input channel '{channel}' (looked for "
                      f"{' or '.join(repr(n) for n in names)}); columns present: {', '.join(header)}")


def read_csv_table(path: str | Path) -> tuple[tuple[str, ...], list[list[str]], list[int]]:
    """Header, data rows (as strings) and their file line numbers of a CSV file; blank lines and
    lines starting with '#' skipped. ConfigError if unreadable, headerless or with duplicate columns."""
    path = Path(path)
    note_read(path)
    try:
        fh = open(path, newline="")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot open ({exc.strerror})") from None
    with fh:
        reader = csv.reader(fh)
        header: tuple[str, ...] | None = None
        rows: list[list[str]] = []
        lines: list[int] = []
        try:
            for rec in reader:
                if not rec or all(not c.strip() for c in rec) or rec[0].lstrip().startswith("#"):
                    continue
                if header is None:
                    header = tuple(c.strip() for c in rec)
                    continue
                rows.append(rec)
                lines.append(reader.line_num)
        except (csv.Error, UnicodeDecodeError) as exc:
            raise ConfigError(f"{path}: line {reader.line_num}: not a readable CSV file ({exc})") from None
    if header is None:
        raise ConfigError(f"{path}: empty file (no header row)")
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise ConfigError(f"{path}: column {dup[0]!r} appears more than once in the header")
    return header, rows, lines


def parse_column(path: Path, header: tuple[str, ...], rows: list[list[str]], lines: list[int],
                 col: str) -> np.ndarray:
    """Column `col` as floats; ConfigError naming file, column and row for an empty, non-numeric or
    non-finite cell."""
    j = header.index(col)
    out = np.empty(len(rows))
    for i, rec in enumerate(rows):
        where = f"{path}: column {col!r}, row {i + 1} (line {lines[i]})"
        if j >= len(rec) or not rec[j].strip():
            raise ConfigError(f"{where}: empty value")
        try:
            x = float(rec[j])
        except ValueError:
            raise ConfigError(f"{where}: {rec[j].strip()!r} is not a number") from None
        if not math.isfinite(x):
            raise ConfigError(f"{where}: value {rec[j].strip()!r} is not finite")
        out[i] = x
    return out


def read_recording(path: str | Path, columns: list[str] | None = None,
                   channels: list[str] | None = None) -> Recording:
    """Read and validate a recorded input table.

    columns: column names to read (validated numeric and finite);
    channels: input channels to read, each from its own column or its sensor alias;
    neither: every column of the header that feeds an input channel.
    The returned `Recording.columns` is keyed by column name; `time` is always read.
    """
    path = Path(path)
    header, rows, lines = read_csv_table(path)
    if "time" not in header:
        raise ConfigError(f"{path}: no 'time' column (time in s); columns present: {', '.join(header)}")

    if columns is None and channels is None:
        wanted = list(dict.fromkeys(Recording(path, np.zeros(0), header=header).input_columns().values()))
        if not wanted:
            raise ConfigError(f"{path}: no input channel column (expected any of "
                              f"{', '.join(list(INPUT_INDEX) + list(SENSOR_ALIASES))}); "
                              f"columns present: {', '.join(header)}")
    else:
        wanted = list(columns or [])
        for ch in channels or []:
            if ch not in INPUT_INDEX:
                raise ConfigError(f"{path}: unknown input channel {ch!r}; allowed: {', '.join(INPUT_INDEX)}")
            wanted.append(_column_for(path, header, ch))
        for col in wanted:
            if col not in header:
                raise ConfigError(f"{path}: column {col!r} missing; columns present: {', '.join(header)}")
    wanted = [c for c in dict.fromkeys(wanted) if c != "time"]

    if len(rows) < 2:
        raise ConfigError(f"{path}: {len(rows)} data row(s); a recording needs at least 2 samples")

    time = parse_column(path, header, rows, lines, "time")
    bad = np.nonzero(np.diff(time) <= 0.0)[0]
    if bad.size:
        i = int(bad[0]) + 1
        raise ConfigError(f"{path}: column 'time', row {i + 1} (line {lines[i]}): time {time[i]!r} s does "
                          f"not increase (row {i}: {time[i - 1]!r} s); time must be strictly increasing")
    data = {}
    for col in wanted:
        vals = parse_column(path, header, rows, lines, col)
        ch = input_name(col)
        if ch is not None:
            lo, hi = LIMITS[ch]
            out = np.nonzero((vals < lo) | (vals > hi))[0]
            if out.size:
                i = int(out[0])
                raise ConfigError(f"{path}: column {col!r}, row {i + 1} (line {lines[i]}): value {vals[i]!r} "
                                  f"{INPUT_UNITS[ch]} is out of range for {ch} (allowed {lo:g} .. {hi:g} "
                                  f"{INPUT_UNITS[ch]})")
        data[col] = vals
    return Recording(path, time, data, header)


def resample(time: np.ndarray, values: np.ndarray, dt: float, start: float | None = None,
             hold: bool = False) -> tuple[float, np.ndarray]:
    """Resample a signal onto the grid start + k dt, k = 0..ceil((time[-1] - start)/dt).
    Returns (start, grid values). Linear interpolation, or zero-order hold (the last sample at or
    before each grid time); ends held."""
    if not dt > 0.0:
        raise ValueError(f"dt = {dt} must be > 0")
    start = float(time[0]) if start is None else float(start)
    n = max(int(math.ceil((time[-1] - start) / dt - GRID_EPS)), 0) + 1
    grid = start + dt * np.arange(n)
    if hold:
        idx = np.searchsorted(time, grid + GRID_EPS * dt, side="right") - 1
        vals = values[np.clip(idx, 0, time.size - 1)]
    else:
        vals = np.interp(grid, time, values)
    return start, vals


def replay_profiles(rec: Recording, dt: float, channels: dict[str, str] | None = None,
                    hold: bool = False, start: float | None = None) -> dict[str, Uniform]:
    """Uniform-grid profiles (scenario time 0 = recording time `start`) for the input channels.

    channels: input channel -> column name (default: every input column the recording holds).
    """
    if channels is None:
        channels = {ch: col for ch, col in rec.input_columns().items() if col in rec.columns}
    s = float(rec.time[0]) if start is None else float(start)
    out = {}
    for ch, col in channels.items():
        if col not in rec.columns:
            raise ConfigError(f"{rec.path}: column {col!r} (for {ch}) was not read")
        _, vals = resample(rec.time, rec.columns[col], dt, start=s, hold=hold)
        out[ch] = Uniform(0.0, dt, vals, hold=hold)
    return out
