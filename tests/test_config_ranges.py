"""Every number a config file can set has its range declared where the field is (rtsim.configfile: a
`Range` annotation, or pydantic's Field(ge=, gt=, le=, lt=)), so a bad value's error names the file, the
key, the value and the allowed range. The test walks every config model (every `Strict` section, and
the config dataclasses they hold) and lists the numeric fields without a declared range.

NOT_YET_RANGED is the work left: sections whose numbers are still checked by hand (or not at all:
hardpoint coordinates, table nodes). It may only shrink: a new unranged number fails, and so does a
listed field that has gained a range (then drop it from the list)."""
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
    "rtsim.batch.plan.Criterion": {"max", "min"},
    "rtsim.batch.plan.Distribution": {"uniform"},
    "rtsim.ecutest.catalog.Bounds": {"max", "min"},
    "rtsim.faults.spec.Condition": {"value"},
    "rtsim.faults.spec.FaultSpec": {"params", "target"},
    "rtsim.vehicle.car.config.Axle": {"travel_m"},
    "rtsim.vehicle.car.config.Chassis": {"cg_m", "inertia_kgm2", "ixz_kgm2"},
    "rtsim.vehicle.car.config.DoubleWishboneHardpoints": {
        "lower_ball", "lower_front", "lower_rear", "spring_lower", "spring_upper", "tie_inner", "tie_outer",
        "upper_ball", "upper_front", "upper_rear", "wheel_centre",
    },
    "rtsim.vehicle.car.config.MacPhersonHardpoints": {
        "lower_ball", "lower_front", "lower_rear", "strut_lower", "strut_top", "toe_inner", "toe_outer",
        "wheel_centre",
    },
    "rtsim.vehicle.car.config.SensorNoise": {"bias"},
    "rtsim.vehicle.car.config.Sensors": {"imu_position_m"},
    "rtsim.vehicle.car.config.VerticalSliderHardpoints": {
        "kingpin", "spring_lower", "spring_upper", "tie_inner", "tie_outer", "wheel_centre",
    },
    "rtsim.vehicle.kit.brake.BrakeAxleConfig": {"effective_radius", "mu", "mu_static", "pads", "piston_area"},
    "rtsim.vehicle.kit.brake.BrakeConfig": {
        "anchor_damping", "anchor_stiffness", "omega_eps", "omega_stick", "proportioning_knee",
        "proportioning_ratio",
    },
    "rtsim.vehicle.kit.eps.AssistLaw": {"current_a", "speed_mps", "torque_nm"},
    "rtsim.vehicle.kit.powertrain.ConverterConfig": {
        "k_factor", "lockup_capacity", "lockup_damping", "lockup_gear", "lockup_speed", "overrun_capacity_scale",
        "speed_ratio_nodes", "torque_ratio", "torque_ratio_nodes",
    },
    "rtsim.vehicle.kit.powertrain.EngineConfig": {
        "idle_ki", "idle_kp", "idle_max_opening", "idle_speed", "inertia", "rev_limit", "rev_limit_band",
        "speed_nodes", "throttle_nodes", "torque_table",
    },
    "rtsim.vehicle.kit.powertrain.GearboxConfig": {
        "downshift_speeds", "efficiency", "final_drive", "ratios", "reverse_ratio", "schedule_throttle",
        "shift_delay", "shift_time", "upshift_speeds", "wheel_radius",
    },
    "rtsim.vehicle.kit.spring_damper.Characteristic": {"force_n", "x"},
    "rtsim.vehicle.motorcycle.config.Aero": {"centre_of_pressure_m"},
    "rtsim.vehicle.motorcycle.config.Body": {"cg_m", "inertia_kgm2", "ixz_kgm2"},
    "rtsim.vehicle.motorcycle.config.Chain": {"front_sprocket_m"},
    "rtsim.vehicle.motorcycle.config.Geometry": {"swingarm_pivot_m"},
    "rtsim.vehicle.motorcycle.config.Powertrain": {
        "closed_throttle_torque_nm", "engine_speed_rpm", "full_load_torque_nm", "gear_ratios",
    },
    "rtsim.vehicle.motorcycle.config.Sensors": {"imu_position_m"},
    "rtsim.vehicle.motorcycle.config.Shock": {"frame_mount_m", "swingarm_mount_m"},
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
    return any(getattr(m, k, None) is not None for m in metadata for k in ("gt", "ge", "lt", "le")) or \
        any(declared_range(Annotated[float, m]) is not None for m in metadata)


def _fields(cls):
    """(name, annotation, field metadata) of a pydantic model or a config dataclass."""
    if isinstance(cls, type) and issubclass(cls, BaseModel):
        return [(n, f.annotation, list(f.metadata)) for n, f in cls.model_fields.items()]
    hints = typing.get_type_hints(cls, include_extras=True)
    return [(f.name, hints[f.name], []) for f in dataclasses.fields(cls)]


def unranged_numbers() -> dict[str, set[str]]:
    """model (module.qualname) -> its numeric fields (float or int, alone, optional or in lists) with no
    declared range, over every Strict model and the config dataclasses reachable from them."""
    _import_all()
    todo, seen, out = list(_subclasses(Strict)), set(), {}
    while todo:
        cls = todo.pop()
        if cls in seen:
            continue
        seen.add(cls)
        for name, ann, meta in _fields(cls):
            kinds = _members(ann)
            todo += [m for m in kinds if dataclasses.is_dataclass(m)
                     or (isinstance(m, type) and issubclass(m, BaseModel))]
            if any(m in (float, int) for m in kinds) and not _ranged(meta + _annotated_metadata(ann)):
                out.setdefault(f"{cls.__module__}.{cls.__qualname__}", set()).add(name)
    return out


def test_every_number_of_every_config_model_has_a_declared_range():
    found = unranged_numbers()
    new = {k: sorted(v - NOT_YET_RANGED.get(k, set())) for k, v in found.items()}
    new = {k: v for k, v in new.items() if v}
    assert not new, f"numeric config fields without a declared range (declare one with Range or Field bounds): {new}"
    ranged_now = {k: sorted(v - found.get(k, set())) for k, v in NOT_YET_RANGED.items()}
    ranged_now = {k: v for k, v in ranged_now.items() if v}
    assert not ranged_now, f"these have a range now: drop them from NOT_YET_RANGED: {ranged_now}"


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
