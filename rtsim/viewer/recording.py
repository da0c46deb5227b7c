"""A recording as a source of the page (`rtsim view FILE.mcap [FILE2.mcap]`): the state, sensor and status
samples of a service's MCAP (bridge.mcap_recorder.read_topics; a damaged recording, or one cut off by a
kill, gives the chunks that check out, and ``health``/``damage`` say what was lost and how the session
ended; a recording with no readable state sample is an error) and the scene it needs, described from the
session's metadata (the vehicle and scenario files as they were when recorded; the files at those paths
when they still exist).

The page gets each recording whole (``payload``) and plays it with its own timeline; the sensor samples
come at the state's rate (the last sensor sample at or before each state sample) to keep the page light.
Only the topics the page needs are read, and the samples are not decoded here: their JSON text, as the
service recorded it, goes into the page's message (a 45 MB, 187 s session: about 0.5 s instead of 8 s).
"""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

from rtsim.errors import RtsimError


class Recording:
    """One recording's samples and scene description. The state and sensor samples stay the JSON text the
    service recorded (bridge.mcap_recorder.read_topics: only the topics the page needs, nothing decoded
    here; the page parses them), the status is decoded (a few a second)."""

    def __init__(self, path: str | Path):
        from bridge.mcap_recorder import read_topics

        self.path = Path(path)
        kinds = ("state", "sensors", "status", "faults")
        msgs, info = read_topics(self.path, lambda t: t.startswith("rtsim/") and t.rsplit("/", 1)[-1] in kinds
                                 and t.count("/") == 2)
        self.health = info.health_line()     # what the file lost, how the session ended (one line)
        self.damage = info.damage            # the same, as the page's ``recording`` message carries it
        damage = f"; {self.health}" if info.damaged else ""
        session = info.metadata.get("rtsim.session", {})
        vid = session.get("vehicle_id") or next((t.split("/")[1] for t in msgs if t.endswith("/state")), None)
        topics = {k: f"rtsim/{vid}/{k}" for k in kinds}
        if vid is None or topics["state"] not in msgs:
            raise RtsimError(f"{self.path}: no state topic (rtsim/<vehicle>/state): "
                             + (f"nothing readable{damage}" if info.damaged else "not a recording of rtsim serve"))
        self.vehicle_id = vid
        state = msgs[topics["state"]]
        if not state.data:
            raise RtsimError(f"{self.path}: the recording holds no state sample{damage}")
        self.times = state.log_time_ns * 1e-9          # s, the state samples' simulation times
        self._state = state.data
        self.status = [json.loads(m) for m in msgs[topics["status"]].data] if topics["status"] in msgs else []
        #: the injected faults' onsets and ends (rtsim.faults), for the timeline's marks
        self.faults = [json.loads(m) for m in msgs[topics["faults"]].data] if topics["faults"] in msgs else []
        sensors = msgs.get(topics["sensors"])
        self._sensors = self._at_state_times(state, sensors.log_time_ns.tolist() if sensors else [],
                                             sensors.data if sensors else [])
        self.complete = info.complete
        self.config = self._config(info, session)

    @staticmethod
    def _at_state_times(state, sensor_ns: list, sensors: list) -> list[bytes]:
        """Per state sample, the last sensor sample at or before its time (log times: the samples' own
        simulation times, ns), else one holding only the time."""
        out, j, n = [], -1, len(sensor_ns)
        for t in state.log_time_ns.tolist():
            while j + 1 < n and sensor_ns[j + 1] <= t + 1:
                j += 1
            out.append(sensors[j] if j >= 0 else b'{"time":%r}' % (t * 1e-9))
        return out

    @property
    def duration(self) -> float:
        """s from the first to the last state sample."""
        return float(self.times[-1] - self.times[0])

    @property
    def state(self) -> list[dict]:
        """The state samples, decoded (for scripts and tests; the page gets the text)."""
        return [json.loads(m) for m in self._state]

    @property
    def sensors(self) -> list[dict]:
        """The sensor samples at the state samples' times, decoded."""
        return [json.loads(m) for m in self._sensors]

    def _config(self, info, session: dict) -> dict:
        """What the service's ``config`` query would have answered, from the recording's metadata."""
        veh = info.metadata.get("rtsim.vehicle", {})
        vpath = Path(veh["path"]) if veh.get("path") else None
        raw = tomllib.loads(veh["toml"]) if veh.get("toml") else {}
        vehicle = raw
        if vpath is not None and vpath.is_file():
            try:
                from rtsim.vehicle.registry import open_vehicle
                vehicle = open_vehicle(vpath).config.model_dump(mode="json")
            except Exception:  # noqa: BLE001  (the file changed since: the recorded text)
                vehicle = raw
        if not vehicle:
            raise RtsimError(f"{self.path}: no vehicle in the recording's metadata (rtsim.vehicle)")
        scen = info.metadata.get("rtsim.scenario", {})
        channels = json.loads(info.channels.to_json()) if info.channels is not None else {}
        return {"vehicle_id": self.vehicle_id, "vehicle": vehicle, "dt": float(session.get("dt", "0.001")),
                "options": {"vehicle": str(vpath) if vpath is not None and vpath.is_file() else None,
                            "mode": session.get("mode")},
                "scenario": {"name": session.get("scenario"), "path": scen.get("path")}, "channels": channels}

    def payload(self, index: int) -> str:
        """The page's ``recording`` message (JSON text): every sample, the file's name and completeness; the
        samples' text is spliced in as recorded."""
        head = json.dumps({"type": "recording", "index": index, "file": self.path.name, "complete": self.complete,
                           "health": self.health, "damage": self.damage, "status": self.status,
                           "faults": self.faults},
                          separators=(",", ":"), default=str)
        return "".join((head[:-1], ',"state":[', b",".join(self._state).decode(), '],"sensors":[',
                        b",".join(self._sensors).decode(), "]}"))
