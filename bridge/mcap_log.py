"""MCAP files of a run: one JSON message per logged sample on `rtsim/<vehicle_id>/sensors` (every
sensor channel) and `rtsim/<vehicle_id>/state` (pose, speed, tyre forces, constraint violation), with
JSON-schema channels that Foxglove opens without plug-ins, zstd-compressed chunks, log time = the
simulation time. Names and units are the channel dictionary's (rtsim.channels)."""
from __future__ import annotations

import json
from pathlib import Path

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from rtsim.channels import BY_NAME, SENSOR_NAMES

STATE_UNITS = {"pos_x": "m", "pos_y": "m", "pos_z": "m", "yaw": "rad", "speed": "m/s",
               "constraint_violation": "coordinate units"}


def _schema(title: str, fields: list[str], units: dict[str, str]) -> bytes:
    props = {"time": {"type": "number", "description": "simulation time, s"}}
    for f in fields:
        props[f] = {"type": "number", "description": units.get(f, "")}
    return json.dumps({"title": title, "type": "object", "properties": props,
                       "required": ["time", *fields]}).encode()


def write_run(path: str | Path, columns: tuple[str, ...], rows, vehicle_id: str) -> None:
    """Write the rows of a run (columns as rtsim.vehicle.offline.COLUMNS) to an MCAP file."""
    sensors = [c for c in columns if c in SENSOR_NAMES]
    state = [c for c in columns if c not in SENSOR_NAMES and c != "time"]
    units = {n: BY_NAME[n].unit for n in sensors}
    units.update({n: ("N" if n.startswith("tyre_") else STATE_UNITS.get(n, "")) for n in state})
    idx = {c: i for i, c in enumerate(columns)}
    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="rtsim")
        ch = {}
        for topic, fields in (("sensors", sensors), ("state", state)):
            sid = w.register_schema(name=f"rtsim.{topic}", encoding="jsonschema",
                                    data=_schema(f"rtsim {topic}", fields, units))
            ch[topic] = (w.register_channel(topic=f"rtsim/{vehicle_id}/{topic}", message_encoding="json",
                                            schema_id=sid), fields)
        for seq, r in enumerate(rows):
            t_ns = int(round(float(r[idx["time"]]) * 1e9))
            for cid, fields in ch.values():
                msg = {"time": float(r[idx["time"]]), **{f: float(r[idx[f]]) for f in fields}}
                w.add_message(channel_id=cid, log_time=t_ns, publish_time=t_ns, sequence=seq,
                              data=json.dumps(msg).encode())
        w.finish()


def read_messages(path: str | Path, topic: str):
    """(time, message dict) of one topic, in log-time order."""
    with open(path, "rb") as fh:
        for _schema_, channel, message in make_reader(fh).iter_messages(topics=[topic]):
            yield message.log_time * 1e-9, json.loads(message.data)
