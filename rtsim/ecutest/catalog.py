"""An ECU test catalogue (``rtsim test CATALOG.toml``): the ECU under test, and test cases, each a scenario,
faults and expectations on signals. Validated on load like every rtsim config (rtsim.configfile: a bad value
is one line naming the file, the key, the value and the allowed range).

    name = "demo_ecu"
    mode = "lockstep"                   # or "realtime"
    vehicle = "xbw"                     # a name in configs/vehicles or a .toml path (relative to this file)
    scenario = "hil_flat"               # likewise, configs/scenarios
    duration = 4.0                      # s of simulated time per case (a case may give its own)

    [ecu]
    command = ["{python}", "-m", "drivers.ecu_demo", "--manoeuvre", "straight_line"]
    # the bus, the duration and (lockstep) --lockstep are appended, unless the command names
    # {interface}, {channel}, {duration} or {lockstep} itself; or: channel = "127.0.0.1:54701" for
    # an ECU already on a python-can-remote bus (realtime only; the catalogue then runs its hub's cases
    # one at a time)

    # or, instead of [ecu] (or beside it): a controller FMU as the command source (docs/fmu.md):
    # controller = "pi.toml"            # its mapping file (relative to this file); a case may give its own

    [[cases]]
    name = "brake_timeout_hold"
    [[cases.faults]]                    # the fault spec of rtsim.faults (docs/faults.md)
    id = "brake_lost"
    kind = "loss"
    target = "BRAKE_CMD"
    n = 1
    m = 1
    at = 2.0
    [[cases.expect]]
    kind = "reaction"                   # bounds | reaction | monotonic | reached
    signal = "commands.brake_pressure_cmd"
    after = "fault:brake_lost"
    condition = "> 2900"
    within = 0.05

Signals (rtsim.ecutest.signals): ``sensors.<channel>``, ``state.<channel>``, ``commands.<channel>`` (the
commands the simulator applied, after its watchdog), ``ecu.<FRAME>.<signal>`` (the ECU's own frames as
received, decoded from the DBC), ``fault.<id>`` (1 while the fault is active, else 0), ``sim.<FRAME>.<signal>``
(the simulator's SIM_STATUS and SIM_DIAG frames: the watchdog's time-out flags).
Events (``after``): ``start``, ``fault:<id>`` (its onset), ``fault_end:<id>``, or a condition over a signal
(``sensors.speed > 5``, ``abs(state.yaw_rate) > 0.1``: the first sample where it holds).
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Annotated, Literal, Optional, Union

from pydantic import Field, model_validator

from rtsim.configfile import Range, Strict, bad, load_toml, problem, validate
from rtsim.faults.spec import FaultSpec, load_fault_specs

_NAME = r"^[A-Za-z0-9_.-]{1,64}$"
_SIGNAL = r"[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*){1,2}"
_COND = re.compile(rf"^\s*(abs\(\s*)?({_SIGNAL})?\s*(\))?\s*(>=|<=|>|<|==)\s*([-+0-9.eE]+|true|false)\s*$")
SIGNAL_PATTERN = rf"^{_SIGNAL}$"
EVENT_PATTERN = r"^(start|fault:[A-Za-z0-9_.-]{1,64}|fault_end:[A-Za-z0-9_.-]{1,64})$"
Time = Range(0.0, 3600.0, "s")
Window = Range(0.0, 3600.0, "s", lo_open=True)
SignalValue = Range(-math.inf, math.inf, "the signal's unit", lo_open=True, hi_open=True)   # any finite


def parse_condition(text: str, signal: bool) -> tuple[Optional[str], str, float, bool]:
    """(signal or None, op, value, magnitude) of ``[abs(]SIGNAL[)] OP VALUE`` (``signal`` True) or of
    ``OP VALUE`` (False: the expectation's own signal); ValueError otherwise. OP: > >= < <= ==."""
    m = _COND.match(text)
    if m is None or bool(m.group(1)) != bool(m.group(3)) or (m.group(2) is None) == signal:
        form = "[abs(]SIGNAL[)] OP VALUE" if signal else "OP VALUE"
        raise ValueError(f"not a condition: write {form} with OP one of > >= < <= ==")
    v = {"true": 1.0, "false": 0.0}.get(m.group(5))
    if v is None:
        try:
            v = float(m.group(5))
        except ValueError:
            raise ValueError(f"{m.group(5)!r} is not a number") from None
    return m.group(2), m.group(4), v, bool(m.group(1))


def check_event(text: str) -> str:
    """An event as written (``after``): ``start``, ``fault:ID``, ``fault_end:ID`` or a signal condition."""
    if re.match(EVENT_PATTERN, text):
        return text
    parse_condition(text, signal=True)
    return text


class _Expect(Strict):
    signal: str = Field(pattern=SIGNAL_PATTERN, description="the signal (module docstring)")
    after: str = Field("start", description="the event the window starts from")
    name: Optional[str] = Field(None, description="a name for the report (default: kind and signal)")

    @model_validator(mode="after")
    def _event(self):
        try:
            check_event(self.after)
        except ValueError as exc:
            raise bad("after", self.after, f"{exc}; or start, fault:ID, fault_end:ID") from None
        return self

    def label(self) -> str:
        return self.name or f"{self.kind} {self.signal}"


class Bounds(_Expect):
    """Every sample of ``signal`` in [min, max] from ``start`` to ``end`` s after the event (end: the case's
    end when left out)."""
    kind: Literal["bounds"]
    min: Optional[SignalValue] = None
    max: Optional[SignalValue] = None
    start: Time = 0.0
    end: Optional[Window] = None

    @model_validator(mode="after")
    def _limits(self):
        if self.min is None and self.max is None:
            raise bad("max", None, "give min, max or both")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise bad("max", self.max, f"must be >= min ({self.min:g})")
        if self.end is not None and self.end <= self.start:
            raise bad("end", self.end, f"must be > start ({self.start:g} s)")
        return self


class _Conditioned(_Expect):
    condition: str = Field(description="OP VALUE on the signal: > >= < <= ==")

    @model_validator(mode="after")
    def _cond(self):
        try:
            parse_condition(self.condition, signal=False)
        except ValueError as exc:
            raise bad("condition", self.condition, str(exc)) from None
        return self


class Reaction(_Conditioned):
    """The signal meets ``condition`` within ``within`` s of the event (the reaction time is reported);
    with ``hold`` it then keeps meeting it for ``hold`` s."""
    kind: Literal["reaction"]
    within: Window
    hold: Time = 0.0


class Reached(_Conditioned):
    """The signal meets ``condition`` at some sample from ``start`` to ``end`` s after the event (end: the
    case's end)."""
    kind: Literal["reached"]
    start: Time = 0.0
    end: Optional[Window] = None


class Monotonic(_Expect):
    """The signal never rises (``decreasing``) or never falls (``increasing``) by more than ``tolerance``
    between samples, from ``start`` to ``end`` s after the event."""
    kind: Literal["monotonic"]
    direction: Literal["increasing", "decreasing"]
    tolerance: Range(0.0, 1e9) = 0.0
    start: Time = 0.0
    end: Optional[Window] = None


Expectation = Annotated[Union[Bounds, Reaction, Reached, Monotonic], Field(discriminator="kind")]


class Ecu(Strict):
    """The ECU under test: a command the catalogue starts for each case, or a bus where it already is."""
    command: Optional[list[str]] = Field(None, min_length=1, description="argv; {python} is this Python")
    channel: Optional[str] = Field(None, pattern=r"^127\.0\.0\.1:[0-9]{1,5}$",
                                   description="python-can-remote hub (127.0.0.1:PORT) an ECU already uses")
    args: list[str] = Field([], description="arguments added after the command for every case")

    @model_validator(mode="after")
    def _one(self):
        if (self.command is None) == (self.channel is None):
            raise bad("command", self.command, "give either command (the catalogue starts the ECU) or channel "
                                               "(an ECU already on that bus)")
        return self


class Case(Strict):
    """One test case: what runs (scenario, vehicle, faults, the ECU's extra arguments) and what must hold."""
    name: str = Field(pattern=_NAME)
    description: str = ""
    scenario: Optional[str] = None
    vehicle: Optional[str] = None
    duration: Optional[Window] = None
    controller: Optional[str] = Field(None, min_length=1, description="a controller FMU's mapping file")
    ecu_args: list[str] = []
    faults: list[dict] = []
    expect: list[Expectation] = Field(min_length=1)


class Catalogue(Strict):
    """The file's top level (module docstring)."""
    name: str = Field(pattern=_NAME)
    description: str = ""
    mode: Literal["lockstep", "realtime"] = "lockstep"
    vehicle: Optional[str] = None
    scenario: Optional[str] = None
    duration: Window = 5.0
    timeout: Range(1.0, 86400.0, "s") = Field(300.0, description="wall-clock bound of one case (hung ECU)")
    controller: Optional[str] = Field(None, min_length=1, description="a controller FMU's mapping file "
                                      "(rtsim.fmu.mapping), the command source of every case without its own")
    ecu: Optional[Ecu] = None
    cases: list[Case] = Field(min_length=1)

    @model_validator(mode="after")
    def _unique(self):
        seen: dict[str, int] = {}
        for i, c in enumerate(self.cases):
            if c.name in seen:
                raise bad(f"cases[{i}].name", c.name, f"used by cases[{seen[c.name]}] too (names are unique)")
            seen[c.name] = i
            if self.ecu is None and self.controller is None and c.controller is None:
                raise bad(f"cases[{i}].controller", None, "give [ecu] (the ECU under test) or a controller "
                                                         "(a controller FMU's mapping file) for every case")
        if self.ecu is None and self.mode != "lockstep":
            raise bad("mode", self.mode, "a catalogue without [ecu] steps its controller FMU in lockstep mode only")
        if self.ecu is not None and self.ecu.channel is not None and self.mode != "realtime":
            raise bad("mode", self.mode, "an ECU already on the bus (ecu.channel) runs in realtime mode only")
        return self


class LoadedCatalogue:
    """A validated catalogue with its file (``path``), folder for relative paths and each case's faults."""

    def __init__(self, spec: Catalogue, path: Path, faults: list[list[FaultSpec]]):
        self.spec, self.path, self.faults = spec, path, faults

    def config(self, case: Case, what: str) -> Optional[Path]:
        """The case's scenario or vehicle file (its own, else the catalogue's): a .toml path relative to
        the catalogue, or a name of the shipped configs (None: the service's default)."""
        value = getattr(case, what) or getattr(self.spec, what)
        if value is None:
            return None
        if value.endswith(".toml"):
            return (self.path.parent / value).resolve()
        from rtsim.vehicle.registry import resolve_scenario, resolve_vehicle
        return (resolve_scenario if what == "scenario" else resolve_vehicle)(value)

    @property
    def external(self) -> Optional[str]:
        """The bus of an ECU already running (``[ecu] channel``), else None."""
        return self.spec.ecu.channel if self.spec.ecu is not None else None

    def controller(self, case: Case):
        """The case's controller FMU (its own mapping file, else the catalogue's) as a loaded mapping
        (rtsim.fmu.mapping.load_mapping, relative to the catalogue), or None."""
        value = case.controller or self.spec.controller
        if value is None:
            return None
        from rtsim.fmu.mapping import load_mapping
        return load_mapping(self.path.parent / value)

    def duration(self, case: Case) -> float:
        return case.duration if case.duration is not None else self.spec.duration


def load_catalogue(path: str | Path) -> LoadedCatalogue:
    """The catalogue of ``path``, every value and each case's faults checked (ConfigError naming the file,
    key, value and allowed range); an expectation naming a fault the case does not declare is refused."""
    path = Path(path)
    raw = load_toml(path)
    spec = validate(Catalogue, raw, path)
    faults = []
    for i, case in enumerate(spec.cases):
        specs = load_fault_specs(case.faults, path, key=f"cases[{i}].faults")
        ids = {s.id for s in specs}
        for j, e in enumerate(case.expect):
            ev = e.after.split(":", 1)
            if ev[0] in ("fault", "fault_end") and ev[1] not in ids:
                raise problem(path, f"cases[{i}].expect[{j}].after", e.after,
                              f"names no fault of this case (its faults: {', '.join(sorted(ids)) or 'none'})")
            if e.signal.startswith("fault.") and e.signal[6:] not in ids:
                raise problem(path, f"cases[{i}].expect[{j}].signal", e.signal, "names no fault of this case")
        if case.controller or spec.controller:
            key = f"cases[{i}].controller" if case.controller else "controller"
            try:
                LoadedCatalogue(spec, path, []).controller(case)
            except Exception as exc:  # noqa: BLE001  (the mapping's own one-line error, naming its file)
                raise problem(path, key, case.controller or spec.controller, str(exc)) from None
        for what in ("scenario", "vehicle"):
            try:
                LoadedCatalogue(spec, path, []).config(case, what)
            except Exception as exc:  # noqa: BLE001  (the registry's own one-line error)
                raise problem(path, f"cases[{i}].{what}", getattr(case, what) or getattr(spec, what),
                              str(exc)) from None
        faults.append(specs)
    return LoadedCatalogue(spec, path, faults)
