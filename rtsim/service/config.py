"""`rtsim serve`'s settings, declared once (and the file's ``[[faults]]``, rtsim.faults.spec): each is a field of `ServeOptions` with its type, default, range,
help text, its key in the settings file (configs/service.toml documents every key and the embedded
defaults) and its command-line flag. The file's sections, the flags and the validation are derived from
these declarations; flags override the file; errors name the file (or the flag), the key, the value and
what is allowed (rtsim.configfile).
"""
from __future__ import annotations

import argparse
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, create_model

from rtsim.configfile import Range, Strict, load_toml, validate

from .user_input import USER_HOLD

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_SCENARIO = ROOT / "configs" / "scenarios" / "hil_flat.toml"
TWO_WHEELER_SCENARIO = ROOT / "configs" / "scenarios" / "motorcycle_hil.toml"
DEFAULT_ZENOH_LISTEN = "tcp/127.0.0.1:7447"
Step = Range(1e-5, 0.01, "s")
Pressure = Range(0.0, 12000.0, "kPa")
StateRate = Range(1.0, 1000.0, "Hz")
StatusRate = Range(1.0, 10.0, "Hz")
Spin = Range(0.0, 0.01, "s")
WallTime = Range(0.0, 1e9, "s", lo_open=True)
Port = Range(1, 65535, "TCP port", integer=True)
Hold = Range(0.1, 3600.0, "s")


def setting(default: Any, help: str, key: str | None, flag: str | None = None, **kw):
    """A setting's declaration: `key` is "section.name" in the settings file (None: flag only), `flag`
    the command-line option (default --<name> with dashes; "" for none); a bool flag given as "--no-x"
    sets False."""
    return Field(default, description=help, json_schema_extra={"key": key, "flag": flag}, **kw)


class ServeOptions(BaseModel):
    """Everything `rtsim serve` can be told."""
    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    scenario: Optional[Path] = setting(None, "scenario TOML or name in configs/scenarios (road, start, step; "
                                       "default hil_flat, motorcycle_hil for a two-wheeler)", "simulation.scenario")
    scenario_dirs: list[Path] = setting(
        [], "folder the control op load_scenario may read scenarios from, besides the shipped configs/scenarios "
        "(repeatable; a name outside these folders is refused)", "simulation.scenario_dirs", "--scenario-dir")
    vehicle: Optional[Path] = setting(None, "vehicle TOML or name in configs/vehicles (default: the scenario's, else "
                                      "configs/vehicles/xbw.toml)", "simulation.vehicle")
    dt: Optional[Step] = setting(None, "fixed step, s (default: the scenario's, 0.001)",
                                                   "simulation.dt")
    rider: Literal["on", "off"] = setting(
        "on", "a two-wheeler's rider: on (default): the scenario's rider rides it inside the service; off: "
        "nobody does (a controller on the bus steers, throttles and brakes)", "simulation.rider")
    mode: Literal["realtime", "lockstep", "fast"] = setting(
        "realtime", "realtime (default): paced by the wall clock; lockstep: steps only on request (CAN "
        "SIM_STEP_REQ or Zenoh control op=step); fast: as fast as possible", "simulation.mode")
    max_catch_up: Range(0, 10000, "steps", integer=True) = setting(
        20, "after a stall, steps run back to back before the rest are skipped (default 20)",
        "simulation.max_catch_up")
    loop_cpu: Optional[Range(0, 4095, "CPU", integer=True)] = setting(
        None, "pin the loop thread (only it) to this CPU, Linux (default: not pinned); give it a core nothing "
        "else runs on, e.g. pages and other work on the others", "simulation.loop_cpu")
    loop_priority: Optional[Range(1, 99, "SCHED_FIFO priority", integer=True)] = setting(
        None, "run the loop thread (only it) under SCHED_FIFO at this real-time priority, Linux, needs the "
        "privilege (default: the normal scheduler); with --loop-cpu other processes on its CPU wait for it",
        "simulation.loop_priority")
    hold_pressure: Optional[Pressure] = setting(
        None, "brake pressure applied when the brake command times out, kPa (default 3000)",
        "simulation.hold_pressure")
    can_interface: Optional[str] = setting(None, "python-can interface (socketcan, remote, virtual, pcan, ...); "
                                           "default: socketcan vcan0 if present, else the loopback hub",
                                           "can.interface")
    can_channel: Optional[str] = setting(None, "python-can channel (vcan0, can0, 127.0.0.1:54701, ...)",
                                         "can.channel")
    can_hub_port: Optional[Port] = setting(
        None, "port of the loopback CAN hub on 127.0.0.1 (used when no --can-interface is given and the kernel "
        "has no vcan0; default: $RTSIM_CAN_HUB_PORT, else 54701)", "can.hub_port")
    start_hub: bool = setting(True, "do not start the embedded loopback CAN hub", "can.start_hub", "--no-hub")
    zenoh: bool = setting(True, "do not publish over Zenoh", "zenoh.enabled", "--no-zenoh")
    zenoh_listen: list[str] = setting([DEFAULT_ZENOH_LISTEN], f"Zenoh listen endpoint (repeatable; default "
                                      f"{DEFAULT_ZENOH_LISTEN})", "zenoh.listen")
    zenoh_connect: list[str] = setting([], "Zenoh endpoint to connect to (a router on a bench; repeatable)",
                                       "zenoh.connect")
    zenoh_allow_remote: bool = setting(False, "allow Zenoh endpoints off 127.0.0.1 (a real bench network)",
                                       "zenoh.allow_remote")
    vehicle_id: Optional[str] = setting(None, "key segment of the Zenoh keys and MCAP topics (default: the "
                                        "vehicle's id)", "zenoh.vehicle_id", pattern=r"^[A-Za-z0-9_-]+$")
    state_rate: StateRate = setting(100.0, "state publication rate, Hz (default 100)",
                                                   "zenoh.state_rate")
    status_rate: StatusRate = setting(10.0, "status publication rate, Hz (1-10, default 10)",
                                                  "zenoh.status_rate")
    user_input: bool = setting(True, "refuse driving commands from `rtsim view` (the Zenoh control op drive; by "
                               "default a user's commands replace the in-loop driver's, and the bus ECU's where it "
                               "has no valid command or the user takes over)", "simulation.user_input",
                               "--no-user-input")
    user_hold: Hold = setting(USER_HOLD, f"s of wall time a user's command is held without a new request, then "
                              f"handed back (default {USER_HOLD:g}: a page that went away stops driving; longer for "
                              f"a page on a slow link or a loaded machine)", "simulation.user_hold")
    record: Optional[Path] = setting(None, "record the session to MCAP (FILE.mcap)", "record.path")
    foxglove_port: Optional[Range(0, 65535, "TCP port (0: a free one)", integer=True)] = setting(None, "serve a Foxglove WebSocket on this port (ws://HOST:PORT: the "
                                           "topics, 3D scene and road; 0: a free port; default off)",
                                           "foxglove.port")
    foxglove_host: str = setting("127.0.0.1", "address the Foxglove server binds to (default 127.0.0.1; "
                                 "another than loopback only with --foxglove-allow-remote)", "foxglove.host")
    foxglove_allow_remote: bool = setting(False, "let the Foxglove server bind to an address off loopback",
                                          "foxglove.allow_remote")
    spin: Spin = setting(0.0002, "busy-wait before each step, s (default 0.0002; a value >= "
                                          "the step never sleeps: for a dedicated core)", None)
    duration: Optional[WallTime] = setting(
        None, "stop after this many seconds of wall time", None)
    dbc: Optional[Path] = setting(None, "DBC of the CAN interface (default: the vehicle's [interface] dbc)", None)
    faults: list[Path] = setting([], "a TOML file whose [[faults]] to arm in the session (see `rtsim faults --list`; "
                                 "repeatable; a settings file's own [[faults]] come first)", None, "--faults")

    def check(self) -> None:
        """Checks across settings (each value was checked on assignment)."""
        from rtsim.errors import ConfigError
        if self.record is not None and Path(self.record).suffix.lower() != ".mcap":
            raise ConfigError(f"--record {self.record}: the recording must be an .mcap file")
        if self.foxglove_port is not None:
            from bridge.foxglove_live import check_host
            check_host(self.foxglove_host, self.foxglove_allow_remote)
        if self.loop_priority is not None and not hasattr(__import__("os"), "SCHED_FIFO"):
            raise ConfigError("--loop-priority: this system has no SCHED_FIFO (Linux only)")
        if self.loop_cpu is not None:
            import os
            if not hasattr(os, "sched_setaffinity"):
                raise ConfigError("--loop-cpu: this system cannot pin a thread to a CPU (Linux only)")
            if self.loop_cpu >= (os.cpu_count() or 1):
                raise ConfigError(f"--loop-cpu {self.loop_cpu}: this machine has CPUs 0..{(os.cpu_count() or 1) - 1}")


def _declared():
    for name, f in ServeOptions.model_fields.items():
        extra = f.json_schema_extra or {}
        yield name, f, extra.get("key"), extra.get("flag")


def _file_schema() -> type[BaseModel]:
    """The settings file's model, derived from the declarations: one Strict section per file section."""
    sections: dict[str, dict] = {}
    for name, f, key, _flag in _declared():
        if key:
            sec, k = key.split(".")
            tp = Annotated[(f.annotation, *f.metadata)] if f.metadata else f.annotation
            sections.setdefault(sec, {})[k] = (tp, Field(f.default, description=f.description))
    models = {sec: create_model(f"Service_{sec}", __base__=Strict, **fields) for sec, fields in sections.items()}
    return create_model("ServiceFile", __base__=Strict, **{sec: (m, m()) for sec, m in models.items()})


def load_service_config(path: str | Path) -> dict:
    """ServeOptions keyword arguments from a settings file (only the keys it sets; relative paths
    against its folder); errors name the file and the section.key."""
    from rtsim.faults.spec import load_fault_specs

    path = Path(path)
    raw = load_toml(path)
    faults = raw.pop("faults", None)
    validate(_file_schema(), raw, str(path))
    out = {}
    if faults is not None:
        load_fault_specs(faults, path)            # checked now: errors name this file and faults[i].key
        out["faults"] = [path]
    for name, f, key, _flag in _declared():
        if not key:
            continue
        sec, k = key.split(".")
        if k in raw.get(sec, {}):
            v = raw[sec][k]
            if f.annotation in (Path, Optional[Path]) and v is not None and not Path(v).is_absolute():
                v = path.parent / v
            elif f.annotation == list[Path] and isinstance(v, list):
                v = [path.parent / e if isinstance(e, str) and not Path(e).is_absolute() else e for e in v]
            out[name] = v
    return out


def _arg_type(annotation):
    """The command-line conversion of a setting's type (its range is checked by the model)."""
    for tp in (t for t in (typing.get_args(annotation) or (annotation,)) if t is not type(None)):
        base = typing.get_args(tp)[0] if typing.get_origin(tp) is typing.Annotated else tp
        if base in (float, int, Path):
            return base
    return str


#: what the value of each flag-settable setting is, as its --help shows it (a Literal's choices show themselves)
METAVARS = {
    "scenario": "FILE|NAME", "vehicle": "FILE|NAME", "dt": "S", "max_catch_up": "N", "loop_cpu": "CPU",
    "loop_priority": "P", "hold_pressure": "KPA", "can_interface": "INTERFACE", "can_channel": "CHANNEL",
    "can_hub_port": "PORT", "vehicle_id": "ID", "state_rate": "HZ", "status_rate": "HZ", "record": "FILE.mcap",
    "user_hold": "S",
    "foxglove_port": "PORT", "foxglove_host": "ADDRESS", "spin": "S", "duration": "S", "dbc": "FILE",
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    """One flag per declared setting (plus --config and --json)."""
    p.add_argument("--config", metavar="FILE",
                   help="service settings TOML (see configs/service.toml); flags override it")
    for name, f, _key, flag in _declared():
        if flag == "":
            continue
        dest = f"opt_{name}"
        if f.annotation is bool:
            neg = flag is not None and flag.startswith("--no-")
            p.add_argument(flag or f"--{name.replace('_', '-')}", dest=dest, action="store_const",
                           const=not neg, default=None, help=f.description)
        elif f.annotation == list[str]:
            p.add_argument(flag or f"--{name.replace('_', '-')}", dest=dest, action="append", metavar="ENDPOINT",
                           help=f.description)
        elif f.annotation == list[Path]:
            p.add_argument(flag or f"--{name.replace('_', '-')}", dest=dest, action="append", metavar="FILE" if name == "faults" else "FOLDER",
                           type=Path, help=f.description)
        elif typing.get_args(f.annotation) and all(isinstance(c, str) for c in typing.get_args(f.annotation)):
            p.add_argument(flag or f"--{name.replace('_', '-')}", dest=dest, choices=typing.get_args(f.annotation),
                           help=f.description)
        else:
            p.add_argument(flag or f"--{name.replace('_', '-')}", dest=dest, type=_arg_type(f.annotation),
                           help=f.description, metavar=METAVARS[name])
    p.add_argument("--json", action="store_true", help="print the closing summary as JSON")


def options(args) -> ServeOptions:
    """ServeOptions from the defaults, then the --config file, then the flags given (flag errors name
    `rtsim serve` and the setting)."""
    kw: dict = {}
    if getattr(args, "config", None):
        kw.update(load_service_config(args.config))
    flags = {name: getattr(args, f"opt_{name}") for name, *_ in _declared()
             if getattr(args, f"opt_{name}", None) is not None}
    if "faults" in kw and "faults" in flags:         # the file's own [[faults]], then the --faults files
        flags["faults"] = [*kw["faults"], *flags["faults"]]
    return validate(ServeOptions, {**kw, **flags}, "rtsim serve")
