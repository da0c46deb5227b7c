"""The signals of a case, read from its session recording (MCAP), each as simulated times and values:

- ``sensors.<channel>``: every sensor sample as the ECU saw it (faulted values included), stamped by sample;
- ``state.<channel>``: the vehicle's state channels (100 Hz);
- ``commands.<channel>``: the commands the simulator applied (after its watchdog: safe values included);
- ``ecu.<FRAME>.<signal>``: the ECU's own frames as the simulator received them (topic ``can/rx``), decoded
  with the session's DBC (recorded in the file); a frame that does not decode is counted, not used;
- ``fault.<id>``: 0 before the fault's onset, 1 from it until its end (topic ``faults``);
- ``sim.<FRAME>.<signal>``: the simulator's status frames as sent (``SIM_STATUS``: the watchdog's time-out
  flags ``fault_brake_timeout`` ..., ``SIM_DIAG``; topic ``can/tx``), decoded with the DBC, every 100 ms.

Times are the recorded simulation stamps (s), never wall-clock times."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

STATUS_FRAMES = ("SIM_STATUS", "SIM_DIAG")     # the simulator's frames decoded as ``sim.*`` signals


@dataclass
class Signals:
    """name -> (times s, values) arrays; ``fault_events`` the recorded onsets and ends as (time, id, event);
    ``end`` the last simulated time recorded; ``undecoded`` frames that did not decode."""
    series: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    fault_events: list[tuple[float, str, str]] = field(default_factory=list)
    end: float = 0.0
    undecoded: int = 0

    def get(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """The signal's (times, values); KeyError naming a few of the known signals otherwise."""
        try:
            return self.series[name]
        except KeyError:
            head = name.split(".", 1)[0] + "."
            near = sorted(n for n in self.series if n.startswith(head))[:8]
            raise KeyError(f"no signal {name!r} in the recording (e.g. {', '.join(near) or 'none of that kind'})") \
                from None


def _columns(rows: list[dict], stamp: str = "time") -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per key of the rows, the (stamps, values) of the rows carrying a number for it."""
    acc: dict[str, tuple[list, list]] = {}
    for r in rows:
        t = r.get(stamp)
        if not isinstance(t, (int, float)):
            continue
        for k, v in r.items():
            if k != stamp and isinstance(v, (int, float)):
                ts, vs = acc.setdefault(k, ([], []))
                ts.append(float(t))
                vs.append(float(v))
    return {k: (np.asarray(ts), np.asarray(vs)) for k, (ts, vs) in acc.items()}


def _frames(rows: list[dict], db, prefix: str, names, out: Signals) -> None:
    """The frames of ``rows`` (recorded CAN frames) whose DBC name is in ``names`` (None: any), decoded
    into ``<prefix>.<FRAME>.<signal>`` series."""
    acc: dict[str, tuple[list, list]] = {}
    for r in rows:
        try:
            msg = db.get_message_by_frame_id(int(r["id"]))
        except KeyError:
            continue                                  # not a frame of the DBC
        if names is not None and msg.name not in names:
            continue
        try:
            decoded = msg.decode(bytes.fromhex(r["data"]), decode_choices=False)
        except Exception:  # noqa: BLE001  (a corrupt frame: counted, not used)
            out.undecoded += 1
            continue
        for sig, v in decoded.items():
            ts, vs = acc.setdefault(f"{prefix}.{msg.name}.{sig}", ([], []))
            ts.append(float(r["time"]))
            vs.append(float(v))
    out.series.update({k: (np.asarray(ts), np.asarray(vs)) for k, (ts, vs) in acc.items()})


def read_signals(path: str | Path) -> Signals:
    """Every signal of the recording at ``path`` (module docstring)."""
    from bridge.mcap_recorder import read_topics

    import cantools

    wanted = ("sensors", "state", "commands", "can/rx", "can/tx", "faults")
    data, info = read_topics(path, lambda t: t.split("/", 2)[-1] in wanted)
    rows = {topic.split("/", 2)[-1]: [json.loads(b) for b in td.data] for topic, td in data.items()}
    out = Signals()
    for kind in ("sensors", "state", "commands"):
        for k, s in _columns(rows.get(kind, [])).items():
            out.series[f"{kind}.{k}"] = s
    dbc = info.metadata.get("rtsim.dbc", {}).get("text")
    if dbc:
        db = cantools.database.load_string(dbc, database_format="dbc", strict=False)
        _frames(rows.get("can/rx", []), db, "ecu", None, out)
        _frames(rows.get("can/tx", []), db, "sim", STATUS_FRAMES, out)
    ends = [s[0][-1] for s in out.series.values() if len(s[0])]
    out.end = max(ends) if ends else 0.0
    events = sorted((float(r["time"]), str(r["id"]), str(r["event"])) for r in rows.get("faults", []))
    out.fault_events = events
    for fid in {e[1] for e in events}:
        ts, vs = [0.0], [0.0]
        for t, i, ev in events:
            if i == fid:
                ts.append(t)
                vs.append(1.0 if ev == "onset" else 0.0)
        out.series[f"fault.{fid}"] = (np.asarray(ts), np.asarray(vs))
    return out
