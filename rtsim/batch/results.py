"""The results of a batch: a CSV journal that gets each row as it arrives (flushed and synced, so an
interrupted batch keeps every finished run), read back on resume to skip the run ids it holds; at the end
the table sorted by run id, as Parquet (pyarrow) and CSV. Floats are written with repr: a row read back
is bit for bit the row computed."""
from __future__ import annotations

import csv
import math
import os
from pathlib import Path

from rtsim.errors import ConfigError

TEXT = ("run_id", "scenario", "vehicle", "status", "verdict", "failed", "error", "worker")
INTS = ("case", "seed")
#: columns that depend on where and when a run ran, not on what it computed
VOLATILE = ("wall_s", "worker")


def _cell(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, dict, bool)):
        import json
        return json.dumps(v)
    return str(v)


def _parse(name: str, s: str):
    if name in TEXT:
        return s
    if name in INTS:
        return int(s)
    if s == "":
        return None
    try:
        return float(s)
    except ValueError:
        return s


class Journal:
    """Append-only CSV of result rows with a fixed header (the plan's columns)."""

    def __init__(self, path: Path, columns: list[str]):
        self.path, self.columns = Path(path), list(columns)
        self.rows: dict[str, dict] = {}
        if self.path.exists() and self.path.stat().st_size > 0:
            self._read()
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with self.path.open("w", newline="") as fh:
                csv.writer(fh).writerow(self.columns)
        self._fh = self.path.open("a", newline="")
        self._w = csv.writer(self._fh)

    def _read(self) -> None:
        with self.path.open(newline="") as fh:
            text = fh.read()
        lines = list(csv.reader(text.splitlines()))
        if lines[0] != self.columns:
            raise ConfigError(f"{self.path}: the journal's columns differ from this plan's (a different plan?); "
                              "move it away or give another --out")
        if not text.endswith("\n"):          # a row cut off by an interruption: dropped, its run redone
            lines = lines[:-1]
            with self.path.open("w", newline="") as fh:
                w = csv.writer(fh)
                w.writerows(lines)
        for cells in lines[1:]:
            if len(cells) == len(self.columns):
                row = {c: _parse(c, s) for c, s in zip(self.columns, cells)}
                self.rows[row["run_id"]] = row

    def append(self, row: dict) -> None:
        self._w.writerow([_cell(row.get(c)) for c in self.columns])
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self.rows[row["run_id"]] = {c: _parse(c, _cell(row.get(c))) for c in self.columns}

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
            arrays[c] = pa.array(["" if v is None else str(v) for v in vals], pa.string())
        elif c in INTS:
            arrays[c] = pa.array(vals, pa.int64())
        elif all(v is None or isinstance(v, (int, float)) for v in vals):
            arrays[c] = pa.array([math.nan if v is None else float(v) for v in vals], pa.float64())
        else:
            arrays[c] = pa.array([_cell(v) for v in vals], pa.string())
    pq.write_table(pa.table(arrays), out / "results.parquet")
    with (out / "results.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow([_cell(r.get(c)) for c in columns])
    return out / "results.parquet", out / "results.csv"
