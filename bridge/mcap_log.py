"""MCAP files of an offline run, written by the service's recorder (bridge.mcap_recorder: one writer, one
set of schemas): one JSON message per logged sample on `rtsim/<vehicle_id>/sensors` and
`rtsim/<vehicle_id>/state`, log time = the simulation time. Names and units are the vehicle's channel
dictionary's, so a run and a service session of the same vehicle look alike to Foxglove and to the
validation workflow."""
from __future__ import annotations

import json
from pathlib import Path

from mcap.reader import make_reader

from bridge.mcap_recorder import Recorder
from bridge.payloads import encode_json
from rtsim.channels import CAR, ENERGY, ChannelDictionary

ENERGY_NAMES = frozenset(c.name for c in ENERGY)


def write_run(path: str | Path, columns: tuple[str, ...], rows, vehicle_id: str,
              channels: ChannelDictionary = CAR) -> None:
    """Write the rows of a run (columns: `time`, then channels of `channels`, as
    rtsim.vehicle.offline.columns_of, and the power audit's rtsim.channels.ENERGY) to an MCAP file: each
    row as one sensors, one state and one energy message with the columns of that kind it has."""
    sensors = [c for c in columns if c in channels.sensor_names]
    state = [c for c in columns if c in channels.state_names]
    energy = [c for c in columns if c in ENERGY_NAMES and c not in state]
    idx = {c: i for i, c in enumerate(columns)}
    rec = Recorder(path, vehicle_id, queue_size=3 * len(rows) + 16, channels=channels)
    try:
        for r in rows:
            t = float(r[idx["time"]])
            t_ns = int(round(t * 1e9))
            for key, fields in (("sensors", sensors), ("state", state), ("energy", energy)):
                if not fields:
                    continue
                rec.record(key, t_ns, encode_json({"time": t, **{f: float(r[idx[f]]) for f in fields}}))
    finally:
        rec.close()


def read_messages(path: str | Path, topic: str):
    """(time, message dict) of one topic, in log-time order."""
    with open(path, "rb") as fh:
        for _schema_, channel, message in make_reader(fh).iter_messages(topics=[topic], log_time_order=True):
            yield message.log_time * 1e-9, json.loads(message.data)
