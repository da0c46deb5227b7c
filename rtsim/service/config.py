"""`rtsim serve --config FILE`: the service's settings as a validated TOML file (configs/service.toml
documents every key and the embedded defaults). Errors name the file, the key, the value and what is
allowed; command-line flags override the file."""
from __future__ import annotations

from pathlib import Path
from typing import Literal, Optional

from pydantic import Field

from rtsim.configfile import Strict, load


class SimulationSection(Strict):
    scenario: Optional[str] = None
    vehicle: Optional[str] = None
    mode: Literal["realtime", "lockstep", "fast"] = "realtime"
    dt: Optional[float] = Field(None, ge=1e-5, le=0.01)
    max_catch_up: int = Field(20, ge=0, le=10000)
    hold_pressure: Optional[float] = Field(None, ge=0.0, le=12000.0)


class CanSection(Strict):
    interface: Optional[str] = None
    channel: Optional[str] = None
    start_hub: bool = True


class ZenohSection(Strict):
    enabled: bool = True
    listen: list[str] = ["tcp/127.0.0.1:7447"]
    connect: list[str] = []
    allow_remote: bool = False
    vehicle_id: Optional[str] = Field(None, pattern=r"^[A-Za-z0-9_-]+$")
    state_rate: float = Field(100.0, ge=1.0, le=1000.0)
    status_rate: float = Field(10.0, ge=1.0, le=10.0)


class RecordSection(Strict):
    path: Optional[str] = None


class ServiceConfig(Strict):
    simulation: SimulationSection = SimulationSection()
    can: CanSection = CanSection()
    zenoh: ZenohSection = ZenohSection()
    record: RecordSection = RecordSection()


def load_service_config(path: str | Path) -> dict:
    """ServeOptions keyword arguments from a service TOML (paths resolved against its folder)."""
    path = Path(path)
    cfg = load(ServiceConfig, path)
    base = path.parent

    def rel(p):
        return None if p is None else (Path(p) if Path(p).is_absolute() else base / p)
    s, c, z, r = cfg.simulation, cfg.can, cfg.zenoh, cfg.record
    out = {"mode": s.mode, "dt": s.dt, "max_catch_up": s.max_catch_up, "hold_pressure": s.hold_pressure,
           "vehicle": rel(s.vehicle), "can_interface": c.interface, "can_channel": c.channel,
           "start_hub": c.start_hub, "zenoh": z.enabled, "zenoh_listen": list(z.listen),
           "zenoh_connect": list(z.connect), "zenoh_allow_remote": z.allow_remote, "vehicle_id": z.vehicle_id,
           "state_rate": z.state_rate, "status_rate": z.status_rate, "record": rel(r.path)}
    if s.scenario is not None:
        out["scenario"] = rel(s.scenario)
    return out
