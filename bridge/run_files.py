"""A recorded run read back, from a CSV file (a header row of column names, as `rtsim run` writes it) or
an MCAP recording (bridge.mcap_log): the whole table for figures and the steering feel
(``read_recorded``), the power audit's channels for `rtsim energy` (``read_energy``). The analyses
and the vehicle take the arrays; reading the outside world's files is the bridge's."""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from rtsim.channels import ENERGY
from rtsim.errors import ConfigError

from .mcap_log import read_messages, read_run

ENERGY_NAMES = tuple(c.name for c in ENERGY)


def read_recorded(path: str | Path) -> tuple[tuple[str, ...], np.ndarray]:
    """Columns and (n, ncol) values of a recorded run: CSV with a header row (as `rtsim run` writes;
    empty or non-numeric cells become NaN) or MCAP (bridge.mcap_log.read_run). ConfigError otherwise."""
    path = Path(path)
    kind = path.suffix.lower()
    if kind == ".mcap":
        return read_run(path)
    if kind != ".csv":
        raise ConfigError(f"{path}: unknown run format {path.suffix or '(none)'}; use .csv or .mcap")
    try:
        with path.open(newline="") as fh:
            rows = [r for r in csv.reader(fh) if r]
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    if not rows:
        raise ConfigError(f"{path}: empty file (no header row)")
    columns = tuple(c.strip() for c in rows[0])
    if all(len(r) == len(columns) for r in rows[1:]):
        try:                               # a clean numeric table
            return columns, np.array(rows[1:], dtype=float).reshape(-1, len(columns))
        except ValueError:
            pass
    data = [[_number(r[j]) if j < len(r) else math.nan for j in range(len(columns))] for r in rows[1:]]
    return columns, np.array(data, dtype=float).reshape(-1, len(columns))


def _number(cell: str) -> float:
    try:
        return float(cell)
    except ValueError:
        return math.nan


def read_energy(path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The power audit of a recorded run: time (s) and the ENERGY channels, from an MCAP file's
    ``energy`` topic or a CSV's columns. Raises ValueError when the run has no audit."""
    path = Path(path)
    if path.suffix.lower() == ".csv":
        with path.open(newline="") as fh:
            rows = list(csv.reader(fh))
        head, body = rows[0], np.array(rows[1:], dtype=float)
        if "time" not in head or not set(ENERGY_NAMES) <= set(head):
            raise ValueError(f"{path}: no power audit columns (work_*, stored_*) in this CSV")
        return body[:, head.index("time")], {n: body[:, head.index(n)] for n in ENERGY_NAMES}
    msgs = [m for _t, m in read_messages(path, _energy_topic(path))]
    if not msgs:
        raise ValueError(f"{path}: no power audit (topic rtsim/<vehicle>/energy) in this recording")
    return (np.array([m["time"] for m in msgs]),
            {n: np.array([m.get(n, np.nan) for m in msgs]) for n in ENERGY_NAMES})


def _energy_topic(path) -> str:
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    topics = [c.topic for c in (summary.channels.values() if summary else []) if c.topic.endswith("/energy")]
    return topics[0] if topics else "rtsim/energy"
