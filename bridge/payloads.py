"""The JSON payloads of the HIL service, shared by Zenoh (``rtsim/<vehicle_id>/<key>``) and MCAP.

``SCHEMAS[key] = (schema name, JSON schema)`` for every topic key; names, units and meanings come from
the channel dictionary (rtsim.channels), every payload carries ``time`` (s, simulation time), and
non-finite numbers travel as JSON ``null`` (JSON has no NaN or infinity). The encoders run on a
publisher thread at 500 Hz, so the sensor and state encoders fill precomputed ``%``-templates
instead of calling :mod:`json`; their cost is Python's float-to-text conversion, about 0.4 µs per
value for the exact shortest form, 0.15 µs rounded to 9 digits (``python -m bridge.payloads --bench``).

Command line: ``python -m bridge.payloads --write-schemas DIR`` writes one ``<key>.json`` per topic
(``can/rx`` and ``can/tx`` into ``DIR/can/``); the committed copies live in ``schemas/``.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from rtsim.channels import CAR, ENERGY, SENSOR_NAMES, STATE_NAMES, ChannelDictionary
from rtsim.errors import RtsimError

TOPIC_KEYS = ("sensors", "state", "status", "commands", "can/rx", "can/tx")
EVENT_TOPIC_KEYS = ("user", "control", "faults")   # recorded by the service only (not published on Zenoh)
OFFLINE_TOPIC_KEYS = ("energy",)    # recorded by offline runs only (rtsim.vehicle.car.energy)
MODES = ("realtime", "lockstep", "fast")
RUN_STATES = ("running", "paused", "model_fault")    # model_fault: rtsim.service.loop's model-fault state
COMMAND_SOURCES = ("can", "zenoh", "safe")
FAULTS = ("throttle_timeout", "brake_timeout", "steer_timeout", "bus_error")
REJECTIONS = ("dlc", "crc", "counter", "range", "unknown_id")
#: the receiver's further outcomes (bridge.can_e2e; SIM_DIAG), optional: absent from older recordings
E2E_REJECTIONS = ("repeated", "jump", "sync", "format")
SIM_FAULTS = ("model", "second_sim")   # the simulator's own fault flags besides bus_error (SIM_STATUS)
USER_CAUSES = ("drive", "release", "lapse")
CONTROL_OPS = ("pause", "resume", "step", "driver", "reset", "load_scenario", "inject_fault",
               "clear_fault")   # recorded (rtsim.service.loop)
FAULT_EVENTS = ("onset", "end")    # a fault's events (rtsim.faults)
DRIVER_SOURCES = ("user", "ecu", "scenario", "rider", "safe", "none", "user+ecu", "rider+ecu", "none+ecu")
STATUS_OPTIONAL = ("wall_time", "drivers", "user", "foreign_frames", "model_fault", "injected_faults")

# ----------------------------------------------------------------------------------------- schemas

_TIME = {"type": "number", "description": "simulation time of the sample [s]"}
_NUM_OR_NULL = ["number", "null"]


def _signal(unit: str, desc: str) -> dict:
    """A channel value: a number in SI units, null when it was not finite."""
    return {"type": _NUM_OR_NULL, "description": f"{desc} [{unit}]"}


def _count(desc: str) -> dict:
    return {"type": "integer", "minimum": 0, "description": desc}


def _seconds(desc: str, nullable: bool = True) -> dict:
    return {"type": _NUM_OR_NULL if nullable else "number", "description": f"{desc} [s]"}


def _obj(title: str, props: dict, required, extra=False) -> dict:
    return {"title": title, "type": "object", "properties": props, "required": list(required),
            "additionalProperties": extra}


def _status_props() -> dict:
    return {
        "time": _TIME,
        "vehicle_id": {"type": "string", "description": "vehicle id of the service (topic prefix)"},
        "mode": {"type": "string", "enum": list(MODES),
                 "description": "pacing: realtime (wall clock), lockstep (stepped by requests), fast"},
        "run_state": {"type": "string", "enum": list(RUN_STATES), "description": "loop state"},
        "sim_time": _seconds("simulation time reached", nullable=False),
        "steps": _count("steps taken since start or reset"),
        "overruns": _count("steps started one period or more late"),
        "skipped_steps": _count("steps skipped after a stall (simulation time jumped)"),
        "catch_up_steps": _count("steps run back to back to catch up after lateness"),
        "stalls": _count("stalls: lateness beyond the catch-up limit"),
        "lateness_p50": _seconds("median step start lateness"),
        "lateness_p99": _seconds("99th percentile step start lateness"),
        "lateness_max": _seconds("largest step start lateness"),
        "cpu_p50": _seconds("median loop-thread CPU time per step"),
        "cpu_p99": _seconds("99th percentile loop-thread CPU time per step"),
        "cpu_max": _seconds("largest loop-thread CPU time per step"),
        "steal": _seconds("CPU time taken by the hypervisor (steal) over the run, null if unknown"),
        "faults": {"title": "active faults", "type": "object",
                   "description": "one flag per command's watchdog (<command>_timeout; the by-wire cars': "
                                  f"{', '.join(FAULTS[:-1])}), bus_error, model, second_sim, and for a car whose "
                                  "EPS is commanded over CAN eps_safe_state (assist off, latched until a reset)",
                   "properties": {
                       "bus_error": {"type": "boolean", "description": "bus_error fault active"},
                       "model": {"type": "boolean", "description": "the vehicle model has failed and is frozen "
                                                                   "until a reset (SIM_STATUS.fault_model)"},
                       "second_sim": {"type": "boolean",
                                      "description": "frames with this simulator's own ids that it did not send "
                                                     "arrived within the last second of simulation time: a second "
                                                     "simulator on the bus (SIM_STATUS.fault_second_sim)"}},
                   "required": ["bus_error"], "additionalProperties": {"type": "boolean"}},
        "rejected": _obj("rejected CAN frames by reason",
                         {**{r: _count(f"frames rejected: {r}") for r in REJECTIONS},
                          "repeated": _count("authentic command frames rejected: alive counter repeated (a frozen "
                                             "sender), whatever the time since the last good frame (part of counter)"),
                          "jump": _count("authentic command frames rejected: alive counter jumped beyond the allowed "
                                         "step while in sequence; starts a re-synchronisation (part of counter)"),
                          "sync": _count("authentic command frames in sequence not taken while the command "
                                         "re-synchronises after a time-out or a jump (DBC attribute E2ESyncCounter)"),
                          "format": _count("frames with a command's or SIM_STEP_REQ's id that are not classic "
                                           "standard-id data frames (extended id, remote, CAN FD)")},
                         REJECTIONS),
        "accepted_frames": _count("CAN frames accepted"),
        "bus_errors": _count("CAN bus errors"),
        "recorder": {
            "type": ["object", "null"],
            "description": "live MCAP recorder, null when not recording",
            "properties": {
                "path": {"type": ["string", "null"], "description": "recording file"},
                "written": _count("messages written"),
                "dropped": _count("messages dropped (queue full)"),
                "chunks": _count("chunks pushed to the operating system"),
            },
            "required": ["path", "written", "dropped", "chunks"],
            "additionalProperties": False,
        },
        "zenoh_dropped": _count("Zenoh publications that failed (congestion control DROP)"),
        "scenario": {"type": ["string", "null"], "description": "loaded scenario, null if none"},
        "message": {"type": "string", "description": "last event, free text"},
        "wall_time": _seconds("the service's wall clock (Unix time) when the status was made; with sim_time "
                              "it maps simulation to wall time in realtime mode (latency of observers)",
                              nullable=False),
        "drivers": {"title": "who drives", "type": "object",
                    "description": "per driving input (a car: throttle_angle_cmd, brake_pressure_cmd, "
                                   "steering_wheel_angle_cmd; a two-wheeler: throttle_cmd, brake_pressure_front_cmd, "
                                   "brake_pressure_rear_cmd, roll_angle_demand): user (rtsim view), ecu (a valid bus "
                                   "command), scenario (the in-loop driver), rider, safe (watchdog), none; '+ecu' "
                                   "when a bus assist torque adds to a two-wheeler's steering",
                    "additionalProperties": {"type": "string", "enum": list(DRIVER_SOURCES)}},
        "user": {"title": "the user command source (rtsim view, control op drive)", "type": "object",
                 "properties": {
                     "channels": {"type": "object", "description": "channels the user drives now, SI values",
                                  "additionalProperties": {"type": "number"}},
                     "takeover": {"type": "boolean", "description": "the user has taken over from the bus ECU"},
                     "seq": {"type": ["integer", "null"], "description": "sequence number of the last request"},
                     "requests": _count("drive requests taken"),
                     "lapses": _count("times the user's channels were handed back because no request came "
                                      "within the hold (rtsim.service.user_input.USER_HOLD s of wall time)"),
                     "accepted": {"type": "boolean", "description": "the service accepts user commands"}},
                 "required": ["channels", "takeover", "seq", "requests", "accepted"],
                 "additionalProperties": False},
        # (optional: absent from recordings made before the second-simulator check)
        "foreign_frames": _count("frames with one of this simulator's own ids (sensor, status, diagnostics, "
                                 "acknowledgement) that it did not send (faults.second_sim)"),
        "model_fault": {"type": ["object", "null"], "description": "the vehicle model's failure while run_state "
                        "is model_fault (rtsim.model_fault.ModelFault), else null",
                        "properties": {"reason_code": {"type": "integer", "description": "the failed step's status "
                                                       "(SIM_DIAG.model_fault_reason)"},
                                       "reason": {"type": "string", "description": "its name (the DBC's)"},
                                       "message": {"type": "string", "description": "the model's message"},
                                       "step": {"type": "integer", "description": "the failed step's number"},
                                       "sim_time": _seconds("simulation time the failed step was to end at",
                                                            nullable=False),
                                       "coordinate": {"type": "string", "description": "the generalized "
                                                      "coordinate the failure names, empty if none"}},
                        "required": ["reason_code", "reason", "message", "step", "sim_time", "coordinate"]},
        # (optional: absent from recordings made before the user command source existed)
        "injected_faults": {"type": "object", "description": "the faults armed in the session (rtsim.faults)",
                            "properties": {
                                "faults": {"type": "array", "description": "one object per fault: id, kind, "
                                           "target, state (armed, active, ended), onset_time and end_time (s, "
                                           "null until they happened)"},
                                "lost_out": _count("frames the simulator did not send because of a fault"),
                                "lost_in": _count("received frames a fault took (lost, bus off)")},
                            "required": ["faults", "lost_out", "lost_in"]},
    }


def schemas_for(channels: ChannelDictionary = CAR) -> dict[str, tuple[str, dict]]:
    """topic key -> (schema name, JSON schema) of a vehicle's channel dictionary."""
    sensors = {"time": _TIME, **{c.name: _signal(c.unit, c.description) for c in channels.sensors}}
    state = {"time": _TIME, **{c.name: _signal(c.unit, c.description) for c in channels.state}}
    commands = {"time": _TIME, **{c.name: _signal(c.unit, c.description) for c in channels.commands},
                "source": {"type": "string", "enum": list(COMMAND_SOURCES),
                           "description": "where the applied values came from: can (the ECU), "
                                          "zenoh (a control request) or safe (watchdog fallback)"}}
    status = _status_props()
    can = {
        "id": {"type": "integer", "minimum": 0, "description": "CAN arbitration id"},
        "dlc": {"type": "integer", "minimum": 0, "description": "data length code (bytes)"},
        "data": {"type": "string", "description": "frame payload, hexadecimal, 2 digits per byte"},
        "time": _TIME,
        # (optional: written only when true; absent from recordings made before they existed)
        "extended": {"type": "boolean", "description": "an extended (29-bit) id frame"},
        "remote": {"type": "boolean", "description": "a remote frame (no data)"},
        "fd": {"type": "boolean", "description": "a CAN FD frame"},
    }
    energy = {"time": _TIME, **{c.name: _signal(c.unit, c.description) for c in ENERGY}}
    order = {"type": "integer", "minimum": 0, "description": "the service's count of recorded events (user and "
                                                            "control) before this one: their order across both topics"}
    user = {
        "time": {"type": "number", "description": "simulation time at which the loop applied the change; it acts "
                                                  "on the steps after it [s]"},
        "step": {"type": "integer", "minimum": 0, "description": "the loop's step count when it applied the change "
                                                               "(time = step * dt)"},
        "cause": {"type": "string", "enum": list(USER_CAUSES),
                  "description": "drive (a request's values or takeover), release (the page handed the vehicle "
                                 "back), lapse (no request for the hold time)"},
        "channels": {"type": "object", "description": "every user channel of the vehicle (rtsim.service.user_input): "
                                                     "its value in SI units, null where the user does not drive it",
                     "additionalProperties": {"type": _NUM_OR_NULL}},
        "takeover": {"type": "boolean", "description": "the user has taken over from the bus ECU"},
        "seq": {"type": ["integer", "null"], "description": "sequence number of the page's last request"},
        "order": order,
    }
    control = {
        "time": {"type": "number", "description": "simulation time when the loop took the request (before a step "
                                                  "ran, before a reset restarted time) [s]"},
        "step": {"type": "integer", "minimum": 0, "description": "the loop's step count when it took the request"},
        "op": {"type": "string", "enum": list(CONTROL_OPS), "description": "the control op (rtsim serve's control key)"},
        "args": {"type": "object", "description": "the request's arguments: step {n}; driver {channel: value | null} "
                                                  "(SI units); reset and load_scenario {scenario: name}; "
                                                  "inject_fault: a fault spec ([[faults]] keys); clear_fault {id}"},
        "order": order,
    }
    faults = {
        "time": {"type": "number", "description": "simulation time of the onset or end (step * dt) [s]"},
        "step": {"type": "integer", "minimum": 0, "description": "the step of the onset or end"},
        "id": {"type": "string", "description": "the fault's id"},
        "kind": {"type": "string", "description": "its kind (rtsim faults --list)"},
        "target": {"type": ["string", "integer"], "description": "its target: channel, frame, bus or actuator"},
        "event": {"type": "string", "enum": list(FAULT_EVENTS), "description": "onset: it acts from this step on; "
                                                                             "end: from this step on no more"},
        "order": order,
    }
    return {
        "sensors": ("rtsim.sensors", _obj("rtsim sensors", sensors, sensors)),
        "state": ("rtsim.state", _obj("rtsim state", state, state)),
        "status": ("rtsim.status", _obj("rtsim service status", status,
                                        [k for k in status if k not in STATUS_OPTIONAL])),
        "commands": ("rtsim.commands", _obj("rtsim applied actuator commands (after the watchdog)",
                                            commands, ["time", "source"])),
        # one schema (one name) for both directions: MCAP registers a schema name once
        "can/rx": ("rtsim.can_frame", _obj("rtsim CAN frame", can, ["id", "dlc", "data", "time"])),
        "can/tx": ("rtsim.can_frame", _obj("rtsim CAN frame", can, ["id", "dlc", "data", "time"])),
        "user": ("rtsim.user", _obj("rtsim user command source changes (rtsim view, control op drive)", user,
                                    [k for k in user if k != "order"])),
        "control": ("rtsim.control", _obj("rtsim control requests that changed the run (pause, resume, step, driver, "
                                          "reset, load_scenario)", control, list(control))),
        "faults": ("rtsim.faults", _obj("rtsim injected faults: onsets and ends (rtsim.faults)", faults,
                                        list(faults))),
        "energy": ("rtsim.energy", _obj("rtsim power audit (offline runs)", energy, ["time"])),
    }


#: topic key -> (schema name, JSON schema). Treat as read-only.
SCHEMAS: dict[str, tuple[str, dict]] = schemas_for(CAR)


# ----------------------------------------------------------------------------------------- encoders

def _template(names, spec: str) -> str:
    return "{" + ",".join(f'"{n}":{spec}' for n in names) + "}"


_TEMPLATES: dict[tuple[tuple[str, ...], int | None], tuple[str, str]] = {}


def _templates(names: tuple[str, ...], digits: int | None) -> tuple[str, str]:
    """(all-finite template, template of preformatted strings); time is always exact (%r)."""
    key = (names, digits)
    tpl = _TEMPLATES.get(key)
    if tpl is None:
        if digits is not None and not (isinstance(digits, int) and 1 <= digits <= 17):
            raise ValueError(f"digits must be an integer in 1..17 or None, got {digits!r}")
        spec = "%r" if digits is None else f"%.{digits}g"
        tpl = _TEMPLATES[key] = ('{"time":%r,' + _template(names, spec)[1:],
                                 '{"time":%s,' + _template(names, "%s")[1:])
    return tpl


def _encode_row(names: tuple[str, ...], t: float, values, digits: int | None) -> bytes:
    template, template_s = _templates(names, digits)
    if isinstance(values, np.ndarray):
        vals = (values if values.dtype == np.float64 else values.astype(np.float64)).tolist()
    else:
        vals = [float(v) for v in values]
    if len(vals) != len(names):
        raise ValueError(f"expected {len(names)} values ({names[0]}..{names[-1]}), got {len(vals)}")
    t = float(t)
    # One float sum tells whether every value is finite (NaN and inf propagate); an overflow of
    # finite values only sends us down the exact per-value path below.
    if math.isfinite(t + sum(vals)):
        return (template % (t, *vals)).encode()
    spec = "%r" if digits is None else f"%.{digits}g"
    parts = [repr(t) if math.isfinite(t) else "null"]
    parts += [spec % v if math.isfinite(v) else "null" for v in vals]
    return (template_s % tuple(parts)).encode()


def encode_sensors(t: float, values, digits: int | None = None, names: tuple[str, ...] = SENSOR_NAMES) -> bytes:
    """One ``sensors`` message: ``t`` (s) and the sensor values in the order of `names` (the vehicle's
    sensor channels; default the rear-drive car's) (SI units; NaN/inf become null). ``digits=None``
    writes each value's shortest exact (round-trip) decimal; ``digits=N`` rounds to N significant
    digits, about 3x cheaper."""
    return _encode_row(names, t, values, digits)


def encode_state(t: float, values, digits: int | None = None, names: tuple[str, ...] = STATE_NAMES) -> bytes:
    """One ``state`` message: ``t`` (s) and the values in the order of `names` (the vehicle's state
    channels; default the car's) (``digits`` as for :func:`encode_sensors`)."""
    return _encode_row(names, t, values, digits)


def _finite(x):
    """Copy of ``x`` with non-finite floats replaced by None and numpy values made plain."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (np.ndarray, np.generic)):
        return _finite(x.tolist())
    return x


def _default(obj):
    if isinstance(obj, (np.ndarray, np.generic)):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


_ENCODER = json.JSONEncoder(allow_nan=False, separators=(",", ":"), default=_default).encode


def encode_json(obj: dict) -> bytes:
    """Compact JSON of a dict (numpy scalars and arrays allowed); NaN/inf become null."""
    try:
        return _ENCODER(obj).encode()
    except ValueError:          # NaN / inf somewhere: not JSON, write them as null
        return _ENCODER(_finite(obj)).encode()


def decode(payload) -> dict:
    """The dict of one JSON message (bytes, bytearray, memoryview, str or a zenoh ZBytes).
    Raises RtsimError when it is not a JSON object."""
    if not isinstance(payload, (bytes, bytearray, str)):
        payload = bytes(payload)
    try:
        obj = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as e:
        raise RtsimError(f"payload is not JSON: {e}") from None
    if not isinstance(obj, dict):
        raise RtsimError(f"payload is JSON but not an object: {type(obj).__name__}")
    return obj


# ----------------------------------------------------------------------------------------- validation

_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "integer": lambda v: (isinstance(v, int) and not isinstance(v, bool))
    or (isinstance(v, float) and v.is_integer()),
}
_KNOWN = {"type", "properties", "required", "additionalProperties", "enum", "minimum", "title",
          "description"}


def validation_errors(schema: dict | str, obj, path: str = "$") -> list[str]:
    """Errors of ``obj`` against a JSON schema (or a topic key of SCHEMAS), one string each.

    Implements the subset SCHEMAS uses: type (one or a list), properties, required,
    additionalProperties (bool or schema), enum, minimum; any other keyword is an error so that a
    schema cannot silently outgrow the validator."""
    if isinstance(schema, str):
        schema = SCHEMAS[schema][1]
    unknown = set(schema) - _KNOWN
    if unknown:
        return [f"{path}: schema keyword(s) not supported by this validator: {sorted(unknown)}"]
    types = schema.get("type")
    if types is not None:
        types = [types] if isinstance(types, str) else types
        if not any(_TYPES[t](obj) for t in types):
            return [f"{path}: {obj!r} is not of type {' or '.join(types)}"]
    errors = []
    if "enum" in schema and obj not in schema["enum"]:
        errors.append(f"{path}: {obj!r} is not one of {schema['enum']}")
    if "minimum" in schema and _TYPES["number"](obj) and obj < schema["minimum"]:
        errors.append(f"{path}: {obj!r} is below the minimum {schema['minimum']}")
    if isinstance(obj, dict):
        props = schema.get("properties", {})
        for name in schema.get("required", ()):
            if name not in obj:
                errors.append(f"{path}: missing required property {name!r}")
        extra = schema.get("additionalProperties", True)
        for name, value in obj.items():
            sub = f"{path}.{name}"
            if name in props:
                errors += validation_errors(props[name], value, sub)
            elif extra is False:
                errors.append(f"{sub}: property not allowed")
            elif isinstance(extra, dict):
                errors += validation_errors(extra, value, sub)
    return errors


def validate(key: str, obj) -> None:
    """Raise RtsimError naming every problem of payload ``obj`` (a dict) on topic ``key``."""
    if key not in SCHEMAS:
        raise RtsimError(f"unknown topic key {key!r}; allowed: {', '.join(TOPIC_KEYS)}")
    errors = validation_errors(key, obj)
    if errors:
        raise RtsimError(f"{key} payload invalid: " + "; ".join(errors))


# ----------------------------------------------------------------------------------------- files

def schema_files(channels: ChannelDictionary = CAR) -> dict[str, str]:
    """Relative file name (``<key>.json``) -> file text for every topic's schema of a vehicle with the
    channel dictionary `channels` (default the rear-drive car's: the committed schemas/ files)."""
    schemas = schemas_for(channels)
    return {f"{key}.json": json.dumps(schemas[key][1], indent=2) + "\n" for key in TOPIC_KEYS + EVENT_TOPIC_KEYS}


def write_schemas(directory: str | Path, channels: ChannelDictionary = CAR) -> list[Path]:
    """Write :func:`schema_files` of `channels` into ``directory`` (created if needed); returns the paths."""
    out = []
    for rel, text in schema_files(channels).items():
        p = Path(directory) / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
        out.append(p)
    return out


def _bench() -> None:
    import timeit
    rng = np.random.default_rng(0)
    sens, state = rng.normal(size=len(SENSOR_NAMES)), rng.normal(size=len(STATE_NAMES)) * 1e3
    state_nan = state.copy()
    state_nan[3] = np.nan
    status = {"time": 1.0, "vehicle_id": "xbw", "mode": "realtime", "run_state": "running",
              "sim_time": 1.0, "steps": 1000, "overruns": 0, "skipped_steps": 0, "catch_up_steps": 0,
              "stalls": 0, "lateness_p50": 1e-6, "lateness_p99": 2e-4, "lateness_max": 1e-3,
              "cpu_p50": 3e-5, "cpu_p99": 6e-5, "cpu_max": 1e-4, "steal": None,
              "faults": dict.fromkeys(FAULTS, False), "rejected": dict.fromkeys(REJECTIONS, 0),
              "accepted_frames": 0, "bus_errors": 0, "recorder": None, "zenoh_dropped": 0,
              "scenario": None, "message": ""}
    cmds = {"time": 1.0, "throttle_angle_cmd": 0.1, "brake_pressure_cmd": 0.0,
            "steering_wheel_angle_cmd": -0.2, "source": "can"}
    cases = {
        f"encode_sensors ({len(SENSOR_NAMES)} values)": lambda: encode_sensors(1.234, sens),
        f"encode_state ({len(STATE_NAMES)} values)": lambda: encode_state(1.234, state),
        "encode_state with one NaN": lambda: encode_state(1.234, state_nan),
        "encode_sensors, digits=9": lambda: encode_sensors(1.234, sens, digits=9),
        "encode_state, digits=9": lambda: encode_state(1.234, state, digits=9),
        "encode_json (commands)": lambda: encode_json(cmds),
        "encode_json (status)": lambda: encode_json(status),
        "decode (sensors)": (lambda b=encode_sensors(1.0, sens): decode(b)),
    }
    for name, fn in cases.items():
        n = 20000
        best = min(timeit.repeat(fn, number=n, repeat=5)) / n
        print(f"{name:<36} {best * 1e6:6.2f} us")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bridge.payloads", description=__doc__.split("\n")[0])
    ap.add_argument("--write-schemas", metavar="DIR", help="write one <key>.json schema per topic")
    ap.add_argument("--vehicle", metavar="FILE", help="vehicle config whose channels the schemas describe "
                                                     "(default: the rear-drive car's, as in schemas/)")
    ap.add_argument("--bench", action="store_true", help="time the encoders (best of 5)")
    args = ap.parse_args(argv)
    if args.write_schemas:
        channels = CAR
        if args.vehicle:
            from rtsim.vehicle.car.build import build_vehicle     # the vehicle layer, only when asked
            from rtsim.vehicle.car.config import load_vehicle
            channels = build_vehicle(*load_vehicle(args.vehicle)).channels
        for p in write_schemas(args.write_schemas, channels):
            print(p)
    if args.bench:
        _bench()
    if not (args.write_schemas or args.bench):
        ap.print_usage(sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
