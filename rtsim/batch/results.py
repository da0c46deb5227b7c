"""The results of a batch: a journal that gets each row as it arrives (flushed and synced, so an
interrupted batch keeps every finished run), read back on resume to skip the run ids it holds; at the end
the table sorted by run id, as Parquet (pyarrow) and CSV.

The journal is JSON lines (journal.jsonl): a first line naming the columns, then one JSON object per
row. JSON escapes every character a text may hold (line breaks, tabs, quotes, any unicode, even lone
surrogates) and writes floats with repr (NaN and infinities as JSON's NaN / Infinity tokens), so a row
read back is the row computed, bit for bit and character for character; a line cut off by an
interruption does not parse and is dropped (its run is done again)."""
from __future__ import annotations

import csv
import json
import math
import os
from pathlib import Path

from rtsim.errors import ConfigError

TEXT = ("run_id", "scenario", "vehicle", "status", "verdict", "failed", "error", "worker", "copy_of")
INTS = ("case", "seed")
#: columns that depend on where and when a run ran, not on what it computed
VOLATILE = ("wall_s", "step_s", "outside_s", "outside_pct", "between_s", "worker")


def _cell(v) -> str:
    """A value as the CSV table writes it."""
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, dict, bool)):
        return json.dumps(v)
    return str(v)


def _text(v) -> str:
    """A text cell: lone surrogates (undecodable bytes of a file name) as backslash escapes, so that
    every table format can hold it."""
    s = "" if v is None else str(v)
    return s.encode("utf-8", "backslashreplace").decode("utf-8")


def _json(v):
    """A value as the journal stores it (tuples become lists, numpy scalars Python numbers)."""
    if isinstance(v, (list, tuple)):
        return [_json(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _json(x) for k, x in v.items()}
    if isinstance(v, (str, bool, int, float)) or v is None:
        return v
    if hasattr(v, "item"):                  # a numpy scalar
        return v.item()
    return str(v)


class Journal:
    """Append-only JSON lines of result rows with a fixed set of columns (the plan's)."""

    def __init__(self, path: Path, columns: list[str]):
        self.path, self.columns = Path(path), list(columns)
        self.rows: dict[str, dict] = {}
        if self.path.exists() and self.path.stat().st_size > 0:
            self._read()
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self.path.open("w", encoding="ascii") as fh:
                fh.write(json.dumps({"columns": self.columns}) + "\n")
        self._fh = self.path.open("a", encoding="ascii")

    def _read(self) -> None:
        with self.path.open("rb") as fh:
            data = fh.read()
        lines = data.split(b"\n")
        try:
            head = json.loads(lines[0])["columns"]
        except (ValueError, KeyError, TypeError):
            head = None
        if head != self.columns:
            raise ConfigError(f"{self.path}: the journal's columns differ from this plan's (a different plan?); "
                              "move it away or give another --out")
        complete = lines[:-1]                # the part after the last line break: cut off (or empty)
        kept = [complete[0]]
        for line in complete[1:]:
            try:
                row = json.loads(line)
            except ValueError:
                continue                     # not a whole row: dropped, its run done again
            if isinstance(row, dict) and "run_id" in row:
                self.rows[row["run_id"]] = {c: row.get(c) for c in self.columns}
                kept.append(line)
        if len(kept) != len(lines) - 1 or lines[-1]:
            with self.path.open("wb") as fh:
                fh.write(b"".join(line + b"\n" for line in kept))

    def append(self, row: dict) -> None:
        stored = {c: _json(row.get(c)) for c in self.columns}
        self._fh.write(json.dumps(stored) + "\n")
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.rows[stored["run_id"]] = json.loads(json.dumps(stored))

    def close(self) -> None:
        self._fh.close()


def sorted_rows(rows: dict[str, dict], ids: list[str] | None = None) -> list[dict]:
    """The rows of `ids` (default all), sorted by run id."""
    keep = rows if ids is None else {i: rows[i] for i in ids if i in rows}
    return [keep[k] for k in sorted(keep)]


def write_tables(rows: list[dict], columns: list[str], out: Path) -> tuple[Path, Path]:
    """results.parquet and results.csv in `out`."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    arrays = {}
    for c in columns:
        vals = [r.get(c) for r in rows]
        if c in TEXT:
            arrays[c] = pa.array([_text(v) for v in vals], pa.string())
        elif c in INTS:
            arrays[c] = pa.array(vals, pa.int64())
        elif all(v is None or isinstance(v, (int, float)) for v in vals):
            arrays[c] = pa.array([math.nan if v is None else float(v) for v in vals], pa.float64())
        else:
            arrays[c] = pa.array([_text(_cell(v)) for v in vals], pa.string())
    pq.write_table(pa.table(arrays), out / "results.parquet")
    with (out / "results.csv").open("w", newline="", encoding="utf-8", errors="backslashreplace") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow([_text(_cell(r.get(c))) for c in columns])
    return out / "results.parquet", out / "results.csv"
