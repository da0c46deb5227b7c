"""The arguments of the service's control ops (the Zenoh ``control`` key), declared once and checked before
the loop sees a request.

Each op has one pydantic model: no argument it does not declare (``extra="forbid"``: ``{"steps": 5}`` on
``step`` is an error, not one step), strict types (no string for a number, no ``true`` for 1, no 5.0 for
an integer) and finite numbers only (NaN and infinity are refused, whether sent as JSON's ``NaN`` literal
or a selector parameter). A request that fails is answered ``{"ok": false, "error": "<op>: <one line>"}``
and never reaches the loop. The ranges of the values (a channel's limits, the steps of ``step``) are
checked by the op's handler, which knows the served vehicle.

``load_scenario``'s ``scenario`` is a name inside the scenario folders (``scenario_file``): the shipped
configs/scenarios and those the service's settings declare (``simulation.scenario_dirs``,
``--scenario-dir``); an absolute path, a ``..`` component, or a name whose file (symbolic links
followed) lies outside those folders is refused.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Iterable, Optional

from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model

import math

from drivers.base import INPUT_NAMES
from rtsim.configfile import Range, range_text, validate
from rtsim.errors import ConfigError, RtsimError
from rtsim.faults.spec import FaultSpec

from .user_input import USER_CHANNEL_NAMES

SHIPPED_SCENARIOS = Path(__file__).resolve().parents[2] / "configs" / "scenarios"

#: a finite number (an int is taken as a float; a bool or a string is not a number)
Finite = Annotated[float, Field(allow_inf_nan=False)]


class ControlError(RtsimError):
    """A control request refused before it reached the loop; the message is one line."""


class _Args(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


class NoArgs(_Args):
    """pause, resume, reset (reset restarts the scenario being served: it takes no argument)."""


class StepArgs(_Args):
    """step (lockstep mode only)."""
    n: Range(1, 1_000_000, integer=True) = Field(1, description="steps to run, each one step of the model")


class LoadScenarioArgs(_Args):
    """load_scenario."""
    scenario: str = Field(min_length=1, description="name of a scenario in the scenario folders "
                                                    "(e.g. step_steer_80kph, or sub/name.toml)")


#: driver: the in-loop driver's inputs (drivers.base.INPUT_NAMES, SI units), a number or null (hand it back)
DriverArgs = create_model("DriverArgs", __base__=_Args,
                          **{name: (Optional[Finite], None) for name in INPUT_NAMES})

#: drive: the shipped vehicles' user channels (rtsim.service.user_input; the handler checks the served
#: vehicle's channels and ranges), a number or null, and the request's flags
DriveArgs = create_model(
    "DriveArgs", __base__=_Args,
    takeover=(Optional[bool], None), release=(bool, False), seq=(Optional[int], None),
    **{name: (Optional[Finite], None) for name in USER_CHANNEL_NAMES})

class ClearFaultArgs(_Args):
    """clear_fault."""
    id: str = Field(min_length=1, description="the id of an armed fault")


#: op -> its arguments' model (the ops of bridge.zenoh_link.CONTROL_OPS); inject_fault's is the fault spec
#: (rtsim.faults.spec.FaultSpec: the keys of a [[faults]] table), checked by the one config formatter
OP_ARGS: dict[str, type[BaseModel]] = {
    "reset": NoArgs, "pause": NoArgs, "resume": NoArgs, "load_scenario": LoadScenarioArgs,
    "step": StepArgs, "driver": DriverArgs, "drive": DriveArgs, "inject_fault": FaultSpec,
    "clear_fault": ClearFaultArgs,
}


def _reason(op: str, model: type[BaseModel], exc: ValidationError) -> str:
    """One line for the first error of ``exc`` (and how many more there were)."""
    errs = exc.errors()
    e = errs[0]
    name = ".".join(str(p) for p in e["loc"]) or "arguments"
    value = e.get("input")
    kind = e["type"]
    if kind == "extra_forbidden":
        allowed = ", ".join(model.model_fields) or "none"
        what = f"unknown argument {name!r} (its arguments: {allowed})"
    elif kind == "finite_number":
        what = f"{name} = {value!r} is not a finite number"
    elif kind == "missing":
        what = f"argument {name!r} missing"
    elif kind == "out_of_range":
        c = e["ctx"]
        what = f"{name} = {value!r}: {range_text(name, c['lo'], c['hi'], c['unit'], c['lo_open'], c['hi_open'])}"
    else:
        what = f"{name} = {value!r}: {e['msg'][0].lower()}{e['msg'][1:]}"
    more = f" (and {len(errs) - 1} more)" if len(errs) > 1 else ""
    return f"{op}: {what}{more}"


def check_request(op: object, args: dict) -> dict:
    """The arguments of a control request as its op declares them (only those the request set, an
    explicit null kept: it hands a channel back); ControlError with one line otherwise."""
    if not isinstance(op, str) or op not in OP_ARGS:
        raise ControlError(f"unknown op {op!r}; ops: {', '.join(OP_ARGS)}")
    model = OP_ARGS[op]
    if model is FaultSpec:
        for k, v in args.items():
            if isinstance(v, float) and not math.isfinite(v):
                raise ControlError(f"{op}: {k} = {v!r} is not a finite number")
        try:
            return validate(FaultSpec, dict(args), op).table()
        except ConfigError as exc:
            raise ControlError(str(exc)) from None
    bad = [k for k in args if not isinstance(k, str) or k.startswith("_")]
    if bad:
        raise ControlError(f"{op}: unknown argument {bad[0]!r} (its arguments: {', '.join(model.model_fields) or 'none'})")
    try:
        return model.model_validate(args).model_dump(exclude_unset=True)
    except ValidationError as exc:
        raise ControlError(_reason(op, model, exc)) from None


def scenario_folders(extra: Iterable[Path] = ()) -> list[Path]:
    """The folders ``load_scenario`` reads from: the shipped configs/scenarios, then ``extra``; resolved."""
    out = []
    for folder in (SHIPPED_SCENARIOS, *extra):
        p = Path(folder).resolve()
        if p not in out:
            out.append(p)
    return out


def scenario_file(name: str, folders: list[Path]) -> Path:
    """The scenario file ``name`` names inside ``folders`` (resolved by ``scenario_folders``): a bare name
    (``<name>.toml``) or a relative path, looked up in each folder in order; ControlError when ``name`` is
    absolute, has a ``..`` component, leads (through symbolic links too) outside its folder, or is in none."""
    where = ", ".join(str(f) for f in folders)
    p = Path(name)
    if p.is_absolute() or name.startswith("~"):
        raise ControlError(f"load_scenario: {name!r} is an absolute path; give a scenario name inside the "
                           f"scenario folders ({where})")
    if ".." in p.parts:
        raise ControlError(f"load_scenario: {name!r} leaves the scenario folders ('..'); give a name inside "
                           f"them ({where})")
    for folder in folders:
        for cand in ((folder / p, folder / f"{name}.toml") if p.suffix != ".toml" else (folder / p,)):
            if not cand.is_file():
                continue
            real = cand.resolve()
            if not real.is_relative_to(folder):
                raise ControlError(f"load_scenario: {name!r} in {folder} is a link to {real}, outside the "
                                   f"scenario folders ({where})")
            return real
    raise ControlError(f"load_scenario: no scenario {name!r} in the scenario folders ({where})")
