"""Loading and checking the repetitions of a manoeuvre: CSV files (column `time` in s, then any sensor
channels of rtsim.channels.SENSOR_NAMES in their SI units) or MCAP recordings of the service (topic
`rtsim/<vehicle_id>/sensors`, one JSON message per sample holding `time` and every sensor channel).

Every run is checked before use; a run that fails is left out with one line naming it and the reason
(`Rejected.line`; the workflow prints it on stderr and writes it to summary.json and the report):
- unreadable file, unknown format, no `time` column, no sensor channel, fewer than `MIN_SAMPLES` samples;
- a column that appears twice in a CSV header, a row with more or fewer cells than the header;
- every value missing (NaN or empty);
- a cell of the time or a sensor channel that is not a number (text, inf): empty and `nan` cells are the
  only markers of a missing sample (a logger's dropout);
- time not finite, going backwards or repeating a stamp;
- a reading outside its channel's plausible range (rtsim.channels.PLAUSIBLE: a channel logged in another
  unit, e.g. degrees where radians are expected, Pa where kPa);
- no sensor channel left after the gaps (below).
Missing samples (NaN or empty cells) in a channel: gaps up to `MAX_GAP` s are filled by linear
interpolation and counted in the run's notes; a channel with a longer gap is dropped from that run
(noted). Columns that are not sensor channels (state columns of `rtsim run`, anything else) are ignored
(named once in the notes); wheel angles are unwrapped. The workflow stops unless at least `MIN_RUNS`
runs remain (`require_runs`; `rtsim validate --min-runs` lowers it).

The accelerometer frame a logger writes (`accel_frame`: "body" or "level", see replay) may be declared
in a run: a comment line `# accel_frame: level` before a CSV's header, or an MCAP metadata record (any
name) with the key `accel_frame`. An unknown frame rejects the run; runs declaring different frames, or a
declaration that contradicts the frame asked for (`rtsim validate --accel-frame`), are an error
(`accel_frame`).
"""
from __future__ import annotations

import csv
import io
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rtsim.channels import (BY_NAME, COMMAND_NAMES, PLAUSIBLE, SENSOR_NAMES, TWO_WHEELER_COMMANDS,
                            TWO_WHEELER_SENSORS)
from rtsim.errors import ConfigError

from .signals import WHEEL_ANGLES, unwrap_angle

#: Longest run of missing samples (s) filled by interpolation; longer gaps drop the channel.
MAX_GAP = 0.1
MIN_SAMPLES = 10
#: Runs needed to go on (a band of the mean from fewer runs is too wide to judge by; --min-runs lowers it)
MIN_RUNS = 3
#: Window (s) over which a cumulative channel's rate is taken for its plausibility check
RATE_WINDOW = 0.05
#: share of a channel's samples (at most; or 3) outside its plausible range read as spikes, not as another unit
SPIKE = 0.001
#: accelerometer frames a logger may declare (replay.ACCEL_FRAMES; kept here so loading needs no model)
ACCEL_FRAMES = ("body", "level")
#: cell texts that mark a missing sample (anything else that is not a finite number is junk)
MISSING = ("", "nan")


class DataError(ConfigError):
    """A run cannot be used (the message names file, column, row and what is wrong); `reason`: the same
    without the file."""

    def __init__(self, message: str, reason: str | None = None):
        super().__init__(message)
        self.reason = reason or message


def _fail(path: Path, reason: str) -> DataError:
    return DataError(f"{path}: {reason}", reason)


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
    """A run left out and why (`reason` without the file's name)."""
    path: Path
    reason: str

    @property
    def line(self) -> str:
        """The one line the terminal, summary.json and the report show: "<file name>: <reason>"."""
        return f"{self.path.name}: {self.reason}"


# ---------------------------------------------------------------------------------------- reading
@dataclass
class _Table:
    """What a file holds: column names, a float matrix (NaN where a sample is missing or junk), the cells
    that are neither a number nor a missing marker (row index, column index, text), the declarations and
    what a row is called in messages."""
    header: list[str]
    m: np.ndarray
    junk: list[tuple[int, int, str]]
    declared: dict[str, str]
    row: str = "row"
    incomplete: bool = False


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


def _read_csv(path: Path) -> _Table:
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise _fail(path, f"cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise _fail(path, "empty file (no header row)")
    header = [c.strip() for c in next(csv.reader([lines[0]]))]
    for name in dict.fromkeys(header):
        where = [j + 1 for j, c in enumerate(header) if c == name]
        if len(where) > 1:
            raise _fail(path, f"column {name!r} appears {len(where)} times in the header (columns "
                              f"{', '.join(map(str, where))}): which one holds the channel cannot be told")
    ncol = len(header)
    junk: list[tuple[int, int, str]] = []
    try:                                   # fast path: a clean numeric table
        m = np.loadtxt(io.StringIO("\n".join(lines[1:])), delimiter=",", ndmin=2, dtype=float)
        if m.size and m.shape[1] != ncol:
            raise ValueError
    except ValueError:                     # slow path: cell by cell
        rows = list(csv.reader(lines[1:]))
        m = np.full((len(rows), ncol), np.nan)
        for i, rec in enumerate(rows):
            if len(rec) != ncol:
                raise _fail(path, f"row {i + 1} has {len(rec)} cells, the header {ncol}: a cell holding the "
                                  f"separator ',' or a truncated line shifts the columns")
            for j, cell in enumerate(rec):
                try:
                    m[i, j] = float(cell)
                except ValueError:
                    if cell.strip().lower() not in MISSING:
                        junk.append((i, j, cell.strip()))
    if m.size == 0:
        m = np.zeros((0, ncol))
    return _Table(header, m, junk, _csv_declarations(text))


def _read_mcap(path: Path, sensor_names, read_recording) -> _Table:
    """The `rtsim/<id>/sensors` topic of an MCAP recording as a table (a row per message); `read_recording`:
    path -> (messages by topic, info), bridge.mcap_recorder.read_recording (the bridge reads MCAP, a layer
    above this one: the command passes its reader in)."""
    if read_recording is None:
        raise _fail(path, "no MCAP reader was given (the rtsim validate command passes the bridge's); "
                          "give the run as CSV")
    messages, info = read_recording(path)
    topics = [t for t in messages if t.startswith("rtsim/") and t.endswith("/sensors")]
    if not topics:
        raise _fail(path, f"no rtsim/<vehicle_id>/sensors topic (topics: {', '.join(messages) or 'none'})")
    if len(topics) > 1:
        raise _fail(path, f"several sensor topics ({', '.join(topics)}); one vehicle per recording")
    msgs = [m.data for m in messages[topics[0]] if isinstance(m.data, dict)]
    names = [n for n in sensor_names if any(n in d for d in msgs[:50])]
    header = ["time", *names]
    m = np.full((len(msgs), len(header)), np.nan)
    junk = []
    for i, d in enumerate(msgs):
        for j, n in enumerate(header):
            v = d.get(n)
            if isinstance(v, (int, float)):
                m[i, j] = float(v)
            elif v is not None:
                junk.append((i, j, repr(v)))
    frames = {str(rec["accel_frame"]).strip() for rec in info.metadata.values() if "accel_frame" in rec}
    if len(frames) > 1:
        raise _fail(path, f"metadata declare several accelerometer frames ({', '.join(sorted(frames))})")
    declared = {"accel_frame": frames.pop()} if frames else {}
    return _Table(header, m, junk, declared, "message", not info.complete)


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


def _check_time(t: np.ndarray, row: str) -> str | None:
    """Why a time column cannot be used (not finite, backwards, a repeated stamp), None when it can."""
    bad = np.nonzero(~np.isfinite(t))[0]
    if bad.size:
        return (f"column 'time', {row} {bad[0] + 1}: not a finite number ({bad.size} such {row}(s)); time must "
                f"be finite and strictly increasing")
    d = np.diff(t)
    back, same = np.nonzero(d < 0.0)[0], np.nonzero(d == 0.0)[0]
    if back.size and (not same.size or back[0] < same[0]):
        i = int(back[0]) + 1
        return (f"time goes backwards at {row} {i + 1}: {t[i]:.10g} s after {t[i - 1]:.10g} s ({back.size} such "
                f"{row}(s){f', and {same.size} repeated stamp(s)' if same.size else ''}); time must be strictly "
                f"increasing")
    if same.size:
        i = int(same[0]) + 1
        return (f"time stamp {t[i]:.10g} s repeated at {row} {i + 1} ({same.size} repeated stamp(s)"
                f"{f', and {back.size} going backwards' if back.size else ''}); time must be strictly increasing")
    return None


def _check_range(name: str, t: np.ndarray, x: np.ndarray, row: str) -> str | None:
    """Why a channel's reading is implausible for its unit (rtsim.channels.PLAUSIBLE), None when it is not
    (or the channel declares no range)."""
    p = PLAUSIBLE.get(name)
    if p is None or x.size < 2:
        return None
    u = unit(name)
    if p.rate:
        k = max(1, int(round(RATE_WINDOW / float(np.median(np.diff(t))))))
        k = min(k, x.size - 1)
        v = (x[k:] - x[:-k]) / (t[k:] - t[:-k])
        u = f"{u}/s"
    else:
        v = x
    out = (v < p.lo) | (v > p.hi)
    if not out.any():
        return None
    first = int(np.argmax(out))
    worst = float(v[int(np.argmax(np.where(out, np.abs(v), -np.inf)))])
    what = "changes at up to" if p.rate else "reads up to"
    k = int(out.sum())
    hint = ("a spike or junk values in the log?" if k <= max(3, SPIKE * v.size) else
            f"logged in {p.other_unit} instead of {unit(name)}?")
    return (f"column {name!r} {what} {worst:.4g} {u} ({k} of {v.size} samples outside its plausible "
            f"range {p.lo:g} .. {p.hi:g} {u}, the first at {row} {first + 1}): {hint}")


def load_run(path: str | Path, sensor_names=SENSOR_NAMES, read_mcap=None) -> Run:
    """Read and check one run (see the module docstring) of a vehicle with the sensor channels
    `sensor_names` (its channel dictionary's); DataError naming the file and the reason if it cannot be used.
    `read_mcap`: how an MCAP recording is read (bridge.mcap_recorder.read_recording; None: MCAP runs are
    left out, saying so)."""
    path = Path(path)
    if not path.is_file():
        raise _fail(path, "no such file")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        tab = _read_csv(path)
    elif suffix == ".mcap":
        tab = _read_mcap(path, sensor_names, read_mcap)
    else:
        raise _fail(path, f"unknown run format {path.suffix or '(none)'}; use .csv or .mcap")
    header, m, row = tab.header, tab.m, tab.row
    declared = tab.declared.get("accel_frame")
    if declared is not None and declared.lower() not in ACCEL_FRAMES:
        raise _fail(path, f"accel_frame {declared!r} is not an accelerometer frame (use one of "
                          f"{', '.join(ACCEL_FRAMES)})")
    notes: list[str] = []
    if tab.incomplete:
        notes.append("MCAP file was not closed (recovered complete chunks only)")
    if "time" not in header:
        raise _fail(path, f"no 'time' column (time in s); columns present: {', '.join(header)}")
    used = [j for j, c in enumerate(header) if c in sensor_names]
    if not used:
        raise _fail(path, f"no sensor channel (expected any of {', '.join(sensor_names)}); columns present: "
                          f"{', '.join(header)}")
    n = m.shape[0]
    if n < MIN_SAMPLES:
        raise _fail(path, f"{n} data {row}(s); a run needs at least {MIN_SAMPLES} samples")
    jt = header.index("time")
    cols = [jt, *used]
    if not np.isfinite(m[:, cols]).any() and not any(j in cols for _, j, _ in tab.junk):
        raise _fail(path, f"every value is missing (NaN or empty): {n} {row}s of time and {len(used)} sensor "
                          f"channel(s)")
    junk = [(i, j, s) for i, j, s in tab.junk if j in cols]
    junk += [(int(i), int(j), format(m[i, j])) for i, j in zip(*np.nonzero(np.isinf(m))) if j in cols]
    if junk:
        i, j, s = min(junk)
        ncols = len({jj for _, jj, _ in junk})
        raise _fail(path, f"column {header[j]!r}, {row} {i + 1}: {s!r} is not a finite number ({len(junk)} such "
                          f"cell(s) in {ncols} column(s)); a sample is a number, or empty or nan when missing")
    t = m[:, jt]
    why = _check_time(t, row)
    if why:
        raise _fail(path, why)
    ignored = [c for c in header if c != "time" and c not in sensor_names and c not in COMMAND_NAMES]
    if ignored:
        notes.append(f"ignored {len(ignored)} non-sensor column(s): {', '.join(ignored[:6])}"
                     + (" ..." if len(ignored) > 6 else ""))
    channels: dict[str, np.ndarray] = {}
    for j in used:
        name = header[j]
        raw = m[:, j]
        ok = np.isfinite(raw)
        if ok.sum() >= 2:
            seen = raw[ok]
            if name in WHEEL_ANGLES and np.ptp(seen) <= 2.0 * np.pi + 0.1:     # a logger wrapping at one turn
                seen = unwrap_angle(seen)
            why = _check_range(name, t[ok], seen, row)
            if why:
                raise _fail(path, why)
        x, nbad, gap = _fill_gaps(t, raw)
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
        raise _fail(path, "no usable sensor channel: every one has a gap of missing samples longer than "
                          f"{MAX_GAP} s ({'; '.join(notes)})")
    return Run(path, t, channels, notes, declared.lower() if declared is not None else None)


def load_runs(paths: list[str | Path], sensor_names=SENSOR_NAMES, read_mcap=None) -> tuple[list[Run], list[Rejected]]:
    """Every run that can be read, and the rejected ones with their reasons. Paths may be folders
    (their *.csv and *.mcap files, sorted by name); `sensor_names`: the vehicle's sensor channels;
    `read_mcap`: the MCAP reader (load_run).
    DataError when a path does not exist or a folder holds no run."""
    files: list[Path] = []
    for p in map(Path, paths):
        if not p.exists():                 # a path mistyped on the command line: no run to leave out
            raise DataError(f"{p}: no such file or folder")
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
            runs.append(load_run(f, sensor_names, read_mcap))
        except DataError as exc:
            rejected.append(Rejected(f, exc.reason))
    return runs, rejected


def announce(rejected: list[Rejected], stream=None) -> None:
    """One line on stderr (or `stream`) for every run left out, naming it and the reason."""
    for r in rejected:
        print(f"rtsim validate: run left out: {r.line}", file=stream or sys.stderr)


def require_runs(used: list, rejected: list[Rejected], min_runs: int = MIN_RUNS) -> None:
    """DataError (one line) unless at least `min_runs` runs are usable."""
    if min_runs < 1:
        raise DataError(f"--min-runs {min_runs}: at least 1 run is needed")
    if len(used) >= min_runs:
        return
    total = len(used) + len(rejected)
    out = ("; left out: " + ", ".join(r.path.name for r in rejected)) if rejected else ""
    err = DataError(f"{len(used)} usable run(s) of {total}, at least {min_runs} needed (--min-runs N lowers "
                    f"this){out}")
    err.runs = {"used": [r.name for r in used], "left_out": [{"run": r.path.name, "reason": r.reason}
                                                             for r in rejected], "min_runs": min_runs}
    raise err


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
    """SI unit of a sensor or derived channel (a car's or a two-wheeler's)."""
    if channel.startswith("wheel_speed_"):
        return "rad/s"
    if channel in BY_NAME:
        return BY_NAME[channel].unit
    return next((c.unit for c in TWO_WHEELER_SENSORS + TWO_WHEELER_COMMANDS if c.name == channel), "")
