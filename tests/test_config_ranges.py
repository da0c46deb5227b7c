"""Every number a config file can set has its range declared where the field is, one way: a `Range`
annotation of rtsim.configfile (with its unit; `integer=True` for counts; a vector's or a table's
elements each declared, `tuple[Coord, Coord, Coord]`, `list[Range(...)]`), on pydantic sections and
config dataclasses alike, so a bad value's error names the file, the key (and element), the value and
the allowed range. The test walks every config model (every `Strict` section, and the config
dataclasses they hold) and lists the numeric fields without a declared range, and the fields declared a
second way (pydantic's Field(ge=, gt=, le=, lt=)). Relations between fields (min < max, increasing
nodes, as many values as nodes) stay validators: they are rules, not ranges.

NOT_YET_RANGED is what is left, each with its reason. It may only shrink: a new unranged number
fails, and so does a listed field that has gained a range (then drop it from the list)."""
from __future__ import annotations

import dataclasses
import gc
import importlib
import math
import pkgutil
import types
import typing
from pathlib import Path
from typing import Annotated, Union

import pytest
from pydantic import BaseModel

import drivers
import rtsim
from rtsim.configfile import Range, Strict, check_declared_ranges, declared_range
from rtsim.errors import ConfigError

NOT_YET_RANGED = {
    # per fault kind: each kind's parameters declare lo, hi and unit in rtsim.faults.catalog, checked (same
    # wording) where the spec gathers them; the field itself holds any kind's
    "rtsim.faults.spec.FaultSpec": {"params"},
}
SKIP_MODULES = ("rtsim.viewer",)     # the browser viewer's server (no config models; imports a web stack)


def _import_all() -> None:
    for pkg in (rtsim, drivers):
        for mod in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + "."):
            if not mod.name.startswith(SKIP_MODULES):
                importlib.import_module(mod.name)


def _subclasses(cls):
    for sub in cls.__subclasses__():
        yield sub
        yield from _subclasses(sub)


def _members(tp) -> list:
    origin = typing.get_origin(tp)
    if origin is Annotated:
        return _members(typing.get_args(tp)[0])
    if origin in (Union, types.UnionType, list, tuple):
        return [m for a in typing.get_args(tp) if a is not Ellipsis for m in _members(a)]
    if origin is dict:
        return _members(typing.get_args(tp)[1])
    return [tp]


def _annotated_metadata(tp) -> list:
    out = list(getattr(tp, "__metadata__", ())) if typing.get_origin(tp) is Annotated else []
    out += [c for m in out for c in getattr(m, "metadata", ())]     # a pydantic Field's own constraints
    for a in typing.get_args(tp):
        out += _annotated_metadata(a)
    return out


def _ranged(metadata) -> bool:
    return any(declared_range(Annotated[float, m]) is not None for m in metadata)


def _field_bounds(metadata) -> bool:
    """A bound declared the other way: pydantic's Field(ge=, gt=, le=, lt=) (annotated_types Ge, ...)."""
    return any(getattr(m, k, None) is not None for m in metadata for k in ("gt", "ge", "lt", "le"))


def _fields(cls):
    """(name, annotation, field metadata) of a pydantic model or a config dataclass."""
    if isinstance(cls, type) and issubclass(cls, BaseModel):
        return [(n, f.annotation, list(f.metadata)) for n, f in cls.model_fields.items()]
    hints = typing.get_type_hints(cls, include_extras=True)
    return [(f.name, hints[f.name], []) for f in dataclasses.fields(cls)]


def _walk():
    """(model's module.qualname, field name, its kinds, its metadata) over every Strict model and the
    config dataclasses reachable from them."""
    _import_all()
    todo, seen = list(_subclasses(Strict)), set()
    while todo:
        cls = todo.pop()
        if cls in seen:
            continue
        seen.add(cls)
        for name, ann, meta in _fields(cls):
            kinds = _members(ann)
            todo += [m for m in kinds if dataclasses.is_dataclass(m)
                     or (isinstance(m, type) and issubclass(m, BaseModel))]
            yield f"{cls.__module__}.{cls.__qualname__}", name, kinds, meta + _annotated_metadata(ann)


def unranged_numbers() -> dict[str, set[str]]:
    """model (module.qualname) -> its numeric fields (float or int, alone, optional or in lists) with no
    declared `Range`."""
    out = {}
    for model, name, kinds, meta in _walk():
        if any(m in (float, int) for m in kinds) and not _ranged(meta):
            out.setdefault(model, set()).add(name)
    return out


def second_style_bounds() -> dict[str, set[str]]:
    """model -> its fields with a bound declared by pydantic's Field(ge=, gt=, le=, lt=)."""
    out = {}
    for model, name, _kinds, meta in _walk():
        if _field_bounds(meta):
            out.setdefault(model, set()).add(name)
    return out


def test_every_number_of_every_config_model_has_a_declared_range():
    found = unranged_numbers()
    new = {k: sorted(v - NOT_YET_RANGED.get(k, set())) for k, v in found.items()}
    new = {k: v for k, v in new.items() if v}
    assert not new, f"numeric config fields without a declared range (declare one with rtsim.configfile.Range): {new}"
    ranged_now = {k: sorted(v - found.get(k, set())) for k, v in NOT_YET_RANGED.items()}
    ranged_now = {k: v for k, v in ranged_now.items() if v}
    assert not ranged_now, f"these have a range now: drop them from NOT_YET_RANGED: {ranged_now}"


def test_no_config_field_declares_its_range_a_second_way():
    found = second_style_bounds()
    assert not found, f"declare these ranges with rtsim.configfile.Range, not Field(ge=, gt=, le=, lt=): {found}"


def test_the_walk_sees_a_planted_second_style_bound():
    """The one-style check is not vacuous: a Strict section with a Field(gt=) bound is caught."""
    from pydantic import Field

    class _PlantedField(Strict):
        bounded: float = Field(1.0, gt=0.0)
    try:
        assert second_style_bounds().get(f"{__name__}.{_PlantedField.__qualname__}") == {"bounded"}
        assert f"{__name__}.{_PlantedField.__qualname__}" in unranged_numbers()   # and it is no Range
    finally:
        del _PlantedField
        gc.collect()


def test_the_walk_sees_a_planted_unranged_number():
    """The walk is not vacuous: a Strict section with one ranged and one bare number is caught."""
    class _Planted(Strict):
        ranged: Range(0.0, 1.0) = 0.5
        bare: float = 1.0
    try:
        assert unranged_numbers().get(f"{__name__}.{_Planted.__qualname__}") == {"bare"}
    finally:
        del _Planted
        gc.collect()          # Strict.__subclasses__ holds it weakly: gone for the other tests


@dataclasses.dataclass(frozen=True)
class _Part:
    gain: Range(0.0, 10.0, "N/m") = 1.0
    limit: Range(0.0, math.inf, "N (inf: none)", lo_open=True) = math.inf

    def __post_init__(self) -> None:
        check_declared_ranges(self)


@pytest.mark.parametrize("kw, text", [({"gain": 11.0}, "out of range (allowed 0 <= gain <= 10 N/m)"),
                                      ({"gain": math.nan}, "out of range (allowed 0 <= gain <= 10 N/m)"),
                                      ({"limit": 0.0}, "out of range (allowed 0 < limit <= inf N (inf: none))"),
                                      ({"gain": "x"}, "must be a number")])
def test_a_config_dataclass_built_in_code_is_checked_by_its_declared_ranges(kw, text):
    with pytest.raises(Exception) as exc:
        _Part(**kw)
    assert text in str(exc.value)
    assert _Part(limit=math.inf).limit == math.inf


def test_a_kit_sections_bad_value_names_the_file_key_value_and_range():
    """The steer-by-wire section's ranges (declared with Range on its dataclass) reach a vehicle file's
    error line."""
    from rtsim.configfile import load_toml
    from rtsim.vehicle.car.config import load_vehicle
    path = Path(__file__).resolve().parents[1] / "configs" / "vehicles" / "xbw.toml"
    data = load_toml(path)
    data["steering"] = {**data.get("steering", {}), "kp": -1.0}
    with pytest.raises(ConfigError) as exc:
        load_vehicle(path, data)
    assert str(exc.value) == f"{path}: steering.kp = -1.0: out of range (allowed 0 <= kp < inf N m/rad)"
