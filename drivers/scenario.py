"""Scenarios: one manoeuvre per TOML file (configs/scenarios/), validated on load.

Format (SI units throughout: s, m, m/s, rad, kPa, N*m; relative file paths are relative to the
scenario file; ranges inclusive unless marked <):

    name = "step_steer_80kph"        # identifier: letters, digits, '_' and '-'
    description = "..."              # free text
    vehicle = "../vehicles/x.toml"   # optional: vehicle configuration replacing the default one
    road = "../roads/flat.toml"      # road configuration (checked to exist only with check_files)
    duration = 6.0                   # s, simulated time                   0 < duration <= 3600
    dt = 0.001                       # s, integrator step                  1e-5 .. 0.01 (default 0.001)
    output_rate = 100.0              # Hz, rate of logged outputs          0 < output_rate <= 1/dt (100)

    [initial]                        # initial state (each defaults to 0)
    speed = 22.22                    # m/s, forward                        0 .. 100
    x = 0.0                          # m, road frame                       -1e6 .. 1e6
    y = 0.0                          # m
    yaw = 0.0                        # rad, from the road x axis, left +   -2 pi .. 2 pi

    [inputs.<channel>]               # an open-loop profile for a channel:
                                     #   throttle_angle_cmd (rad), brake_pressure_cmd (kPa),
                                     #   steering_wheel_angle_cmd (rad, positive steers left)
    [inputs.speed_follower]          # closed loop, drives throttle_angle_cmd and brake_pressure_cmd
    [inputs.path_follower]           # closed loop, drives steering_wheel_angle_cmd
                                     # a channel with neither stays 0; one with both is an error

    [torque_mode]                    # optional: drive with wheel torques instead of the engine (the
    wheel_torque_rl = {...}          #   seed validation's inputs); both are profiles, N*m; the
    wheel_torque_rr = {...}          #   throttle and the speed follower are then not allowed

    [reference]                      # optional, informational: what the manoeuvre should produce
    distance = 63.5                  #   (for validation reports); any key = number

Profiles (`type` selects; see `drivers.profiles` for the exact semantics; times in s):

    type = "constant"   value
    type = "table"      time = [...], value = [...]  (time strictly increasing), hold = false
                        (true: zero-order hold); ends are held
    type = "step"       t0, after, before = 0, ramp = 0 (s from before to after)
    type = "ramp"       t0, t1, v0 = 0, v1 (or rate instead of v1); without t1: t0, v0, rate (for ever)
    type = "pulse"      t0, value, rise, width, fall, base = 0 (a trapezoid)
    type = "sine"       amplitude (>= 0), frequency (Hz, 0 < f <= 100), phase = 0 (rad, -2 pi .. 2 pi),
                        t0 = 0 (start), offset = 0 (the value before t0 and the sine's centre),
                        fade_cycles = 0 (periods over which the amplitude rises from 0, 0 .. 1000)
    type = "sum"        [[...terms]]: profiles added
    type = "sequence"   [[...segments]]: profiles one after another, each with `duration` (s; the
                        last may omit it: for ever), each on its own clock starting at 0
    type = "replay"     file (CSV, see `drivers.replay`), column (default: the channel's name or its
                        sensor name, e.g. brake_pressure), hold = false (true: zero-order hold),
                        start (recording time played at t = 0; default: its first sample)

Speed follower (`drivers.speed_follower`): `time = [...]` or `distance = [...]` (m, odometer) and
`speed = [...]` (m/s, 0 .. 100), the target table; optional controller parameters by the names of
`SpeedFollowerParams` (kp, ki, kd, tau_d, throttle_gain, throttle_max, brake_gain, brake_max, band,
hold_pressure, hold_rate, v_stop, v_eps, i_max, a_res0, a_res2, ff_gain; allowed ranges in
`SPEED_FOLLOWER_RANGES`).

Path follower (`drivers.path_follower`): `x = [...]`, `y = [...]` (m) or `file` (CSV with columns x
and y), `closed = false`, `method = "pure_pursuit"` or `"stanley"`; optional parameters by the names
of `PathFollowerParams` (wheelbase, steering_ratio, la_min, la_gain, la_max, k_stanley, v_soft,
max_wheel_angle, max_rate, rear_offset; ranges in `PATH_FOLLOWER_RANGES`).

Errors. Every problem raises `ConfigError` with one line naming the file, the key (dotted, list
items as [i]), the value and what is allowed, for example

    configs/scenarios/x.toml: duration = -1.0: out of range (allowed 0 < duration <= 3600 s)
    configs/scenarios/x.toml: inputs.throttle_cmd = {...}: unknown key (allowed: throttle_angle_cmd, ...)

Besides each key's own range, profiles are sampled at dt over the whole duration and must stay within
the channel's range (`drivers.base.LIMITS`); replay files are read and checked at load.

Use: `sc = load_scenario(path)`; `sc.driver()` builds a fresh `Driver`; `sc.initial_state()` the
state array the closed-loop drivers read; `sc.road_path` / `sc.vehicle_path` are resolved paths.
"""

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal, Optional, Union

import numpy as np
from pydantic import Field, StrictBool, create_model, model_validator

from rtsim.configfile import Range, Strict, bad, load, problem, range_fields
from rtsim.errors import ConfigError

from .base import INPUT_NAMES, INPUT_UNITS, LIMITS, NSTATE, S_SPEED, S_X, S_Y
from .base import S_YAW, SENSOR_ALIASES, input_name
from .driver import Driver
from .path_follower import PATH_FOLLOWER_RANGES, PathFollowerParams, path_follower
from .profiles import Profile, pack, sample
from . import profiles as P
from .replay import Recording, parse_column, read_csv_table, read_recording, replay_profiles
from .speed_follower import SPEED_FOLLOWER_RANGES, SpeedFollowerParams, speed_follower

SCENARIO_DIR = Path(__file__).resolve().parents[1] / "configs" / "scenarios"

# ---------------------------------------------------------------------------------------------------
# Value types with ranges that report the whole allowed range


Num = Range(-1e9, 1e9)               # any finite value (channel ranges are checked after)
Time = Range(-1e5, 1e5, "s")         # a point in time
Dur = Range(0.0, 1e5, "s")           # a length of time
PosDur = Range(0.0, 1e5, "s", lo_open=True)
Coord = Range(-1e6, 1e6, "m")
TimeAxis = Range(0.0, 1e5, "s")
DistAxis = Range(0.0, 1e7, "m")
Speed = Range(0.0, 100.0, "m/s")
Yaw = Range(-2.0 * math.pi, 2.0 * math.pi, "rad")
Duration = Range(0.0, 3600.0, "s", lo_open=True)
Step = Range(1e-5, 0.01, "s")
Rate = Range(0.0, 1e4, "Hz", lo_open=True)
Amplitude = Range(0.0, 1e9)
Frequency = Range(0.0, 100.0, "Hz", lo_open=True)
Phase = Range(-2.0 * math.pi, 2.0 * math.pi, "rad")
Cycles = Range(0.0, 1000.0, "cycles")

def _param_fields(ranges: dict, defaults) -> dict:
    return range_fields(ranges, {n: getattr(defaults, n) for n in ranges})


_Model = Strict          # the one config base (rtsim.configfile): unknown keys listed, immutable
_bad = bad


def _increasing(name: str, xs: list[float]) -> None:
    for i in range(1, len(xs)):
        if not xs[i] > xs[i - 1]:
            raise _bad(f"{name}[{i}]", xs[i], f"must be greater than {name}[{i - 1}] = {xs[i - 1]!r} "
                       f"(strictly increasing)")


# ---------------------------------------------------------------------------------------------------
# Profiles


class _Profile(_Model):
    duration: Optional[PosDur] = None   # only in sequence segments


class ConstantSpec(_Profile):
    type: Literal["constant"]
    value: Num


class TableSpec(_Profile):
    type: Literal["table"]
    time: list[Time] = Field(min_length=1)
    value: list[Num] = Field(min_length=1)
    hold: StrictBool = False

    @model_validator(mode="after")
    def _check(self):
        if len(self.time) != len(self.value):
            raise _bad("value", f"<{len(self.value)} values>", f"must have as many entries as time "
                       f"({len(self.time)})")
        _increasing("time", self.time)
        return self


class StepSpec(_Profile):
    type: Literal["step"]
    t0: Time
    after: Num
    before: Num = 0.0
    ramp: Dur = 0.0


class RampSpec(_Profile):
    type: Literal["ramp"]
    t0: Time
    t1: Optional[Time] = None
    v0: Num = 0.0
    v1: Optional[Num] = None
    rate: Optional[Num] = None

    @model_validator(mode="after")
    def _check(self):
        if self.t1 is None:
            if self.rate is None:
                raise _bad("rate", None, "missing: a ramp without end time t1 needs a rate")
            if self.v1 is not None:
                raise _bad("v1", self.v1, "not allowed without an end time t1 (give t1, or a rate only)")
        else:
            if self.t1 < self.t0:
                raise _bad("t1", self.t1, f"must be >= t0 = {self.t0!r} s")
            if (self.v1 is None) == (self.rate is None):
                raise _bad("v1", self.v1, "give exactly one of v1 and rate")
        return self


class PulseSpec(_Profile):
    type: Literal["pulse"]
    t0: Time
    value: Num
    rise: Dur
    width: Dur
    fall: Dur
    base: Num = 0.0


class SineSpec(_Profile):
    type: Literal["sine"]
    amplitude: Amplitude
    frequency: Frequency
    phase: Phase = 0.0
    t0: Time = 0.0
    offset: Num = 0.0
    fade_cycles: Cycles = 0.0


class SumSpec(_Profile):
    type: Literal["sum"]
    terms: list["ProfileSpec"] = Field(min_length=1)


class SequenceSpec(_Profile):
    type: Literal["sequence"]
    segments: list["ProfileSpec"] = Field(min_length=1)


class ReplaySpec(_Profile):
    type: Literal["replay"]
    file: str = Field(min_length=1)
    column: Optional[str] = None
    hold: StrictBool = False
    start: Optional[Time] = None


ProfileSpec = Annotated[
    Union[ConstantSpec, TableSpec, StepSpec, RampSpec, PulseSpec, SineSpec, SumSpec, SequenceSpec, ReplaySpec],
    Field(discriminator="type")]
PROFILE_TYPES = ("constant", "table", "step", "ramp", "pulse", "sine", "sum", "sequence", "replay")
SumSpec.model_rebuild()
SequenceSpec.model_rebuild()


# ---------------------------------------------------------------------------------------------------
# Closed-loop drivers


class _SpeedFollowerBase(_Model):
    time: Optional[list[TimeAxis]] = None
    distance: Optional[list[DistAxis]] = None
    speed: list[Speed] = Field(min_length=1)

    @model_validator(mode="after")
    def _check(self):
        if (self.time is None) == (self.distance is None):
            raise _bad("time", self.time, "give exactly one of time and distance (the target table's axis)")
        axis = "time" if self.time is not None else "distance"
        xs = self.time if self.time is not None else self.distance
        if len(xs) != len(self.speed):
            raise _bad("speed", f"<{len(self.speed)} values>", f"must have as many entries as {axis} ({len(xs)})")
        _increasing(axis, xs)
        return self

    def params(self) -> SpeedFollowerParams:
        return SpeedFollowerParams(**{n: getattr(self, n) for n in SPEED_FOLLOWER_RANGES})


SpeedFollowerSpec = create_model("SpeedFollowerSpec", __base__=_SpeedFollowerBase,
                                 **_param_fields(SPEED_FOLLOWER_RANGES, SpeedFollowerParams))


class _PathFollowerBase(_Model):
    method: Literal["pure_pursuit", "stanley"] = "pure_pursuit"
    x: Optional[list[Coord]] = None
    y: Optional[list[Coord]] = None
    file: Optional[str] = None
    closed: StrictBool = False

    @model_validator(mode="after")
    def _check(self):
        if self.file is None:
            if self.x is None or self.y is None:
                raise _bad("x", self.x, "give the path as x and y lists, or a file")
            if len(self.x) != len(self.y):
                raise _bad("y", f"<{len(self.y)} values>", f"must have as many entries as x ({len(self.x)})")
            if len(self.x) < 2:
                raise _bad("x", self.x, "a path needs at least 2 points")
        elif self.x is not None or self.y is not None:
            raise _bad("file", self.file, "give the path either as x and y lists or as a file, not both")
        try:
            self.params()               # the parameters' own checks across keys (PathFollowerParams)
        except ValueError as exc:
            raise _bad("la_max", self.la_max, str(exc).rpartition(": ")[2]) from None
        return self

    def params(self) -> PathFollowerParams:
        return PathFollowerParams(**{n: getattr(self, n) for n in PATH_FOLLOWER_RANGES})


PathFollowerSpec = create_model("PathFollowerSpec", __base__=_PathFollowerBase,
                                **_param_fields(PATH_FOLLOWER_RANGES, PathFollowerParams))


class InputsSpec(_Model):
    throttle_angle_cmd: Optional[ProfileSpec] = None
    brake_pressure_cmd: Optional[ProfileSpec] = None
    steering_wheel_angle_cmd: Optional[ProfileSpec] = None
    speed_follower: Optional[SpeedFollowerSpec] = None
    path_follower: Optional[PathFollowerSpec] = None

    @model_validator(mode="after")
    def _check(self):
        if self.speed_follower is not None:
            for ch in ("throttle_angle_cmd", "brake_pressure_cmd"):
                if getattr(self, ch) is not None:
                    raise _bad(ch, getattr(self, ch).type, "not allowed with speed_follower, which drives "
                               "throttle_angle_cmd and brake_pressure_cmd")
        if self.path_follower is not None and self.steering_wheel_angle_cmd is not None:
            raise _bad("steering_wheel_angle_cmd", self.steering_wheel_angle_cmd.type,
                       "not allowed with path_follower, which drives steering_wheel_angle_cmd")
        return self


class TorqueModeSpec(_Model):
    wheel_torque_rl: ProfileSpec
    wheel_torque_rr: ProfileSpec


class InitialSpec(_Model):
    speed: Speed = 0.0
    x: Coord = 0.0
    y: Coord = 0.0
    yaw: Yaw = 0.0


class ScenarioSpec(_Model):
    name: str = Field(pattern=r"^[A-Za-z0-9_-]+$")
    description: str = ""
    vehicle: Optional[str] = None
    road: str = Field(min_length=1)
    duration: Duration
    dt: Step = 0.001
    output_rate: Rate = 100.0
    initial: InitialSpec = InitialSpec()
    inputs: InputsSpec = InputsSpec()
    torque_mode: Optional[TorqueModeSpec] = None
    reference: dict[str, Num] = {}

    @model_validator(mode="after")
    def _check(self):
        if self.output_rate * self.dt > 1.0 + 1e-9:
            raise _bad("output_rate", self.output_rate, f"must be <= 1/dt = {1.0 / self.dt:g} Hz")
        if self.duration < self.dt:
            raise _bad("duration", self.duration, f"must be >= dt = {self.dt!r} s")
        if self.torque_mode is not None:
            if self.inputs.throttle_angle_cmd is not None:
                raise _bad("inputs.throttle_angle_cmd", self.inputs.throttle_angle_cmd.type,
                           "not allowed in torque mode (the wheel torques replace the engine)")
            if self.inputs.speed_follower is not None:
                raise _bad("inputs.speed_follower", "...", "not allowed in torque mode (it drives the throttle)")
        return self


# ---------------------------------------------------------------------------------------------------
# Error messages


def _fail(file: Path, key: str, value: Any, reason: str) -> ConfigError:
    return problem(file, key, value, reason)


# ---------------------------------------------------------------------------------------------------
# The loaded scenario


@dataclass
class Scenario:
    """A validated scenario: the spec, its resolved files and the profiles of its channels."""
    path: Path
    spec: ScenarioSpec
    road_path: Path
    vehicle_path: Path | None
    profiles: dict[str, Profile] = field(default_factory=dict)
    recordings: dict[Path, Recording] = field(default_factory=dict)
    path_xy: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def duration(self) -> float:
        return self.spec.duration

    @property
    def dt(self) -> float:
        return self.spec.dt

    @property
    def torque_mode(self) -> bool:
        return self.spec.torque_mode is not None

    def initial_state(self) -> np.ndarray:
        """The state array the closed-loop drivers read (`drivers.base.S_*`) at t = 0."""
        s = np.zeros(NSTATE)
        ini = self.spec.initial
        s[S_SPEED], s[S_X], s[S_Y], s[S_YAW] = ini.speed, ini.x, ini.y, ini.yaw
        return s

    def driver(self) -> Driver:
        """A fresh driver (its own controller state) for this scenario."""
        inp = self.spec.inputs
        sf = pf = None
        if inp.speed_follower is not None:
            spec = inp.speed_follower
            by = "time" if spec.time is not None else "distance"
            sf = speed_follower(spec.time if spec.time is not None else spec.distance, spec.speed, by=by,
                                params=spec.params())
        if inp.path_follower is not None:
            spec = inp.path_follower
            x, y = self.path_xy
            pf = path_follower(x, y, method=spec.method, closed=spec.closed, params=spec.params())
        return Driver(self.profiles, speed=sf, path=pf)


def load_scenario(path: str | Path, check_files: bool = False) -> Scenario:
    """Load and validate a scenario file; ConfigError on any problem (see the module docstring).
    check_files: also require the road and vehicle files to exist."""
    path = Path(path)
    spec = load(ScenarioSpec, path)

    base = path.parent
    road = (base / spec.road).resolve()
    vehicle = (base / spec.vehicle).resolve() if spec.vehicle else None
    if check_files:
        if not road.is_file():
            raise _fail(path, "road", spec.road, f"file not found ({road})")
        if vehicle is not None and not vehicle.is_file():
            raise _fail(path, "vehicle", spec.vehicle, f"file not found ({vehicle})")
    sc = Scenario(path, spec, road, vehicle)

    channels: dict[str, tuple[str, Any]] = {}
    for ch in INPUT_NAMES[:3]:
        s = getattr(spec.inputs, ch)
        if s is not None:
            channels[ch] = (f"inputs.{ch}", s)
    if spec.torque_mode is not None:
        for ch in INPUT_NAMES[3:]:
            channels[ch] = (f"torque_mode.{ch}", getattr(spec.torque_mode, ch))
    for ch, (key, s) in channels.items():
        _check_durations(path, key, s, top=True)
        _check_values(path, key, ch, s)
        sc.profiles[ch] = _build(sc, key, ch, s)
    _check_sampled(sc, channels)

    if spec.inputs.path_follower is not None:
        pfs = spec.inputs.path_follower
        if pfs.file is not None:
            sc.path_xy = _read_path(path, base / pfs.file, pfs.file)
        else:
            sc.path_xy = (np.array(pfs.x), np.array(pfs.y))
        try:  # geometry errors (coincident points) surface at load
            path_follower(*sc.path_xy, method=pfs.method, closed=pfs.closed, params=pfs.params())
        except ValueError as exc:
            raise _fail(path, "inputs.path_follower", pfs.file or "<x, y>", str(exc)) from None
    return sc


def load_all(directory: str | Path = SCENARIO_DIR, check_files: bool = False) -> dict[str, Scenario]:
    """Every *.toml scenario of a directory, by name."""
    out = {}
    for f in sorted(Path(directory).glob("*.toml")):
        sc = load_scenario(f, check_files=check_files)
        out[sc.name] = sc
    return out


# ---------------------------------------------------------------------------------------------------
# Checks and construction


def _check_durations(file: Path, key: str, s: Any, top: bool = False, segment: bool = False,
                     last: bool = False) -> None:
    if segment:
        if s.duration is None and not last:
            raise _fail(file, f"{key}.duration", None, "missing: every sequence segment but the last needs "
                        "a duration (s)")
    elif s.duration is not None:
        raise _fail(file, f"{key}.duration", s.duration, "only allowed in the segments of a sequence")
    if isinstance(s, SumSpec):
        for i, t in enumerate(s.terms):
            _check_durations(file, f"{key}.terms[{i}]", t)
    elif isinstance(s, SequenceSpec):
        n = len(s.segments)
        for i, t in enumerate(s.segments):
            _check_durations(file, f"{key}.segments[{i}]", t, segment=True, last=i == n - 1)


def _check_values(file: Path, key: str, ch: str, s: Any) -> None:
    """Values given directly for a channel must lie in its range (sums are checked sampled)."""
    lo, hi = LIMITS[ch]
    unit = INPUT_UNITS[ch]

    def check(k: str, v: float | None) -> None:
        if v is not None and not lo <= v <= hi:
            raise _fail(file, f"{key}.{k}", v, f"out of range for {ch} (allowed {lo:g} .. {hi:g} {unit})")

    if isinstance(s, ConstantSpec):
        check("value", s.value)
    elif isinstance(s, TableSpec):
        for i, v in enumerate(s.value):
            check(f"value[{i}]", v)
    elif isinstance(s, StepSpec):
        check("before", s.before)
        check("after", s.after)
    elif isinstance(s, RampSpec):
        check("v0", s.v0)
        check("v1", s.v1)
    elif isinstance(s, PulseSpec):
        check("base", s.base)
        check("value", s.value)
    elif isinstance(s, SineSpec):
        check("offset", s.offset)
        for extreme in (s.offset - s.amplitude, s.offset + s.amplitude):
            if not lo <= extreme <= hi:
                raise _fail(file, f"{key}.amplitude", s.amplitude, f"offset {s.offset:+g} +- amplitude reaches "
                            f"{extreme:g}, out of range for {ch} (allowed {lo:g} .. {hi:g} {unit})")
    elif isinstance(s, SequenceSpec):
        for i, t in enumerate(s.segments):
            _check_values(file, f"{key}.segments[{i}]", ch, t)


def _build(sc: Scenario, key: str, ch: str, s: Any) -> Profile:
    try:
        if isinstance(s, ConstantSpec):
            return P.constant(s.value)
        if isinstance(s, TableSpec):
            return P.table(s.time, s.value, hold=s.hold)
        if isinstance(s, StepSpec):
            return P.step(s.t0, s.after, before=s.before, ramp=s.ramp)
        if isinstance(s, RampSpec):
            return P.ramp(s.t0, s.t1, v0=s.v0, v1=s.v1, rate=s.rate)
        if isinstance(s, PulseSpec):
            return P.pulse(s.t0, s.value, s.rise, s.width, s.fall, base=s.base)
        if isinstance(s, SineSpec):
            return P.sine(s.amplitude, s.frequency, phase=s.phase, t0=s.t0, offset=s.offset,
                          fade_cycles=s.fade_cycles)
        if isinstance(s, SumSpec):
            return P.total(_build(sc, f"{key}.terms[{i}]", ch, t) for i, t in enumerate(s.terms))
        if isinstance(s, SequenceSpec):
            return P.sequence((t.duration, _build(sc, f"{key}.segments[{i}]", ch, t))
                              for i, t in enumerate(s.segments))
    except ValueError as exc:
        raise _fail(sc.path, key, s.type, str(exc)) from None
    # replay
    file = (sc.path.parent / s.file).resolve()
    if s.column is None:
        names = [ch] + [a for a, c in SENSOR_ALIASES.items() if c == ch]
        try:
            header = read_csv_table(file)[0]
        except ConfigError as exc:
            raise ConfigError(f"{sc.path}: {key}.file = {s.file!r}: {exc}") from None
        found = [n for n in names if n in header]
        if not found:
            raise _fail(sc.path, f"{key}.file", s.file, f"no column for {ch} in {file} (looked for "
                        f"{' or '.join(names)}; columns present: {', '.join(header)})")
        column = found[0]
    else:
        column = s.column
    rec = sc.recordings.get(file)
    if rec is None or column not in rec.columns:
        cols = [column] + (list(rec.columns) if rec is not None else [])
        try:
            rec = read_recording(file, columns=cols)
        except ConfigError as exc:
            raise ConfigError(f"{sc.path}: {key}.file = {s.file!r}: {exc}") from None
        sc.recordings[file] = rec
    if input_name(column) not in (None, ch):
        raise _fail(sc.path, f"{key}.column", column, f"feeds {input_name(column)}, not {ch}")
    return replay_profiles(rec, sc.dt, {ch: column}, hold=s.hold, start=s.start)[ch]


def _check_sampled(sc: Scenario, channels: dict[str, tuple[str, Any]]) -> None:
    """Every channel stays within its range over the whole run (sampled at dt)."""
    if not sc.profiles:
        return
    n = int(math.floor(sc.duration / sc.dt + 1e-9)) + 1
    times = sc.dt * np.arange(n)
    for ch, prof in sc.profiles.items():
        vals = pack({0: prof}, nch=1)
        v = sample(vals, times)[:, 0]
        lo, hi = LIMITS[ch]
        bad = np.nonzero((v < lo - 1e-9 * max(1.0, abs(lo))) | (v > hi + 1e-9 * max(1.0, abs(hi))))[0]
        if bad.size:
            i = int(bad[0])
            key = channels[ch][0]
            raise ConfigError(f"{sc.path}: {key}: the profile reaches {v[i]:.6g} {INPUT_UNITS[ch]} at t = "
                              f"{times[i]:.6g} s, out of range for {ch} (allowed {lo:g} .. {hi:g} {INPUT_UNITS[ch]})")


def _read_path(file: Path, csv_path: Path, given: str) -> tuple[np.ndarray, np.ndarray]:
    key = "inputs.path_follower.file"
    try:
        header, rows, lines = read_csv_table(csv_path)
        for col in ("x", "y"):
            if col not in header:
                raise ConfigError(f"{csv_path}: column {col!r} missing; columns present: {', '.join(header)}")
        x = parse_column(csv_path, header, rows, lines, "x")
        y = parse_column(csv_path, header, rows, lines, "y")
    except ConfigError as exc:
        raise ConfigError(f"{file}: {key} = {given!r}: {exc}") from None
    return x, y


__all__ = ["Scenario", "ScenarioSpec", "load_scenario", "load_all", "SCENARIO_DIR"]
