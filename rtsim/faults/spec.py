"""A fault as a session is told it: ``FaultSpec`` (pydantic, validated like every rtsim config: a bad value
is one line naming the file, the key, the value and the allowed range), read from a ``[[faults]]`` section
of a TOML file (the service's settings, a scenario, a fault file), from the ``inject_fault`` control op, or
built in Python.

    [[faults]]
    id = "ws_stuck"              # unique in the session: events, status and clear_fault name it
    kind = "stuck_value"         # rtsim.faults.catalog
    target = "accel_y"           # a sensor channel, a frame (name or id), "bus", or an actuator
    value = 0.0                  # the kind's parameters (catalog ranges)
    at = 2.0                     # trigger: at a time (s) ...
    # when = "abs(accel_y) > 4"  # ... or on a condition over a channel (sensor or state channel) ...
    # after = "other_id"         # ... or after another fault's onset,
    # after_delay = 0.5          #     plus a delay (s)
    duration = 1.0               # s; leave out: until cleared (clear_fault)

No trigger: the fault starts at the next step after it is armed (live arming). What the targets name is
checked against the served vehicle when the faults are compiled (rtsim.faults.table).
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Annotated, Any, Optional, Union

from pydantic import Discriminator, Field, Tag, model_validator

from rtsim.configfile import Range, Strict, bad, load_toml, validate

from .catalog import BY_NAME

#: s: the latest trigger time and the longest duration or delay a spec may give
MAX_TIME = 1e6
Seconds = Range(0.0, MAX_TIME, "s")
Positive = Range(0.0, MAX_TIME, "s", lo_open=True)
_CONDITION = re.compile(r"^\s*(abs\(\s*)?([A-Za-z_][A-Za-z0-9_]*)\s*(\))?\s*(>|<)\s*([-+0-9.eE]+)\s*$")
#: a target is named (sensor channel, frame name, "bus", actuator) or a frame's id; the union is told by the
#: value's type, so a bad id is reported against the id's range alone
FrameId = Range(0, 1_000_000, "frame id", integer=True)
Target = Annotated[Union[Annotated[str, Tag("name")], Annotated[FrameId, Tag("id")]],
                   Discriminator(lambda v: "id" if isinstance(v, int) and not isinstance(v, bool) else "name")]
COMMON = ("id", "kind", "target", "at", "when", "after", "after_delay", "duration")


class Condition(Strict):
    """``channel > value`` (or ``<``), on the channel's value or its magnitude (``abs``)."""
    channel: str
    op: str
    value: Range(-math.inf, math.inf, "the channel's unit", lo_open=True, hi_open=True)   # finite
    magnitude: bool = False

    def text(self) -> str:
        ch = f"abs({self.channel})" if self.magnitude else self.channel
        return f"{ch} {self.op} {self.value:g}"


def parse_condition(text: str) -> Condition:
    """A trigger condition: ``CHANNEL > VALUE``, ``CHANNEL < VALUE``, ``abs(CHANNEL) > VALUE`` (ValueError
    otherwise)."""
    m = _CONDITION.match(text)
    if m is None or bool(m.group(1)) != bool(m.group(3)):
        raise ValueError("not a condition: write CHANNEL > VALUE, CHANNEL < VALUE or abs(CHANNEL) > VALUE")
    try:
        v = float(m.group(5))
    except ValueError:
        raise ValueError(f"{m.group(5)!r} is not a number") from None
    if not math.isfinite(v):
        raise ValueError("the value must be finite")
    return Condition(channel=m.group(2), op=m.group(4), value=v, magnitude=bool(m.group(1)))


class FaultSpec(Strict):
    """One fault (module docstring); ``params`` holds the kind's parameters, defaults filled in."""
    id: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$", description="the fault's name, unique in the session")
    kind: str = Field(description="a fault kind of the catalogue (rtsim faults --list)")
    target: Target = Field(description="sensor channel, frame name or id, \"bus\", or actuator")
    at: Optional[Seconds] = Field(None, description="onset time (the step at it)")
    when: Optional[str] = Field(None, description="onset condition: CHANNEL > VALUE, abs(CHANNEL) > VALUE, ...")
    after: Optional[str] = Field(None, description="onset after this fault's onset")
    after_delay: Seconds = Field(0.0, description="delay after the other fault's onset")
    duration: Optional[Positive] = Field(None, description="how long the fault lasts (none: until cleared)")
    params: dict[str, int | float] = Field(default_factory=dict, description="the kind's parameters")

    @model_validator(mode="before")
    @classmethod
    def _gather(cls, data: Any) -> Any:
        """The kind's parameters (flat keys of the table) checked against the catalogue and moved into
        ``params``; any other key is an error listing the allowed ones."""
        if not isinstance(data, dict) or "params" in data:
            return data
        kind = data.get("kind")
        if not isinstance(kind, str) or kind not in BY_NAME:
            raise bad("kind", kind, f"not a fault kind (kinds: {', '.join(BY_NAME)})")
        fk = BY_NAME[kind]
        out = {k: v for k, v in data.items() if k in COMMON}
        params = {}
        names = [p.name for p in fk.params]
        for k, v in data.items():
            if k in COMMON:
                continue
            if k not in names:
                raise bad(k, v, f"unknown key for a {kind} fault (allowed: {', '.join((*COMMON, *names))})")
            p = fk.param(k)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise bad(k, v, "must be a number")
            x = float(v)
            if not (math.isfinite(x) and p.lo <= (v if p.integer and isinstance(v, int) else x) <= p.hi):
                unit = f" {p.unit}" if p.unit else ""
                raise bad(k, v, f"out of range (allowed {p.lo:g} <= {k} <= {p.hi:g}{unit}; {p.meaning})")
            if p.integer and x != int(x):
                raise bad(k, v, "must be a whole number")
            params[k] = int(v) if p.integer else x
        for p in fk.params:
            if p.name not in params:
                if p.default is None:
                    raise bad(p.name, None, f"missing: a {kind} fault needs it ({p.meaning}; "
                                            f"{p.lo:g} .. {p.hi:g}{' ' + p.unit if p.unit else ''})")
                params[p.name] = int(p.default) if p.integer else p.default
        out["params"] = params
        return out

    @model_validator(mode="after")
    def _trigger(self) -> "FaultSpec":
        given = [k for k in ("at", "when", "after") if getattr(self, k) is not None]
        if len(given) > 1:
            raise bad(given[1], getattr(self, given[1]), f"one trigger only ({given[0]} is given too)")
        if self.when is not None:
            try:
                parse_condition(self.when)
            except ValueError as exc:
                raise bad("when", self.when, str(exc)) from None
        if self.after_delay and self.after is None:
            raise bad("after_delay", self.after_delay, "only with after = \"FAULT_ID\"")
        if self.after == self.id:
            raise bad("after", self.after, "a fault cannot follow its own onset")
        return self

    @property
    def condition(self) -> Condition | None:
        return None if self.when is None else parse_condition(self.when)

    def table(self) -> dict:
        """The spec as a ``[[faults]]`` table (flat keys; JSON- and TOML-ready): what is recorded."""
        out = {k: getattr(self, k) for k in COMMON if getattr(self, k) is not None}
        if not self.after:
            out.pop("after_delay", None)
        out.update(self.params)
        return out


def load_fault_specs(tables: Any, source: str | Path, key: str = "faults") -> list[FaultSpec]:
    """The specs of a ``[[faults]]`` list read from ``source`` (errors name ``faults[i].key``); ids unique."""
    if tables is None:
        return []
    if not isinstance(tables, list):
        raise _not_list(source, key, tables)
    specs = [validate(FaultSpec, t, source, prefix=f"{key}[{i}]") for i, t in enumerate(tables)]
    seen: dict[str, int] = {}
    for i, s in enumerate(specs):
        if s.id in seen:
            from rtsim.configfile import problem
            raise problem(source, f"{key}[{i}].id", s.id, f"used by {key}[{seen[s.id]}] too (ids are unique)")
        seen[s.id] = i
    return specs


def _not_list(source, key, value):
    from rtsim.configfile import problem
    return problem(source, key, value, "must be a list of tables ([[faults]])")


def load_fault_file(path: str | Path) -> list[FaultSpec]:
    """The ``[[faults]]`` of a TOML file (a file of faults alone, or any file with that section)."""
    raw = load_toml(path)
    extra = [k for k in raw if k != "faults"]
    if extra:
        from rtsim.configfile import problem
        raise problem(path, extra[0], raw[extra[0]], "unknown key (a fault file holds [[faults]] only)")
    return load_fault_specs(raw.get("faults"), path)
