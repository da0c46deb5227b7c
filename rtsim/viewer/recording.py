"""A recording as a source of the page (`rtsim view FILE.mcap [FILE2.mcap]`): the state, sensor and status
samples of a service's MCAP (bridge.mcap_recorder.read_recording; a recording cut off by a kill gives
its complete chunks) and the scene it needs, described from the session's metadata (the vehicle and
scenario files as they were when recorded; the files at those paths when they still exist).

The page gets each recording whole (``payload``) and plays it with its own timeline; the sensor samples
come at the state's rate (the last sensor sample at or before each state sample) to keep the page light.
"""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

from rtsim.errors import RtsimError


class Recording:
    """One recording's samples and scene description."""

    def __init__(self, path: str | Path):
        from bridge.mcap_recorder import read_recording

        self.path = Path(path)
        msgs, info = read_recording(self.path)
        session = info.metadata.get("rtsim.session", {})
        vid = session.get("vehicle_id") or next((t.split("/")[1] for t in msgs if t.endswith("/state")), None)
        if vid is None or f"rtsim/{vid}/state" not in msgs:
            raise RtsimError(f"{self.path}: no state topic (rtsim/<vehicle>/state): not a recording of rtsim serve")
        self.vehicle_id = vid
        self.state = [m.data for m in msgs[f"rtsim/{vid}/state"]]
        if not self.state:
            raise RtsimError(f"{self.path}: the recording holds no state sample")
        self.status = [m.data for m in msgs.get(f"rtsim/{vid}/status", [])]
        self.sensors = self._at_state_times([m.data for m in msgs.get(f"rtsim/{vid}/sensors", [])])
        self.complete = info.complete
        self.config = self._config(info, session)

    def _at_state_times(self, sensors: list[dict]) -> list[dict]:
        out, j = [], -1
        for s in self.state:
            while j + 1 < len(sensors) and sensors[j + 1]["time"] <= s["time"] + 1e-9:
                j += 1
            out.append(sensors[j] if j >= 0 else {"time": s["time"]})
        return out

    def _config(self, info, session: dict) -> dict:
        """What the service's ``config`` query would have answered, from the recording's metadata."""
        veh = info.metadata.get("rtsim.vehicle", {})
        vpath = Path(veh["path"]) if veh.get("path") else None
        raw = tomllib.loads(veh["toml"]) if veh.get("toml") else {}
        vehicle = raw
        if vpath is not None and vpath.is_file():
            try:
                if raw.get("kind") == "two_wheeler":
                    from rtsim.vehicle.motorcycle.config import load_motorcycle
                    vehicle = load_motorcycle(vpath)[0].model_dump(mode="json")
                else:
                    from rtsim.vehicle.car.config import load_vehicle
                    vehicle = load_vehicle(vpath)[0].model_dump(mode="json")
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
        """The page's ``recording`` message (JSON text): every sample, the file's name and completeness."""
        return json.dumps({"type": "recording", "index": index, "file": self.path.name, "complete": self.complete,
                           "state": self.state, "sensors": self.sensors, "status": self.status},
                          separators=(",", ":"))
