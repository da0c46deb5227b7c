"""The one configuration mechanism of rtsim: TOML files read by `load_toml`, validated by pydantic models
derived from `Strict`, every error reported by one formatter as one line naming the file, the key (dotted,
list items as [i]), the offending value and what is allowed:

    configs/scenarios/x.toml: duration = -1.0: out of range (allowed 0 < duration <= 3600 s)
    configs/vehicles/x.toml: steering.kp = -1.0: out of range (allowed 0 <= kp <= 1e+06 N m/rad)
    configs/roads/x.toml: heigth = 1.0: unknown key (allowed: type, height, mu, rolling_resistance)

Ranges are declared one way, with `Range(lo, hi, unit)` (an annotated float, or an int with
`integer=True`: within the bounds, finite unless a closed bound is itself infinite, the unit in the
message); a vector or a table's nodes declare their element's range (`tuple[Coord, Coord, Coord]`,
`list[Range(...)]`: the error names the element, `wheel_centre[2]`). Pydantic models and config
dataclasses alike (a kit part's section calls `check_declared_ranges(self)` in its `__post_init__`, so a
part built in code is checked by the same declaration as one read from a file); pydantic's
`Field(ge=, gt=, le=, lt=)` is not used on config models (tests/test_config_ranges.py). Checks across
keys (rules, not ranges: min < max, increasing nodes) raise `bad(key, value, reason)` inside a model
validator; checks after validation (files that must exist, sampled profiles) raise
`problem(source, key, value, reason)`.
Vehicles, roads, scenarios, drivers and the service's settings all load through here, so `overrides`
(a batch's grid point: dotted keys set in a file's table as it is read) is checked like the file itself.

Every reader of an input file (TOML here, and the tyre, survey, recorded-input and DBC readers) calls
`note_read(path)`; inside `recording_reads()` those paths are collected, so a caller learns the resolved
set of files a load (or a whole run) read, nested files included (a batch's run ids hash their contents).
"""
from __future__ import annotations

import contextvars
import copy
import dataclasses
import functools
import math
import re
import tomllib
import types
import typing
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, TypeVar, Union

from pydantic import AfterValidator, BaseModel, BeforeValidator, ConfigDict, TypeAdapter, ValidationError, \
    model_validator
from pydantic_core import PydanticCustomError

from rtsim.errors import ConfigError

M = TypeVar("M")
MAX_PROBLEMS = 5        # problems listed in one error (all on one line, the first first)


# ---- declarations ----------------------------------------------------------------------------------
def _number(x: Any) -> Any:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise PydanticCustomError("not_number", "must be a number")
    return float(x)


def in_range(x: float, lo: float, hi: float, lo_open: bool = False, hi_open: bool = False) -> bool:
    """x within the bounds; an infinite x only where a closed bound is that infinity (Range(0, inf)
    accepts inf: "no limit"), never NaN."""
    if math.isnan(x) or (math.isinf(x) and not (x == hi and not hi_open or x == lo and not lo_open)):
        return False
    return (x > lo if lo_open else x >= lo) and (x < hi if hi_open else x <= hi)


def range_text(leaf: str, lo: float, hi: float, unit: str = "", lo_open: bool = False, hi_open: bool = False) -> str:
    """'out of range (allowed lo <= leaf <= hi unit)', the one wording of a range violation."""
    unit = f" {unit}" if unit else ""
    return (f"out of range (allowed {lo:g} {'<' if lo_open else '<='} {leaf} "
            f"{'<' if hi_open else '<='} {hi:g}{unit})")


def _integer(x: Any) -> Any:
    if isinstance(x, bool) or not isinstance(x, int):
        raise PydanticCustomError("not_integer", "must be an integer")
    return x


def Range(lo: float, hi: float, unit: str = "", lo_open: bool = False, hi_open: bool = False,
          integer: bool = False):
    """A float (an int if `integer`) within [lo, hi] (open at either end if asked; `in_range`); its
    errors show the whole range and the unit."""
    def check(x: float) -> float:
        if not in_range(x, lo, hi, lo_open, hi_open):
            raise PydanticCustomError("out_of_range", "out of range",
                                      {"lo": lo, "hi": hi, "lo_open": lo_open, "hi_open": hi_open, "unit": unit})
        return x
    check.declared_range = (lo, hi, unit, lo_open, hi_open)
    check.integer = integer
    return Annotated[int if integer else float, BeforeValidator(_integer if integer else _number),
                     AfterValidator(check)]


def Positive(unit: str = ""):
    """A finite value > 0 (in `unit`)."""
    return Range(0.0, math.inf, unit, lo_open=True, hi_open=True)


def NonNegative(unit: str = ""):
    """A finite value >= 0 (in `unit`)."""
    return Range(0.0, math.inf, unit, hi_open=True)


def _range_check(annotation):
    for m in getattr(annotation, "__metadata__", ()):
        if getattr(getattr(m, "func", None), "declared_range", None) is not None:
            return m.func
    return None


def declared_range(annotation) -> tuple | None:
    """(lo, hi, unit, lo_open, hi_open) of a `Range` annotation, else None."""
    check = _range_check(annotation)
    return None if check is None else check.declared_range


def _element_checks(annotation) -> tuple | None:
    """What a dataclass field's annotation declares: ("one", check) for a `Range`, ("each", [declaration
    per position, or one for all]) for a tuple or list (of tuples ...) of `Range`s; an optional field may
    be None."""
    if (c := _range_check(annotation)) is not None:
        return "one", c
    origin = typing.get_origin(annotation)
    if origin in (Union, types.UnionType):
        for a in typing.get_args(annotation):
            if a is not type(None) and (found := _element_checks(a)) is not None:
                return found
    if origin in (tuple, list):
        subs = [_element_checks(a) for a in typing.get_args(annotation) if a is not Ellipsis]
        if subs and all(c is not None for c in subs):
            return "each", subs
    return None


@functools.cache
def _dataclass_ranges(cls) -> tuple:
    hints = typing.get_type_hints(cls, include_extras=True)
    return tuple((f.name, r) for f in dataclasses.fields(cls) if (r := _element_checks(hints.get(f.name))) is not None)


def _check_value(key: str, x: Any, declared: tuple) -> None:
    kind, what = declared
    if kind == "each":
        if not isinstance(x, (tuple, list)):
            raise bad(key, x, "must be a list [...]")
        for i, v in enumerate(x):
            _check_value(f"{key}[{i}]", v, what[min(i, len(what) - 1)])
        return
    lo, hi, unit, lo_open, hi_open = what.declared_range
    if what.integer and (isinstance(x, bool) or not isinstance(x, int)):
        raise bad(key, x, "must be an integer")
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        raise bad(key, x, "must be a number")
    if not in_range(float(x), lo, hi, lo_open, hi_open):
        raise bad(key, x, range_text(key.rsplit(".", 1)[-1], lo, hi, unit, lo_open, hi_open))


def check_declared_ranges(obj) -> None:
    """In a config dataclass's __post_init__: every field declared with `Range` (or a vector or table of
    them) within it, else the error about that key (as `bad`: rtsim.configfile formats it with the file
    and the section's key; a vector's element as key[i])."""
    for name, declared in _dataclass_ranges(type(obj)):
        x = getattr(obj, name)
        if x is not None or declared[0] == "one":
            _check_value(name, x, declared)


def range_fields(ranges: dict, defaults: dict) -> dict:
    """Model fields (for pydantic.create_model) of named floats declared as name -> (lo, hi, unit,
    lo_open), with their defaults."""
    return {n: (Range(lo, hi, unit, lo_open=lo_open), defaults[n]) for n, (lo, hi, unit, lo_open) in ranges.items()}


def check_ranges(model, values: dict, what: str) -> None:
    """ValueError (the one formatter's text) unless `values` fit the ranged model (a driver's
    parameters checked where they are built, by the same declaration the config files use)."""
    try:
        validate(model, values, what)
    except ConfigError as exc:
        raise ValueError(str(exc)) from None


def bad(key: str, value: Any, reason: str) -> PydanticCustomError:
    """An error about `key` (dotted, relative to the model whose validator raises it)."""
    return PydanticCustomError("bad_key", reason, {"key": key, "value": value})


class Strict(BaseModel):
    """Base of every config section: unknown keys are errors that list the allowed keys (a typo must not
    pass silently); sections are immutable once loaded."""
    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            fields = cls.model_fields        # pydantic builds this mapping at each access: once per table
            for k, v in data.items():
                if k not in fields:
                    raise PydanticCustomError("unknown_key", "unknown key",
                                              {"key": k, "value": v, "allowed": ", ".join(fields)})
        return data


# ---- the error formatter ----------------------------------------------------------------------------
def _fmt_value(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 60 else s[:57] + "..."


_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _part(key: str) -> str:
    """A key as TOML writes it in a dotted path: bare when it may be, else quoted (a batch plan's
    `overrides."scenario.duration"` stays one key, not two)."""
    return key if _BARE_KEY.fullmatch(key) else '"' + key.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _leaf(loc: tuple) -> str:
    """The last key of an error location with any list indices after it (its name in an "allowed
    lo <= name <= hi" message)."""
    idx = ""
    for part in reversed(loc):
        if not isinstance(part, int):
            return _part(str(part)) + idx
        idx = f"[{part}]" + idx
    return "value" + idx


def _data_loc(loc: tuple, data: Any) -> tuple:
    """The parts of an error location that are keys of the data (or list indices). Parts pydantic
    inserts that are not (a union's tag or member name) are left out, found by walking the data along
    the path: a key missing from a table while the next part is in it, or any name below a value that is
    no table."""
    out = []
    here = data
    for n, part in enumerate(loc):
        last = n == len(loc) - 1
        if isinstance(here, dict) and not last and (part not in here or (
                part in here.values() and loc[n + 1] in here)):
            continue
        if isinstance(part, str) and out and here is not None and not isinstance(here, (dict, list, tuple)):
            continue
        out.append(part)
        if isinstance(part, int):
            here = here[part] if isinstance(here, (list, tuple)) and -len(here) <= part < len(here) else None
        else:
            here = here.get(part) if isinstance(here, dict) else None
    return tuple(out)


def _key(loc: tuple, data: Any) -> str:
    """Dotted key of an error location as TOML writes it, list items as [i] (`_data_loc`'s parts)."""
    out = ""
    for part in _data_loc(loc, data):
        out += f"[{part}]" if isinstance(part, int) else ("." if out else "") + _part(str(part))
    return out


def _members(tp) -> list:
    """The alternatives of a type: Annotated unwrapped, unions spread."""
    origin = typing.get_origin(tp)
    if origin is Annotated:
        return _members(typing.get_args(tp)[0])
    if origin in (Union, types.UnionType):
        return [m for a in typing.get_args(tp) for m in _members(a)]
    return [tp]


def _field_at(root, loc: tuple):
    """The FieldInfo a location ends on, walking the models (through unions, lists, dicts), or None."""
    cands, info = _members(root), None
    for part in loc:
        nxt, found = [], None
        for tp in cands:
            if isinstance(tp, type) and issubclass(tp, BaseModel):
                f = tp.model_fields.get(part) if isinstance(part, str) else None
                if f is not None:
                    found = f
                    nxt += _members(f.annotation)
                nxt.append(tp)                   # the part may be a union's tag: the model goes on too
            elif typing.get_origin(tp) in (list, tuple):
                nxt += [m for a in typing.get_args(tp) if a is not Ellipsis for m in _members(a)]
            elif typing.get_origin(tp) is dict:
                nxt += _members(typing.get_args(tp)[1])
        cands = nxt
        if isinstance(part, str):
            info = found
    return info


def _allowed(root, loc: tuple, leaf: str, ctx: dict) -> str:
    """'lo <= leaf <= hi; description' from the field's declared bounds (else the violated one)."""
    info = _field_at(root, loc) if root is not None else None
    meta = {}
    for m in (info.metadata if info is not None else ()):
        for k in ("gt", "ge", "lt", "le"):
            if getattr(m, k, None) is not None:
                meta[k] = getattr(m, k)
    meta = meta or {k: ctx[k] for k in ("gt", "ge", "lt", "le") if k in ctx}
    lo = f"{meta['gt']:g} < " if "gt" in meta else f"{meta['ge']:g} <= " if "ge" in meta else ""
    hi = f" < {meta['lt']:g}" if "lt" in meta else f" <= {meta['le']:g}" if "le" in meta else ""
    desc = f"; {info.description}" if info is not None and info.description else ""
    return f"{lo}{leaf}{hi}{desc}"


def message(source: str, err: dict, data: Any = None, root=None, prefix: str = "") -> str:
    """One line for one pydantic error of `data` read from `source` (validated against the type
    `root`, whose fields give the allowed ranges); keys start with `prefix` (a section validated on its
    own: its key in the file); an empty source leaves the file out."""
    line = _message(err, data, root)
    if prefix:
        line = prefix + ("." + line if not line.startswith((" ", ":")) else line)
    return f"{source}: {line}" if source else line


def _message(err: dict, data: Any, root) -> str:
    loc = tuple(err["loc"])
    ctx = err.get("ctx") or {}
    kind = err["type"]
    value = err.get("input")
    if kind == "unknown_key":
        loc = loc + (ctx["key"],)
        value = ctx["value"]
        reason = f"unknown key (allowed: {ctx['allowed']})"
    elif kind in ("extra_forbidden", "unexpected_keyword_argument"):
        reason = "unknown key"
    elif kind == "bad_key":
        loc = loc + tuple(int(k[1:-1]) if k.startswith("[") else k for k in re.findall(r"[^.\[\]]+|\[\d+\]", ctx["key"]))
        value = ctx["value"]
        reason = err["msg"]
    elif kind == "out_of_range":
        where = _data_loc(loc, data) if data is not None else loc
        info = _field_at(root, where) if root is not None else None
        desc = f"; {info.description}" if info is not None and info.description else ""
        reason = range_text(_leaf(where), ctx["lo"], ctx["hi"], ctx["unit"], ctx["lo_open"], ctx["hi_open"])
        reason = reason[:-1] + desc + ")"
    elif kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        reason = f"out of range (allowed {_allowed(root, loc, _leaf(loc), ctx)})"
    elif kind == "missing":
        info = _field_at(root, loc) if root is not None else None
        desc = f"; {info.description}" if info is not None and info.description else ""
        return f"{_key(loc, data)}: missing (required{desc})"
    elif kind == "union_tag_invalid":
        reason = f"not one of {ctx.get('expected_tags')}"
        loc = loc + (ctx.get("discriminator", "'type'").strip("'"),)
        value = ctx.get("tag", value)
    elif kind == "union_tag_not_found":
        key = _key(loc + (ctx.get("discriminator", "'type'").strip("'"),), data)
        return f"{key}: missing (required)"
    elif kind in ("model_type", "model_attributes_type", "dict_type"):
        reason = "must be a table (a [section] or {key = value, ...})"
    elif kind == "list_type":
        reason = "must be a list [...]"
    elif kind == "too_short":
        reason = f"must have at least {ctx.get('min_length', 1)} entries"
    elif kind == "literal_error":
        reason = f"must be one of {ctx.get('expected')}"
    elif kind == "string_pattern_mismatch":
        reason = f"must match {ctx.get('pattern')}"
    else:
        reason = err["msg"]
        if reason.startswith("Value error, "):
            reason = reason[len("Value error, "):]
        reason = reason[:1].lower() + reason[1:]
    return f"{_key(loc, data)} = {_fmt_value(value)}: {reason}"


def problem(source: str | Path, key: str, value: Any, reason: str) -> ConfigError:
    """The error for a check made after validation (a file that must exist, a sampled profile)."""
    return ConfigError(f"{source}: {key} = {_fmt_value(value)}: {reason}")


# ---- loading and validation --------------------------------------------------------------------------
#: resolved path -> {dotted key: value} that load_toml sets in that file's table (see `overrides`)
_OVERRIDES: contextvars.ContextVar[dict] = contextvars.ContextVar("rtsim_config_overrides", default={})


@contextmanager
def overrides(files: dict[Path, dict[str, Any]]):
    """While active, `load_toml` of any of `files` (resolved path -> {dotted key: value}) returns the
    file's table with those keys set, before validation: a parameter sweep's values get the same checks
    and error lines as the file's own. The mapping is read at each load (entries may be added inside)."""
    token = _OVERRIDES.set(files)
    try:
        yield
    finally:
        _OVERRIDES.reset(token)


def set_dotted(data: dict, dotted: str, value: Any) -> None:
    """data[a][b][c] = value for "a.b.c" (tables created on the way); a key below a non-table is a
    KeyError naming the key."""
    keys = dotted.split(".")
    here = data
    for i, k in enumerate(keys[:-1]):
        nxt = here.get(k)
        if nxt is None:
            nxt = here[k] = {}
        elif not isinstance(nxt, dict):
            raise KeyError(f"{'.'.join(keys[:i + 1])} = {nxt!r} is not a table, cannot set {dotted}")
        here = nxt
    here[keys[-1]] = copy.deepcopy(value)


#: the set collecting the resolved paths of the input files read (None: not recording)
_READS: contextvars.ContextVar[set | None] = contextvars.ContextVar("rtsim_config_reads", default=None)


@contextmanager
def recording_reads():
    """Collect the resolved path of every input file read while active (the set it yields; nested
    recordings each collect everything read inside them). A file is noted before it is opened, so a
    missing or unreadable file is in the set too."""
    outer = _READS.get()
    seen: set[Path] = set()
    token = _READS.set(seen)
    try:
        yield seen
    finally:
        _READS.reset(token)
        if outer is not None:
            outer |= seen


def note_read(path: str | Path) -> None:
    """Tell the active `recording_reads` (if any) that the input file `path` is read. Every reader of a
    config or data file a run depends on calls this (TOML, .tir, survey CSV, recorded inputs, DBC)."""
    seen = _READS.get()
    if seen is not None:
        seen.add(Path(path).resolve())


#: parsed tables by resolved path while `keeping_tables` is active (None: every load parses its file)
_TABLES: contextvars.ContextVar[dict | None] = contextvars.ContextVar("rtsim_kept_tables", default=None)


@contextmanager
def keeping_tables(kept: dict):
    """While active, `load_toml` parses a file once and gives a copy of its table at each later load
    (``kept``: resolved path -> table): a batch worker reads the same files run after run, taken not to
    change during the batch. Overrides, validation and the recorded reads are as without it."""
    token = _TABLES.set(kept)
    try:
        yield kept
    finally:
        _TABLES.reset(token)


def load_toml(path: str | Path) -> dict:
    """A TOML file's table (with the active `overrides` for it); ConfigError naming the file otherwise."""
    path = Path(path)
    note_read(path)
    kept = _TABLES.get()
    resolved = path.resolve()
    if kept is None:
        data = _read_toml(path)
    else:
        if resolved not in kept:
            kept[resolved] = _read_toml(path)
        data = _table_copy(kept[resolved])
    for key, value in _OVERRIDES.get().get(resolved, {}).items():
        try:
            set_dotted(data, key, value)
        except KeyError as exc:
            raise ConfigError(f"{path}: {exc.args[0]}") from None
    return data


def _table_copy(value):
    """A parsed TOML value copied as deep as it is mutable: its tables and arrays (the rest -- strings,
    numbers, booleans, dates and times -- is immutable and shared)."""
    if type(value) is dict:
        return {k: _table_copy(v) for k, v in value.items()}
    if type(value) is list:
        return [_table_copy(v) for v in value]
    return value


def _read_toml(path: Path) -> dict:
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: cannot read: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None


def validate(schema: type[M] | TypeAdapter, data: Any, source: str | Path, prefix: str = "") -> M:
    """`data` validated against a model class or a TypeAdapter; a ConfigError naming `source` and every
    problem (up to MAX_PROBLEMS, then how many more) otherwise, keys after `prefix`. An instance of the
    model passes as is."""
    if isinstance(schema, type) and isinstance(data, schema):
        return data
    try:
        if isinstance(schema, TypeAdapter):
            return schema.validate_python(data)
        return schema.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        root = schema._type if isinstance(schema, TypeAdapter) else schema
        lines = [message("", e, data, root, prefix) for e in errors[:MAX_PROBLEMS]]
        more = len(errors) - len(lines)
        tail = f"; and {more} more problem{'s' if more > 1 else ''}" if more > 0 else ""
        text = "; ".join(lines) + tail
        raise ConfigError(f"{source}: {text}" if source else text) from None


def load(schema: type[M] | TypeAdapter, path: str | Path) -> M:
    """A TOML file validated against `schema`."""
    return validate(schema, load_toml(path), str(path))
