"""MCAP files of an offline run, written by the service's recorder (bridge.mcap_recorder: one writer, one
set of schemas): one JSON message per logged sample on `rtsim/<vehicle_id>/sensors` and
`rtsim/<vehicle_id>/state`, log time = the simulation time. Names and units are the vehicle's channel
dictionary's, so a run and a service session of the same vehicle look alike to Foxglove and to the
validation workflow; :func:`read_run` reads either back as one table."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from mcap.reader import make_reader

from bridge.mcap_recorder import Recorder, read_recording
from bridge.payloads import encode_json
from rtsim.channels import CAR, ENERGY, ChannelDictionary
from rtsim.errors import ConfigError

ENERGY_NAMES = frozenset(c.name for c in ENERGY)


def write_offline(res, path: str | Path) -> None:
    """An offline run of any vehicle (rtsim.vehicle.registry.OfflineRun) to ``path``: .csv (its own
    writer) or .mcap (``write_run``, with the 3D scene); ConfigError for any other suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        res.write_csv(path)
    elif suffix == ".mcap":
        write_run(path, res.columns, res.data, res.vehicle_id, res.channels, sim=res.scene)
    else:
        raise ConfigError(f"{path}: output must end in .csv or .mcap")


def write_run(path: str | Path, columns: tuple[str, ...], rows, vehicle_id: str,
              channels: ChannelDictionary = CAR, sim=None) -> None:
    """Write the rows of a run (columns: `time`, then channels of `channels`, as
    rtsim.vehicle.offline.columns_of, and the power audit's rtsim.channels.ENERGY) to an MCAP file: each
    row as one sensors, one state and one energy message with the columns of that kind it has. With
    the run's vehicle simulation `sim` (and the pose among the columns) also the 3D scene of
    bridge.scene: the road at the start, the vehicle's scene and frame transform at most every 10 ms,
    as a service's recording has them (Foxglove shows the vehicle in 3D)."""
    sensors = [c for c in columns if c in channels.sensor_names]
    state = [c for c in columns if c in channels.state_names]
    energy = [c for c in columns if c in ENERGY_NAMES and c not in state]
    idx = {c: i for i, c in enumerate(columns)}
    scene = _scene(sim, vehicle_id, columns, channels, rows)
    rec = Recorder(path, vehicle_id, queue_size=(6 if scene else 3) * len(rows) + 16, channels=channels)
    try:
        due = -1.0
        if scene is not None:
            builder, road, take_state, take_sensors = scene
            rec.record("road", int(round(float(rows[0][idx["time"]]) * 1e9)), road)
        for r in rows:
            t = float(r[idx["time"]])
            t_ns = int(round(t * 1e9))
            for key, fields in (("sensors", sensors), ("state", state), ("energy", energy)):
                if not fields:
                    continue
                rec.record(key, t_ns, encode_json({"time": t, **{f: float(r[idx[f]]) for f in fields}}))
            if scene is not None and t >= due - 1e-9:
                due = t + SCENE_PERIOD
                msg, tf = builder.vehicle(t, take_state(r), take_sensors(r))
                rec.record("tf", t_ns, tf)
                rec.record("scene", t_ns, msg)
    finally:
        rec.close()


#: Shortest interval of an offline run's scene messages, s (the service's scene rate, 100 Hz).
SCENE_PERIOD = 0.01


def _scene(sim, vehicle_id: str, columns, channels: ChannelDictionary, rows):
    """(SceneBuilder, road scene bytes, state row picker, sensor row picker) for write_run; None without
    `sim`, rows, or the pose among the columns."""
    pose = ("pos_x", "pos_y", "pos_z", "roll_angle", "pitch_angle", "yaw_angle")
    if sim is None or not len(rows) or not all(c in columns for c in pose):
        return None
    from bridge.scene import scene_for

    idx = {c: i for i, c in enumerate(columns)}
    first = rows[0]
    builder, road = scene_for(sim, vehicle_id, (float(first[idx["pos_x"]]), float(first[idx["pos_y"]])))
    st = np.array([idx.get(n, -1) for n in channels.state_names], dtype=np.intp)
    se = np.array([idx.get(n, -1) for n in channels.sensor_names], dtype=np.intp)   # (none offline: empty)

    def picker(cols):
        def take(r):
            v = np.asarray(r, dtype=float)[np.maximum(cols, 0)]
            v[cols < 0] = np.nan
            return v
        return take
    return builder, road, picker(st), picker(se)


def read_messages(path: str | Path, topic: str):
    """(time, message dict) of one topic, in log-time order."""
    with open(path, "rb") as fh:
        for _schema_, channel, message in make_reader(fh).iter_messages(topics=[topic], log_time_order=True):
            yield message.log_time * 1e-9, json.loads(message.data)


def read_run(path: str | Path) -> tuple[tuple[str, ...], np.ndarray]:
    """A recording's `rtsim/<vehicle_id>/sensors`, `.../state` and (offline runs) `.../energy` topics (an
    offline run's or a service session's; a damaged file's complete chunks) as one table: columns `time`
    (s), the sensor channels, then the state channels that are not also sensor channels, then the power
    audit's; rows at the sensor messages' times (the
    state's values interpolated onto them where its messages have other times; NaN for null values).
    ConfigError when the file holds neither topic or more than one vehicle."""
    messages, _info = read_recording(path)
    topics = {}
    for key in ("sensors", "state", "energy"):
        found = [t for t in messages if t.startswith("rtsim/") and t.endswith(f"/{key}") and messages[t]]
        if len(found) > 1:
            raise ConfigError(f"{path}: several {key} topics ({', '.join(found)}); one vehicle per recording")
        if found:
            topics[key] = [m.data for m in messages[found[0]] if isinstance(m.data, dict)]
    if not any(topics.values()):
        raise ConfigError(f"{path}: no rtsim/<vehicle_id>/sensors or state messages "
                          f"(topics: {', '.join(messages) or 'none'})")
    columns: list[str] = ["time"]
    tables = []
    for msgs in topics.values():
        if not msgs:
            continue
        names = [n for n in msgs[0] if n != "time" and n not in columns]
        tables.append((_table(msgs, ["time", *names]), names))
        columns += names
    base = tables[0][0]
    base = base[np.argsort(base[:, 0], kind="stable")]
    t = base[:, 0]
    out = np.full((len(t), len(columns)), np.nan)
    out[:, :base.shape[1]] = base
    j = base.shape[1]
    for m, names in tables[1:]:
        if m.shape[0] == len(t) and np.array_equal(m[:, 0], t):
            out[:, j:j + len(names)] = m[:, 1:]
        else:
            order = np.argsort(m[:, 0], kind="stable")
            for k in range(len(names)):
                x = m[order, 1 + k]
                ok = np.isfinite(x)
                if ok.any():
                    out[:, j + k] = np.interp(t, m[order, 0][ok], x[ok], left=np.nan, right=np.nan)
        j += len(names)
    return tuple(columns), out


def _table(msgs: list[dict], names: list[str]) -> np.ndarray:
    """The values of `names` of each message (NaN where missing or not a number)."""
    m = np.full((len(msgs), len(names)), np.nan)
    for i, d in enumerate(msgs):
        for k, n in enumerate(names):
            v = d.get(n)
            if isinstance(v, (int, float)):
                m[i, k] = v
    return m
