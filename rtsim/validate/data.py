"""Loading and checking the repetitions of a manoeuvre: CSV files (column `time` in s, then any sensor
channels of rtsim.channels.SENSOR_NAMES in their SI units) or MCAP recordings of the service (topic
`rtsim/<vehicle_id>/sensors`, one JSON message per sample holding `time` and every sensor channel).

What is checked, and what happens (one-line messages naming the file, column and row):
- unreadable file, no `time` column, fewer than 10 samples, non-finite or non-increasing time:
  the run is rejected (left out) with the reason;
- NaN/inf or empty cells in a channel: gaps up to `MAX_GAP` s are filled by linear interpolation and
  counted in the run's notes; a channel with a longer gap is dropped from that run (noted);
- columns that are not sensor channels (state columns of `rtsim run`, anything else) are ignored
  (named once in the notes); wheel angles are unwrapped.

The accelerometer frame a logger writes (`accel_frame`: "body" or "level", see replay) may be declared
in a run: a comment line `# accel_frame: level` before a CSV's header, or an MCAP metadata record (any
name) with the key `accel_frame`. An unknown frame rejects the run; runs declaring different frames, or a
declaration that contradicts the frame asked for (`rtsim validate --accel-frame`), are an error
(`accel_frame`).
"""
from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtsim.channels import BY_NAME, COMMAND_NAMES, SENSOR_NAMES
from rtsim.errors import ConfigError

from .signals import WHEEL_ANGLES, unwrap_angle

#: Longest run of missing samples (s) filled by interpolation; longer gaps drop the channel.
MAX_GAP = 0.1
MIN_SAMPLES = 10
#: accelerometer frames a logger may declare (replay.ACCEL_FRAMES; kept here so loading needs no model)
ACCEL_FRAMES = ("body", "level")


class DataError(ConfigError):
    """A run cannot be used (the message names file, column, row and what is wrong)."""


@dataclass
class Run:
    """One repetition: time (s, strictly increasing) and sensor channels in SI units."""
    path: Path
    time: np.ndarray
    channels: dict[str, np.ndarray]
    notes: list[str] = field(default_factory=list)
    accel_frame: str | None = None     # the frame the run declares for its accelerations, None: undeclared

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def rate(self) -> float:
        """Median sampling rate, Hz."""
        return 1.0 / float(np.median(np.diff(self.time)))

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])


@dataclass
class Rejected:
    path: Path
    reason: str


# ---------------------------------------------------------------------------------------- reading
def _csv_declarations(text: str) -> dict[str, str]:
    """`# key: value` (or `# key = value`) comment lines before the header, lower-case keys."""
    out = {}
    for ln in text.splitlines():
        s = ln.strip()
        if not s:
            continue
        if not s.startswith("#"):
            break
        key, sep, value = s.lstrip("#").partition(":")
        if not sep:
            key, sep, value = s.lstrip("#").partition("=")
        if sep and key.strip():
            out[key.strip().lower()] = value.strip()
    return out


def _read_csv(path: Path) -> tuple[list[str], np.ndarray, dict[str, str]]:
    """Header, a float matrix (NaN where a cell is empty or not a number) and the declarations."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise DataError(f"{path}: empty file (no header row)")
    header = [c.strip() for c in next(csv.reader([lines[0]]))]
    dup = sorted({c for c in header if header.count(c) > 1})
    if dup:
        raise DataError(f"{path}: column {dup[0]!r} appears more than once in the header")
    body = "\n".join(lines[1:])
    ncol = len(header)
    try:                                   # fast path: a clean numeric table
        m = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2, dtype=float)
        if m.shape[1] != ncol and m.size:
            raise ValueError
    except ValueError:                     # slow path: cell by cell, bad cells become NaN
        rows = list(csv.reader(lines[1:]))
        m = np.full((len(rows), ncol), np.nan)
        for i, rec in enumerate(rows):
            for j in range(min(ncol, len(rec))):
                try:
                    m[i, j] = float(rec[j])
                except ValueError:
                    pass
    if m.size == 0:
        m = np.zeros((0, ncol))
    return header, m, _csv_declarations(text)


def _read_mcap(path: Path, sensor_names) -> tuple[list[str], np.ndarray]:
    """Header and matrix from the `rtsim/<id>/sensors` topic of an MCAP recording."""
    from bridge.mcap_recorder import read_recording     # the bridge reads MCAP; imported only when needed
    messages, info = read_recording(path)
    topics = [t for t in messages if t.startswith("rtsim/") and t.endswith("/sensors")]
    if not topics:
        raise DataError(f"{path}: no rtsim/<vehicle_id>/sensors topic (topics: {', '.join(messages) or 'none'})")
    if len(topics) > 1:
        raise DataError(f"{path}: several sensor topics ({', '.join(topics)}); one vehicle per recording")
    msgs = [m.data for m in messages[topics[0]] if isinstance(m.data, dict)]
    names = [n for n in sensor_names if any(n in d for d in msgs[:50])]
    header = ["time", *names]
    m = np.full((len(msgs), len(header)), np.nan)
    for i, d in enumerate(msgs):
        for j, n in enumerate(header):
            v = d.get(n)
            if isinstance(v, (int, float)):
                m[i, j] = float(v)
    if not info.complete:
        header.append("#incomplete")   # marker picked up by load_run's notes
    frames = {str(rec["accel_frame"]).strip() for rec in info.metadata.values() if "accel_frame" in rec}
    if len(frames) > 1:
        raise DataError(f"{path}: metadata declare several accelerometer frames ({', '.join(sorted(frames))})")
    if frames:
        header.append("#accel_frame=" + frames.pop())
    return header, m


def _fill_gaps(t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray | None, int, float]:
    """Fill non-finite samples by interpolation if no gap exceeds MAX_GAP; returns (filled or None,
    number of bad samples, longest gap in s)."""
    bad = ~np.isfinite(x)
    nbad = int(bad.sum())
    if nbad == 0:
        return x, 0, 0.0
    if nbad == x.size:
        return None, nbad, float(t[-1] - t[0])
    # longest gap: time between the good samples around each bad stretch
    good_idx = np.nonzero(~bad)[0]
    edges = np.concatenate([[t[0]], t[good_idx], [t[-1]]])
    gap = float(np.max(np.diff(edges)))
    if gap > MAX_GAP:
        return None, nbad, gap
    out = x.copy()
    out[bad] = np.interp(t[bad], t[~bad], x[~bad])
    return out, nbad, gap


def load_run(path: str | Path, sensor_names=SENSOR_NAMES) -> Run:
    """Read and check one run (see the module docstring) of a vehicle with the sensor channels
    `sensor_names` (its channel dictionary's); DataError if it cannot be used at all."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file")
    suffix = path.suffix.lower()
    declared = None
    if suffix == ".csv":
        header, m, decl = _read_csv(path)
        declared = decl.get("accel_frame")
    elif suffix == ".mcap":
        header, m = _read_mcap(path, sensor_names)
    else:
        raise DataError(f"{path}: unknown run format {path.suffix or '(none)'}; use .csv or .mcap")
    notes: list[str] = []
    if header and header[-1].startswith("#accel_frame="):
        declared = header.pop().partition("=")[2]
    if declared is not None and declared.lower() not in ACCEL_FRAMES:
        raise DataError(f"{path}: accel_frame {declared!r} is not an accelerometer frame (use one of "
                        f"{', '.join(ACCEL_FRAMES)})")
    if header and header[-1] == "#incomplete":
        header = header[:-1]
        notes.append("MCAP file was not closed (recovered complete chunks only)")
    if "time" not in header:
        raise DataError(f"{path}: no 'time' column (time in s); columns present: {', '.join(header)}")
    n = m.shape[0]
    if n < MIN_SAMPLES:
        raise DataError(f"{path}: {n} data row(s); a run needs at least {MIN_SAMPLES} samples")
    t = m[:, header.index("time")]
    bad = np.nonzero(~np.isfinite(t))[0]
    if bad.size:
        raise DataError(f"{path}: column 'time', row {bad[0] + 1}: not a finite number; time must be finite "
                        f"and strictly increasing")
    back = np.nonzero(np.diff(t) <= 0.0)[0]
    if back.size:
        i = int(back[0]) + 1
        raise DataError(f"{path}: column 'time', row {i + 1}: time {t[i]:.10g} s does not increase (row {i}: "
                        f"{t[i - 1]:.10g} s); time must be strictly increasing ({back.size} such row(s))")
    ignored = [c for c in header if c != "time" and c not in sensor_names and c not in COMMAND_NAMES]
    if ignored:
        notes.append(f"ignored {len(ignored)} non-sensor column(s): {', '.join(ignored[:6])}"
                     + (" ..." if len(ignored) > 6 else ""))
    channels: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        if name not in sensor_names:
            continue
        x, nbad, gap = _fill_gaps(t, m[:, j])
        if x is None:
            notes.append(f"channel {name} dropped: {nbad} missing/NaN sample(s), longest gap {gap:.3g} s "
                         f"(> {MAX_GAP} s)")
            continue
        if nbad:
            notes.append(f"channel {name}: {nbad} missing/NaN sample(s) filled by linear interpolation "
                         f"(longest gap {gap:.3g} s)")
        if name in WHEEL_ANGLES:
            x = unwrap_angle(x)
        channels[name] = x
    if not channels:
        raise DataError(f"{path}: no usable sensor channel (expected any of {', '.join(sensor_names)})")
    return Run(path, t, channels, notes, declared.lower() if declared is not None else None)


def load_runs(paths: list[str | Path], sensor_names=SENSOR_NAMES) -> tuple[list[Run], list[Rejected]]:
    """Every run that can be read, and the rejected ones with their reasons. Paths may be folders
    (their *.csv and *.mcap files, sorted by name); `sensor_names`: the vehicle's sensor channels."""
    files: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted([*p.glob("*.csv"), *p.glob("*.mcap")])
            if not found:
                raise DataError(f"{p}: folder holds no .csv or .mcap runs")
            files.extend(found)
        else:
            files.append(p)
    if not files:
        raise DataError("no runs given")
    runs, rejected = [], []
    for f in files:
        try:
            runs.append(load_run(f, sensor_names))
        except DataError as exc:
            rejected.append(Rejected(f, str(exc)))
    return runs, rejected


def accel_frame(runs: list[Run], asked: str | None = None) -> str:
    """The accelerometer frame of a set of runs: the one they declare, else `asked`, else "body".
    DataError when runs declare different frames, when some declare one and others none with nothing
    asked, or when the declaration contradicts `asked`."""
    if asked is not None and asked not in ACCEL_FRAMES:
        raise DataError(f"accelerometer frame {asked!r}: use one of {', '.join(ACCEL_FRAMES)}")
    by: dict[str | None, list[str]] = {}
    for r in runs:
        by.setdefault(r.accel_frame, []).append(r.name)

    def names(frame):
        f = by[frame]
        return ", ".join(f[:3]) + (f" and {len(f) - 3} more" if len(f) > 3 else "")
    declared = sorted(f for f in by if f is not None)
    if len(declared) > 1:
        raise DataError("the runs declare different accelerometer frames: " + "; ".join(
            f"{f} ({names(f)})" for f in declared) + "; one set of runs has one frame")
    if not declared:
        return asked or "body"
    frame = declared[0]
    if asked is not None and asked != frame:
        raise DataError(f"the runs declare accel_frame {frame} ({names(frame)}) but the {asked} frame was asked "
                        f"for (--accel-frame)")
    if None in by and asked is None:
        raise DataError(f"some runs declare accel_frame {frame} ({names(frame)}), others none ({names(None)}): "
                        f"declare it in every run or pass --accel-frame")
    return frame


def unit(channel: str) -> str:
    """SI unit of a sensor or derived channel."""
    if channel.startswith("wheel_speed_"):
        return "rad/s"
    return BY_NAME[channel].unit if channel in BY_NAME else ""
