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
    """(model's module.qualname, field name, its kinds, its metadata) over every Strict model, the
    service's settings, and the config dataclasses reachable from them."""
    _import_all()
    from rtsim.service.config import ServeOptions     # `rtsim serve`'s settings (its file's sections derive from it)
    todo, seen = [*_subclasses(Strict), ServeOptions], set()
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
    count: Range(1, 4, integer=True) = 2
    point: tuple[Range(-1.0, 1.0, "m"), Range(0.0, 2.0, "m")] = (0.0, 1.0)
    table: tuple[tuple[Range(-5.0, 5.0, "N"), ...], ...] = ((0.0, 1.0), (2.0, 3.0))

    def __post_init__(self) -> None:
        check_declared_ranges(self)


@pytest.mark.parametrize("kw, text", [({"gain": 11.0}, "out of range (allowed 0 <= gain <= 10 N/m)"),
                                      ({"gain": math.nan}, "out of range (allowed 0 <= gain <= 10 N/m)"),
                                      ({"limit": 0.0}, "out of range (allowed 0 < limit <= inf N (inf: none))"),
                                      ({"gain": "x"}, "must be a number"),
                                      ({"count": 2.0}, "must be an integer"),
                                      ({"count": 5}, "out of range (allowed 1 <= count <= 4)"),
                                      ({"point": (0.0, 3.0)}, "out of range (allowed 0 <= point[1] <= 2 m)"),
                                      ({"point": (-1.5, 1.0)}, "out of range (allowed -1 <= point[0] <= 1 m)"),
                                      ({"table": ((0.0, 1.0), (2.0, math.inf))},
                                       "out of range (allowed -5 <= table[1][1] <= 5 N)"),
                                      ({"table": 3.0}, "must be a list")])
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


ROOT = Path(__file__).resolve().parents[1]


def _open_vehicle(path):
    from rtsim.vehicle.registry import open_vehicle
    return open_vehicle(path)


def _load_road(path):
    from rtsim.road.config import load_road
    return load_road(path)


def _load_plan(path):
    from rtsim.batch.plan import load_plan
    return load_plan(path)


def _load_scenario(path):
    from drivers.scenario import load_scenario
    return load_scenario(path)


def _load_service_config(path):
    from rtsim.service.config import load_service_config
    return load_service_config(path)


def _load_catalogue(path):
    from rtsim.ecutest.catalog import load_catalogue
    return load_catalogue(path)


# (module converted, loader, shipped file, {dotted key: bad value} set in the file's table as it is read,
#  the key (and element) and value the line names, the allowed range it states)
FILE_SAMPLES = [
    ("car.config (hardpoint in mm)", _open_vehicle, "configs/vehicles/xbw.toml",
     {"front.hardpoints.wheel_centre": [0.0, 750.0, 0.3]}, "front.hardpoints.wheel_centre[1] = 750.0",
     "-10 <= wheel_centre[1] <= 10 m, design frame"),
    ("car.config (travel)", _open_vehicle, "configs/vehicles/eps_car.toml",
     {"front.travel_m": [-0.08, 80.0]}, "front.travel_m[1] = 80.0", "0 < travel_m[1] <= 0.3 m"),
    ("car.config (Field bound before)", _open_vehicle, "configs/vehicles/xbw.toml",
     {"chassis.mass_kg": 20.0}, "chassis.mass_kg = 20.0", "50 < mass_kg <= 5000 kg"),
    ("kit.design_frame (inertia in kg mm^2)", _open_vehicle, "configs/vehicles/xbw.toml",
     {"chassis.inertia_kgm2": [5.0e8, 2.0e9, 2.2e9]}, "chassis.inertia_kgm2[0] = 500000000.0",
     "0 <= inertia_kgm2[0] <= 100000 kg m^2"),
    ("motorcycle.config (cg in mm)", _open_vehicle, "configs/vehicles/motorcycle.toml",
     {"rear_frame.cg_m": [720.0, 0.52]}, "rear_frame.cg_m[0] = 720.0", "-10 <= cg_m[0] <= 10 m, design frame"),
    ("motorcycle.config (torque curve)", _open_vehicle, "configs/vehicles/motorcycle.toml",
     {"powertrain.gear_ratios": [2.6, 50.0]}, "powertrain.gear_ratios[1] = 50.0", "0.3 <= gear_ratios[1] <= 5"),
    ("kit.brake", _open_vehicle, "configs/vehicles/xbw.toml",
     {"brakes.front.pads": 20}, "brakes.front.pads = 20", "1 <= pads <= 16 pads"),
    ("kit.brake (valve)", _open_vehicle, "configs/vehicles/eps_car.toml",
     {"brakes.proportioning_ratio": 1.5}, "brakes.proportioning_ratio = 1.5", "0 <= proportioning_ratio <= 1"),
    ("kit.powertrain (gearbox)", _open_vehicle, "configs/vehicles/eps_car.toml",
     {"powertrain.gearbox.wheel_radius": 300.0}, "powertrain.gearbox.wheel_radius = 300.0",
     "0.05 < wheel_radius < 2 m"),
    ("kit.powertrain (engine table)", _open_vehicle, "configs/vehicles/xbw.toml",
     {"powertrain.engine.speed_nodes": [0.0, 100.0, 5000.0]}, "powertrain.engine.speed_nodes[2] = 5000.0",
     "0 <= speed_nodes[2] <= 2000 rad/s"),
    ("kit.powertrain (converter)", _open_vehicle, "configs/vehicles/xbw.toml",
     {"powertrain.converter.lockup_gear": 9}, "powertrain.converter.lockup_gear = 9", "1 <= lockup_gear <= 6"),
    ("kit.eps (assist table)", _open_vehicle, "configs/vehicles/eps_car.toml",
     {"eps.assist.speed_mps": [0.0, 8.0, 16.0, 25.0, 350.0]}, "eps.assist.speed_mps[4] = 350.0",
     "0 <= speed_mps[4] <= 100 m/s"),
    ("kit.eps (Field bound before)", _open_vehicle, "configs/vehicles/eps_car.toml",
     {"eps.rack_mass_kg": 0.0}, "eps.rack_mass_kg = 0.0", "0 < rack_mass_kg <= 50 kg"),
    ("kit.spring_damper (table in mm)", _open_vehicle, "configs/vehicles/eps_car.toml",
     {"front.spring.spring_table": {"x": [-100.0, 0.0, 100.0], "force_n": [-6600.0, 0.0, 10300.0]}},
     "front.spring.spring_table.x[0] = -100.0", "-10 <= x[0] <= 10 m or m/s"),
    ("road.config", _load_road, "configs/roads/flat.toml",
     {"mu": 0.0}, "mu = 0.0", "0 < mu <= "),
    ("service.config", _load_service_config, "configs/service.toml",
     {"simulation.loop_priority": 120}, "simulation.loop_priority = 120", "1 <= loop_priority <= 99 SCHED_FIFO"),
    ("batch.plan", _load_plan, "configs/batch/smoke.toml",
     {"repetitions": 0}, "repetitions = 0", "1 <= repetitions <= 10000"),
    ("drivers.scenario (gear)", _load_scenario, "configs/scenarios/motorcycle_counter_steer.toml",
     {"two_wheeler.gear": 12}, "two_wheeler.gear = 12", "0 <= gear <= 8"),
    ("drivers.scenario (lane spacing)", _load_scenario, "configs/scenarios/opendrive_curve.toml",
     {"inputs.path_follower.spacing": 50.0}, "inputs.path_follower.spacing = 50.0", "0.05 <= spacing <= 10 m"),
]


@pytest.mark.parametrize("what, loader, shipped, bad_keys, named, allowed", FILE_SAMPLES,
                         ids=[s[0] for s in FILE_SAMPLES])
def test_a_bad_value_in_a_file_names_the_file_key_value_and_range(what, loader, shipped, bad_keys, named, allowed):
    """A converted field's Range reaches the error line of a file (the value set in the file's table as
    it is read, as a batch's grid point is): file, dotted key (and element), value, allowed range."""
    from rtsim.configfile import overrides
    path = ROOT / shipped
    with overrides({path.resolve(): bad_keys}), pytest.raises(ConfigError) as exc:
        loader(path)
    line = str(exc.value)
    assert "\n" not in line
    assert line.startswith(f"{path}: ") and f"{named}: out of range (allowed {allowed}" in line, line


def test_an_ecutest_bound_and_a_fault_target_name_their_range(tmp_path):
    """The two sections read from lists of tables (no dotted key reaches them): an expectation's bound
    must be finite, a fault's frame id within its range."""
    text = (ROOT / "tests" / "ecu_small_catalog.toml").read_text()
    catalogue = tmp_path / "catalogue.toml"
    assert 'kind = "bounds"\nsignal = "ecu.BRAKE_CMD.brake_pressure_cmd"\nmax = 0\n' in text
    catalogue.write_text(text.replace('signal = "ecu.BRAKE_CMD.brake_pressure_cmd"\nmax = 0\n',
                                      'signal = "ecu.BRAKE_CMD.brake_pressure_cmd"\nmax = inf\n', 1))
    (tmp_path / "ecu_small.py").write_text("")
    with pytest.raises(ConfigError) as exc:
        _load_catalogue(catalogue)
    assert str(exc.value) == (f"{catalogue}: cases[0].expect[1].max = inf: out of range "
                              "(allowed -inf < max < inf the signal's unit)")

    from rtsim.faults.spec import load_fault_specs
    with pytest.raises(ConfigError) as exc:
        load_fault_specs([{"id": "f", "kind": "stuck_last", "target": -3, "at": 1.0}], "s.toml")
    assert str(exc.value) == ('s.toml: faults[0].target = -3: out of range (allowed 0 <= target <= 1e+06 frame id; '
                              'sensor channel, frame name or id, "bus", or actuator)')
